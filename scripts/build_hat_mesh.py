"""Build the default hat's tetrahedral mesh ``meshes/hat_tets.npz`` (the coarse ~1k-tet simulation mesh).

pytetwild's output differs from run to run (and machine to machine), so the demo hat is meshed once here and
shipped: every machine then simulates the same hat and ``kdfem demo`` / ``kdfem window`` give the same numbers.
The file holds ``nodes`` (N, 3) [m], ``tets`` (T, 4) and ``key``, the content hash of the surface, the meshing
settings and the pytetwild version (:func:`kdfem.geometry.tetmesh.tet_key`); ``hat_tetmesh`` uses it only when the
key matches, and a test checks that it still does.

Run:  python scripts/build_hat_mesh.py [--out meshes/hat_tets.npz]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from kdfaces import defaults
from kdfem.fem.default_hat import SHIPPED_HAT_TETS
from kdfem.geometry import christmas_hat, tet_quality, tetrahedralize
from kdfem.geometry.tetmesh import tet_key


def main(argv=None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=SHIPPED_HAT_TETS)
    args = ap.parse_args(argv)
    surf = christmas_hat()
    kw = dict(edge_length_fac=defaults.TET_EDGE_LENGTH_FAC, envelope_fac=defaults.TET_ENVELOPE_FAC, coarsen=True)
    mesh = tetrahedralize(surf.vertices, surf.faces, where="hat", **kw)
    key = tet_key(surf.vertices, surf.faces, **kw)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, nodes=mesh.nodes, tets=mesh.tets.astype(np.int32), key=np.array(key))
    q = tet_quality(mesh)
    print(f"{args.out}: {mesh.num_nodes} nodes, {mesh.num_tets} tets, min dihedral {q['min_dihedral_deg']:.1f}°, "
          f"key {key[:16]}")
    return args.out


if __name__ == "__main__":
    main()
