"""Build a production-like face rig from the default head, as an OBJ folder a studio would hand over.

What a production rig does differently from the default head, all of it on purpose:

- **size**: Loop-subdivided (``--levels``, or ``--target-vertices`` for a count between two levels): 19k vertices
  at one level, 27k with ``--target-vertices 27000``;
- **unit**: centimetres (every length × 100), so a loader that assumes metres sees a 40 m head;
- **names**: ``browInnerUp`` split by vertex side into ``browInnerUp_L``/``browInnerUp_R`` (the character's left
  is +x), ``tongueOut`` dropped — a Live Link Face capture then names a shape the rig lacks and one it splits;
- **pieces**: two small closed boxes inside the mouth, ``box_teeth_upper`` (still) and ``box_teeth_lower`` (moved
  rigidly by ``jawOpen``), on top of the head's own eye and teeth pieces; every piece is an OBJ group;
- **no skeleton**: an OBJ folder carries none, so captured head angles have nothing to drive.

Run:  python scripts/build_production_rig.py OUT_FOLDER [--levels 1] [--target-vertices N]
Python: ``build_production_rig(folder, levels=1, target_vertices=None)`` returns a dict of what it wrote.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from kdfaces import BlendshapeRig, load_default_rig
from kdfaces.io.rigfiles import save_obj_folder
from kdfaces.rig import subdivide_rig

CM = 0.01
BOX_HALF_M = np.array([0.012, 0.004, 0.006])  # a teeth-sized box: 2.4 × 0.8 × 1.2 cm


def _box(center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """8 corners (8, 3) [m] and 6 outward quads (6, 4) of an axis-aligned box."""
    s = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    quads = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])
    return center + s * BOX_HALF_M, quads


def production_rig(*, levels: int = 1, target_vertices: int | None = None) -> BlendshapeRig:
    """The production-like rig in metres (see the module docstring; :func:`build_production_rig` writes it)."""
    base = load_default_rig()
    rig = subdivide_rig(base, levels, target_vertices=target_vertices)
    names = list(rig.shape_names)
    deltas = rig.deltas.astype(np.float64)
    brow = names.index("browInnerUp")
    left = (rig.neutral[:, 0] > 0)[:, None]
    split = [deltas[brow] * left, deltas[brow] * ~left]
    keep = [k for k, n in enumerate(names) if n not in ("browInnerUp", "tongueOut")]
    names = [names[k] for k in keep] + ["browInnerUp_L", "browInnerUp_R"]
    deltas = np.concatenate([deltas[keep], np.stack(split)])
    # two boxes behind the lips, at the default head's teeth; the lower one follows jawOpen rigidly
    teeth_up = rig.neutral[rig.part_vertices("teeth_upper")].mean(axis=0) + [0.0, 0.0, -0.012]
    teeth_lo = rig.neutral[rig.part_vertices("teeth_lower")].mean(axis=0) + [0.0, 0.0, -0.012]
    jaw_move = deltas[names.index("jawOpen")][rig.part_vertices("teeth_lower")].mean(axis=0)
    verts, polys = [rig.neutral], [(rig.polygon_counts, rig.polygon_corners)]
    parts = list(rig.part_names) + ["box_teeth_upper", "box_teeth_lower"]
    vparts = [rig.vertex_parts]
    box_deltas = []
    n = rig.num_vertices
    for k, center in enumerate((teeth_up, teeth_lo)):
        v, q = _box(center)
        verts.append(v)
        polys.append((np.full(len(q), 4), (q + n).reshape(-1)))
        vparts.append(np.full(8, len(rig.part_names) + k))
        d = np.zeros((len(names), 8, 3))
        if k == 1:
            d[names.index("jawOpen")] = jaw_move  # a translation: rigid
        box_deltas.append(d)
        n += 8
    counts = np.concatenate([p[0] for p in polys])
    corners = np.concatenate([p[1] for p in polys])
    from kdfaces.io.obj import triangulate

    return BlendshapeRig.create(np.concatenate(verts), np.concatenate([deltas, *box_deltas], axis=1),
                                triangulate(counts, corners), names, name=f"production_{rig.num_vertices}v",
                                polygons=(counts, corners), part_names=parts, vertex_parts=np.concatenate(vparts))


def build_production_rig(folder, *, levels: int = 1, target_vertices: int | None = None) -> dict:
    """Write the production-like rig to ``folder`` as an OBJ folder in centimetres; returns a summary dict."""
    rig = production_rig(levels=levels, target_vertices=target_vertices)
    save_obj_folder(rig, folder, unit_m=CM)
    return {"folder": str(folder), "vertices": rig.num_vertices, "shapes": rig.num_shapes,
            "parts": list(rig.part_names), "unit": "cm"}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--levels", type=int, default=1)
    ap.add_argument("--target-vertices", type=int, default=None)
    args = ap.parse_args(argv)
    info = build_production_rig(args.out, levels=args.levels, target_vertices=args.target_vertices)
    print(json.dumps(info))
    return info


if __name__ == "__main__":
    main()
