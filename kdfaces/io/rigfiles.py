"""Rig loaders and writers: the npz format, OBJ folders and MakeHuman base OBJ + ``.target`` folders.

All loaders return a :class:`~kdfaces.rig.BlendshapeRig` in metres; unit conversion happens here and nowhere else.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import KDInputError, check_finite
from ..rig.blendshapes import BlendshapeRig
from ..rig.skeleton import Skeleton
from .atomic import atomic_path

__all__ = [
    "DEFAULT_RIG_PATH", "load_default_rig", "load_rig", "load_npz", "save_npz", "read_obj", "write_obj",
    "load_obj_folder", "save_obj_folder", "load_makehuman",
]

DEFAULT_RIG_PATH = Path(os.environ.get("KDFACES_MESHES", Path(__file__).resolve().parents[2] / "meshes")) / \
    "makehuman_head.npz"
MAKEHUMAN_UNIT_M = 0.1  # MakeHuman OBJ and .target files are in decimetres


def _require_file(path) -> Path:
    p = Path(path)
    if not p.exists():
        raise KDInputError(f"{p}: file not found")
    return p


def load_default_rig() -> BlendshapeRig:
    """The embedded default: the CC0 MakeHuman head with the 52 ARKit face units (see meshes/LICENSES.md)."""
    if not DEFAULT_RIG_PATH.exists():
        raise KDInputError(f"{DEFAULT_RIG_PATH}: default rig missing; run `python scripts/build_makehuman_head.py`")
    return load_npz(DEFAULT_RIG_PATH)


def load_rig(spec) -> BlendshapeRig:
    """Load a rig from ``"default"``, an ``.npz``, a glTF (``.gltf``/``.glb``), an OBJ folder, or a MakeHuman folder
    (``base.obj`` + ``*.target``)."""
    if spec is None or str(spec) == "default":
        return load_default_rig()
    p = _require_file(spec)
    if p.is_file() and p.suffix == ".npz":
        return load_npz(p)
    if p.is_file() and p.suffix in (".gltf", ".glb"):
        from .gltf import load_gltf_rig

        return load_gltf_rig(p)
    if p.is_dir():
        if list(p.glob("*.target")) or list(p.glob("targets/*.target")):
            return load_makehuman(p / "base.obj", p / "targets" if (p / "targets").is_dir() else p)
        return load_obj_folder(p)
    raise KDInputError(f"{p}: expected an .npz or glTF rig, an OBJ folder or a MakeHuman folder (base.obj + .target "
                       "files)")


def load_npz(path) -> BlendshapeRig:
    """Load a rig written by :func:`save_npz` (or ``scripts/build_makehuman_head.py``)."""
    p = _require_file(path)
    try:
        d = np.load(p, allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - any unreadable file is one error
        raise KDInputError(f"{p}: not a readable npz rig ({e})") from None
    missing = {"neutral", "deltas", "faces", "shape_names"} - set(d.files)
    if missing:
        raise KDInputError(f"{p}: npz rig lacks field(s) {sorted(missing)}")
    skel = None
    if "skin_weights" in d.files:
        w = np.asarray(d["skin_weights"], dtype=np.float64)
        # weights are stored as float32: rows meant to sum to one are renormalised so fully skinned parts are rigid
        total = w.sum(axis=1, keepdims=True)
        w = np.where(np.abs(total - 1.0) < 1e-5, w / np.where(total > 0, total, 1.0), w)
        skel = Skeleton(
            names=tuple(str(s) for s in d["joint_names"]),
            positions=np.asarray(d["joint_positions"], dtype=np.float64),
            parents=np.asarray(d["joint_parents"], dtype=np.int64),
            weights=w,
        )
    name = str(d["name"]) if "name" in d.files else p.stem
    return BlendshapeRig.create(d["neutral"], d["deltas"], d["faces"], [str(s) for s in d["shape_names"]],
                                skeleton=skel, name=name)


def save_npz(rig: BlendshapeRig, path) -> Path:
    """Write ``rig`` to an npz (atomically)."""
    fields = dict(name=np.array(rig.name), neutral=rig.neutral, deltas=rig.deltas, faces=rig.faces,
                  shape_names=np.array(rig.shape_names))
    if rig.skeleton is not None:
        s = rig.skeleton
        fields.update(joint_names=np.array(s.names), joint_positions=s.positions, joint_parents=s.parents,
                      skin_weights=s.weights.astype(np.float32))
    with atomic_path(path, ".npz") as tmp:
        np.savez_compressed(tmp, **fields)
    return Path(path)


def read_obj(path, *, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) [file units × scale] in file order and triangles (F, 3); polygons are fan-triangulated."""
    p = _require_file(path)
    verts, tris = [], []
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise KDInputError(f"{p}: cannot read OBJ ({e})") from None
    for lineno, line in enumerate(text.splitlines(), 1):
        if line.startswith("v "):
            parts = line.split()
            try:
                verts.append([float(x) for x in parts[1:4]])
            except ValueError:
                raise KDInputError(f"{p}:{lineno}: vertex line needs three numbers, got {line.strip()!r}") from None
            if len(parts) < 4:
                raise KDInputError(f"{p}:{lineno}: vertex line needs three numbers, got {line.strip()!r}")
        elif line.startswith("f "):
            try:
                idx = [int(t.split("/")[0]) for t in line.split()[1:]]
            except ValueError:
                raise KDInputError(f"{p}:{lineno}: bad face line {line.strip()!r}") from None
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            tris.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    if not verts:
        raise KDInputError(f"{p}: no vertices ('v' lines) found")
    v = np.asarray(verts, dtype=np.float64) * scale
    check_finite(v, f"{p} vertices")
    f = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise KDInputError(f"{p}: face index out of range 1..{len(v)}")
    return v, f


def write_obj(path, vertices: np.ndarray, faces: np.ndarray | None = None) -> Path:
    """Write vertices [m] (and 0-based triangles) as an OBJ, atomically."""
    with atomic_path(path, ".obj") as tmp, open(tmp, "w") as fh:
        np.savetxt(fh, vertices, fmt="v %.9g %.9g %.9g")
        if faces is not None and len(faces):
            np.savetxt(fh, np.asarray(faces) + 1, fmt="f %d %d %d")
    return Path(path)


def load_obj_folder(folder, *, neutral_name: str = "neutral.obj", scale: float = 1.0) -> BlendshapeRig:
    """A folder holding ``neutral.obj`` and one OBJ per shape (file stem = shape name), same vertex order."""
    d = Path(folder)
    if not d.is_dir():
        raise KDInputError(f"{d}: expected a folder of OBJ files")
    neutral_path = d / neutral_name
    neutral, faces = read_obj(neutral_path, scale=scale)
    names, deltas = [], []
    for p in sorted(d.glob("*.obj")):
        if p.name == neutral_name:
            continue
        v, _ = read_obj(p, scale=scale)
        if v.shape != neutral.shape:
            raise KDInputError(f"{p}: {len(v)} vertices, expected {len(neutral)} as in {neutral_path.name}")
        names.append(p.stem)
        deltas.append(v - neutral)
    if not names:
        raise KDInputError(f"{d}: no shape OBJ files next to {neutral_name}")
    return BlendshapeRig.create(neutral, np.stack(deltas), faces, names, name=d.name)


def save_obj_folder(rig: BlendshapeRig, folder) -> Path:
    """Write the rig as ``neutral.obj`` + one OBJ per shape (full positions), for other tools."""
    d = Path(folder)
    write_obj(d / "neutral.obj", rig.neutral, rig.faces)
    for k, name in enumerate(rig.shape_names):
        write_obj(d / f"{name}.obj", rig.neutral + rig.deltas[k].astype(np.float64), rig.faces)
    return d


def load_makehuman(base_obj, targets_dir, *, unit_m: float = MAKEHUMAN_UNIT_M) -> BlendshapeRig:
    """A MakeHuman base OBJ plus a folder of sparse ``.target`` files (``index dx dy dz``), both in decimetres."""
    neutral, faces = read_obj(base_obj, scale=unit_m)
    tdir = Path(targets_dir)
    files = sorted(tdir.glob("*.target"))
    if not files:
        raise KDInputError(f"{tdir}: no .target files found")
    deltas = np.zeros((len(files), len(neutral), 3), dtype=np.float32)
    for k, p in enumerate(files):
        rows = []
        for lineno, line in enumerate(p.read_text().splitlines(), 1):
            if not line.strip() or line.startswith("#"):
                continue
            parts = line.split()
            try:
                rows.append((int(parts[0]), float(parts[1]), float(parts[2]), float(parts[3])))
            except (ValueError, IndexError):
                raise KDInputError(f"{p}:{lineno}: expected 'index dx dy dz', got {line.strip()!r}") from None
        if not rows:
            continue
        a = np.asarray(rows)
        idx = a[:, 0].astype(np.int64)
        if idx.min() < 0 or idx.max() >= len(neutral):
            raise KDInputError(f"{p}: vertex index {int(idx.max())} out of range for {base_obj} "
                               f"({len(neutral)} vertices)")
        check_finite(a[:, 1:], f"{p} offsets")
        deltas[k, idx] = a[:, 1:] * unit_m
    return BlendshapeRig.create(neutral, deltas, faces, [p.stem for p in files], name=Path(base_obj).stem)
