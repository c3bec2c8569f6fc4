"""Rig loaders and writers: the npz format, OBJ folders, glTF and MakeHuman base OBJ + ``.target`` folders.

All loaders return a :class:`~kdfaces.rig.BlendshapeRig` in metres; unit conversion happens here and nowhere else:
``units`` ("m", "dm", "cm", "mm") or ``unit_m`` (metres per file unit) say what the file's numbers are. A head that
comes out implausibly large or small for the stated unit gets one :class:`RigUnitsWarning` naming the likely unit.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

import numpy as np

from ..deprecation import renamed_kwargs
from ..errors import KDInputError, check_finite
from ..rig.blendshapes import (
    STRETCH_FACTOR,
    UNITS,
    BlendshapeRig,
    RigUnitsWarning,
    check_plausible_size,
    reordered_shapes,
    surface_problem,
)
from ..rig.skeleton import Skeleton
from .atomic import atomic_path
from .obj import obj_face_key, read_obj_mesh, read_obj_shape, write_obj_mesh

__all__ = [
    "DEFAULT_RIG_PATH", "UNITS", "RigUnitsWarning", "unit_scale", "load_default_rig", "load_rig", "load_npz",
    "save_npz", "read_obj", "write_obj", "load_obj_folder", "save_obj_folder", "load_makehuman",
    "LostInbetweensWarning", "INBETWEEN_FIELDS",
]

DEFAULT_RIG_PATH = Path(os.environ.get("KDFACES_MESHES", Path(__file__).resolve().parents[2] / "meshes")) / \
    "makehuman_head.npz"
MAKEHUMAN_UNIT_M = 0.1  # MakeHuman OBJ and .target files are in decimetres
@renamed_kwargs(scale="unit_m")
def unit_scale(units: str | None = None, unit_m: float | None = None, *, default: float = 1.0,
               where: str = "rig", name: str = "unit_m") -> float:
    """Metres per file unit from ``units`` (one of :data:`UNITS`) or ``unit_m``; ``default`` when neither is given.
    ``name``: what the error messages call ``unit_m`` (a shot file's ``rig.scale``)."""
    scale = unit_m
    if units is not None and scale is not None:
        raise KDInputError(f"{where}: give units or {name}, not both")
    if units is not None:
        if units not in UNITS:
            raise KDInputError(f"{where}.units: expected one of {sorted(UNITS)}, got {units!r}")
        return UNITS[units]
    if scale is not None:
        if isinstance(scale, bool) or not isinstance(scale, int | float) or not (np.isfinite(scale) and scale > 0):
            raise KDInputError(f"{where}.{name}: expected a positive number of metres per file unit, got {scale!r}")
        return float(scale)
    return float(default)


class LostInbetweensWarning(UserWarning):
    """A rig with in-betweens was written to a format that cannot keep them (an OBJ folder)."""


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


@renamed_kwargs(scale="unit_m")
def load_rig(spec, *, units: str | None = None, unit_m: float | None = None, cache_dir=None,
             unit_name: str = "unit_m") -> BlendshapeRig:
    """Load a rig from ``"default"``, an ``.npz``, a glTF (``.gltf``/``.glb``), an FBX 7.x (``.fbx``,
    :func:`~kdfaces.io.fbx.load_fbx_rig`), an OBJ folder, or a MakeHuman folder
    (``base.obj`` + ``*.target``), converting its ``units`` (or ``unit_m``, metres per file unit, as in
    :func:`save_obj_folder`; its old name ``scale`` still works for one release) to metres. ``unit_name``: what
    errors call ``unit_m`` (a shot file passes its ``rig.scale``).

    Defaults: npz and glTF files are in metres (the glTF standard), OBJ folders in metres, MakeHuman in
    decimetres, FBX in the unit its file states (``UnitScaleFactor``), which ``units``/``unit_m`` override.
    An OBJ folder is parsed once per content: with ``cache_dir`` the parsed rig is kept there as an
    npz named by the hash of the folder's files and the unit.
    """
    if spec is None or str(spec) == "default":
        if units is not None or unit_m is not None:
            raise KDInputError(f"rig: the default rig is in metres already; units/{unit_name} apply to rig files")
        return load_default_rig()
    p = _require_file(spec)
    if p.is_file() and p.suffix == ".npz":
        rig = load_npz(p)
        unit_m = unit_scale(units, unit_m, where=str(p), name=unit_name)
        rig = rig if unit_m == 1.0 else _rescaled(rig, unit_m)
    elif p.is_file() and p.suffix in (".gltf", ".glb"):
        from .gltf import load_gltf_rig

        unit_m = unit_scale(units, unit_m, where=str(p), name=unit_name)
        rig = load_gltf_rig(p)
        rig = rig if unit_m == 1.0 else _rescaled(rig, unit_m)
    elif p.is_file() and p.suffix.lower() == ".fbx":
        from .fbx import load_fbx_rig

        # the file says its unit (UnitScaleFactor); units/unit_m override it only when given
        given = None if units is None and unit_m is None else unit_scale(units, unit_m, where=str(p), name=unit_name)
        rig = load_fbx_rig(p, unit_m=given)
        unit_m = rig.source_unit_m
    elif p.is_dir():
        if list(p.glob("*.target")) or list(p.glob("targets/*.target")):
            unit_m = unit_scale(units, unit_m, default=MAKEHUMAN_UNIT_M, where=str(p), name=unit_name)
            rig = load_makehuman(p / "base.obj", p / "targets" if (p / "targets").is_dir() else p, unit_m=unit_m)
        else:
            unit_m = unit_scale(units, unit_m, where=str(p), name=unit_name)
            rig = load_obj_folder(p, unit_m=unit_m, cache_dir=cache_dir)
    else:
        raise KDInputError(f"{p}: expected an .npz, glTF or FBX rig, an OBJ folder or a MakeHuman folder (base.obj "
                           "+ .target files)")
    check_plausible_size(rig, unit_m, str(p))
    return rig


def _rescaled(rig: BlendshapeRig, unit_m: float) -> BlendshapeRig:
    """``rig`` with lengths multiplied by ``unit_m`` (file units → metres)."""
    skel = rig.skeleton
    if skel is not None:
        skel = Skeleton(names=skel.names, positions=skel.positions * unit_m, parents=skel.parents,
                        weights=skel.weights)
    return BlendshapeRig.create(rig.neutral * unit_m, rig.deltas.astype(np.float64) * unit_m, rig.faces,
                                rig.shape_names, skeleton=skel, name=rig.name, polygons=rig.polygons, uvs=rig.uvs,
                                part_names=rig.part_names, vertex_parts=rig.vertex_parts,
                                source_unit_m=rig.source_unit_m * unit_m, check_units=False,
                                inbetweens=rig.inbetweens)


def load_npz(path) -> BlendshapeRig:
    """Load a rig written by :func:`save_npz` (or ``scripts/build_makehuman_head.py``); lengths in metres.

    Only plain arrays are read (``allow_pickle=False``): a field holding pickled Python objects is refused, since
    unpickling a file runs code from it.
    """
    p = _require_file(path)
    try:
        d = np.load(p, allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - any unreadable file is one error
        raise KDInputError(f"{p}: not a readable npz rig ({e})") from None
    if not isinstance(d, np.lib.npyio.NpzFile):
        raise KDInputError(f"{p}: expected an npz rig (a zip of named arrays), got a single .npy array")
    with d:
        missing = {"neutral", "deltas", "faces", "shape_names"} - set(d.files)
        if missing:
            raise KDInputError(f"{p}: npz rig lacks field(s) {sorted(missing)}")

        def field(name: str, dtype=None) -> np.ndarray:
            try:
                a = d[name]
            except ValueError as e:
                if "pickle" in str(e):
                    raise KDInputError(f"{p}: field {name!r} holds pickled Python objects; expected a plain array "
                                       "(numbers or strings: npz rigs are read without unpickling)") from None
                raise KDInputError(f"{p}: field {name!r} is not a readable array ({e})") from None
            except Exception as e:  # noqa: BLE001 - a damaged member of the zip
                raise KDInputError(f"{p}: field {name!r} is not a readable array ({type(e).__name__}: {e})") from None
            if dtype is None:
                return a
            whole = dtype is not np.int64 or a.dtype.kind != "f" or bool(np.all(np.isfinite(a) & (a == np.round(a))))
            if a.dtype.kind not in "biuf" or not whole:
                raise KDInputError(f"{p}: field {name!r} holds {a.dtype} values; expected "
                                   f"{'integers' if dtype is np.int64 else 'numbers'}")
            return a.astype(dtype, copy=False)  # (deltas: float32, as stored)

        def strings(name: str) -> list[str]:
            a = field(name)
            if a.dtype.kind not in "US":
                raise KDInputError(f"{p}: field {name!r} holds {a.dtype} values; expected strings")
            return [str(s) for s in np.atleast_1d(a)]

        skel = None
        if "skin_weights" in d.files:
            w = field("skin_weights", np.float64)
            # weights are stored as float32: rows meant to sum to one are renormalised so fully skinned parts are
            # rigid
            total = w.sum(axis=1, keepdims=True) if w.ndim == 2 else w
            w = np.where(np.abs(total - 1.0) < 1e-5, w / np.where(total > 0, total, 1.0), w)
            try:
                skel = Skeleton(
                    names=tuple(strings("joint_names")),
                    positions=field("joint_positions", np.float64),
                    parents=field("joint_parents", np.int64),
                    weights=w,
                )
            except KeyError as e:
                raise KDInputError(f"{p}: npz rig has skin_weights but lacks field {e}") from None
            except KDInputError as e:
                raise KDInputError(f"{p}: {e}") from None
        name = str(field("name")) if "name" in d.files else p.stem
        extra = {}
        if "polygon_counts" in d.files:
            extra["polygons"] = (field("polygon_counts", np.int64), field("polygon_corners", np.int64))
        if "uvs" in d.files:
            extra["uvs"] = field("uvs", np.float64)
        if "part_names" in d.files:
            extra["part_names"] = strings("part_names")
            extra["vertex_parts"] = field("vertex_parts", np.int64)
        if "source_unit_m" in d.files:
            unit = field("source_unit_m", np.float64)
            if unit.size != 1:
                raise KDInputError(f"{p}: field 'source_unit_m': expected one number (metres per file unit)")
            extra["source_unit_m"] = float(unit.reshape(-1)[0])
        if "inbetween_channels" in d.files:
            extra["inbetweens"] = _read_inbetweens(p, d.files, field)
        arrays = field("neutral", np.float64), field("deltas", np.float32), field("faces", np.int64)
        shape_names = strings("shape_names")
        try:
            return BlendshapeRig.create(*arrays, shape_names, skeleton=skel, name=name, **extra, check_units=False)
        except KDInputError as e:
            raise KDInputError(f"{p}: {e}") from None


#: The npz fields of a rig's in-betweens (:attr:`BlendshapeRig.inbetweens`), flattened: channel c has the channel
#: row ``inbetween_channels[c]`` and the ``inbetween_counts[c]`` targets that follow in ``inbetween_rows`` and
#: ``inbetween_full_weights`` (float64, so they round-trip exactly).
INBETWEEN_FIELDS = ("inbetween_channels", "inbetween_counts", "inbetween_rows", "inbetween_full_weights")


def _read_inbetweens(p: Path, files, field) -> tuple:
    """The in-betweens of an npz rig (member names ``files``; ``field(name, dtype)`` reads one) from its
    :data:`INBETWEEN_FIELDS`; :meth:`BlendshapeRig.create` checks that the rows are shapes of the rig and that the
    full weights increase."""
    missing = [f for f in INBETWEEN_FIELDS if f not in files]
    if missing:
        raise KDInputError(f"{p}: npz rig has inbetween_channels but lacks field(s) {missing}")
    channels, counts = field("inbetween_channels", np.int64), field("inbetween_counts", np.int64)
    rows, full = field("inbetween_rows", np.int64), field("inbetween_full_weights", np.float64)
    if channels.ndim != 1 or counts.shape != channels.shape or (counts < 1).any() or rows.ndim != 1 or \
            full.shape != rows.shape or int(counts.sum()) != len(rows):
        raise KDInputError(f"{p}: fields {list(INBETWEEN_FIELDS)}: expected one channel row and a target count ≥ 1 "
                           f"per channel, and as many target rows and full weights as the counts add up to; got "
                           f"{len(channels)} channels, counts {counts.tolist()}, {len(rows)} rows and {len(full)} "
                           "weights")
    starts = np.concatenate([[0], np.cumsum(counts)])
    return tuple((int(c), tuple(int(r) for r in rows[a:b]), tuple(float(f) for f in full[a:b]))
                 for c, a, b in zip(channels, starts[:-1], starts[1:]))


def save_npz(rig: BlendshapeRig, path) -> Path:
    """Write ``rig`` to an npz (atomically), with its polygons, UVs, parts and in-betweens when it has them."""
    fields = dict(name=np.array(rig.name), neutral=rig.neutral, deltas=rig.deltas, faces=rig.faces,
                  shape_names=np.array(rig.shape_names), source_unit_m=np.array(rig.source_unit_m))
    if rig.skeleton is not None:
        s = rig.skeleton
        fields.update(joint_names=np.array(s.names), joint_positions=s.positions, joint_parents=s.parents,
                      skin_weights=s.weights.astype(np.float32))
    if rig.polygons is not None:
        fields.update(polygon_counts=rig.polygons[0], polygon_corners=rig.polygons[1])
    if rig.uvs is not None:
        fields.update(uvs=rig.uvs)
    if rig.vertex_parts is not None:
        fields.update(part_names=np.array(rig.part_names), vertex_parts=rig.vertex_parts)
    if rig.inbetweens:
        ib = rig.inbetweens
        fields.update(inbetween_channels=np.array([c for c, _, _ in ib], dtype=np.int64),
                      inbetween_counts=np.array([len(r) for _, r, _ in ib], dtype=np.int64),
                      inbetween_rows=np.array([i for _, r, _ in ib for i in r], dtype=np.int64),
                      inbetween_full_weights=np.array([f for _, _, w in ib for f in w], dtype=np.float64))
    with atomic_path(path, ".npz") as tmp:
        np.savez_compressed(tmp, **fields)
    return Path(path)


@renamed_kwargs(scale="unit_m")
def read_obj(path, *, unit_m: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) [file units × ``unit_m``, metres per file unit] in file order and triangles (F, 3); polygons
    are fan-triangulated."""
    mesh = read_obj_mesh(path, scale=unit_m)
    return mesh.vertices, mesh.triangles


def write_obj(path, vertices: np.ndarray, faces: np.ndarray | None = None) -> Path:
    """Write vertices [m] (and 0-based triangles) as an OBJ, atomically."""
    with atomic_path(path, ".obj") as tmp, open(tmp, "w") as fh:
        np.savetxt(fh, vertices, fmt="v %.9g %.9g %.9g")
        if faces is not None and len(faces):
            np.savetxt(fh, np.asarray(faces) + 1, fmt="f %d %d %d")
    return Path(path)


def _folder_key(files: list[Path], scale: float, neutral_name: str) -> str:
    h = hashlib.sha256(repr((round(scale, 12), neutral_name)).encode())
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


@renamed_kwargs(scale="unit_m")
def load_obj_folder(folder, *, neutral_name: str = "neutral.obj", unit_m: float = 1.0,
                    cache_dir=None) -> BlendshapeRig:
    """A folder holding ``neutral.obj`` and one OBJ per shape (file stem = shape name), same vertex order.

    Shapes must share the neutral's topology: a shape file with faces must have the neutral's faces over the same
    vertex indices, and a shape whose vertices look listed in another order (most of the neutral's edges torn apart,
    :func:`~kdfaces.rig.blendshapes.reordered_shapes`) is refused, naming the file. The neutral must be a surface
    (at least 3 vertices and one face, not all of zero area).

    Lengths are multiplied by ``unit_m`` (metres per file unit; its old name ``scale`` still works for one
    release). The neutral's polygons, UVs and groups become the
    rig's polygons, uvs and parts. With ``cache_dir``, the parsed rig is kept there as an npz named by the hash of
    the folder's files (so an edited file is parsed again, never read stale).
    """
    d = Path(folder)
    if not d.is_dir():
        raise KDInputError(f"{d}: expected a folder of OBJ files")
    neutral_path = d / neutral_name
    if not neutral_path.exists():
        raise KDInputError(f"{neutral_path}: file not found (an OBJ folder rig needs its neutral)")
    shapes = sorted(p for p in d.glob("*.obj") if p.name != neutral_name)
    if not shapes:
        raise KDInputError(f"{d}: no shape OBJ files next to {neutral_name}")
    cached = None
    if cache_dir is not None:
        key = _folder_key([neutral_path, *shapes], unit_m, neutral_name)
        cached = Path(cache_dir) / f"rig_{key[:24]}.npz"
        if cached.exists():
            return load_npz(cached)
    mesh = read_obj_mesh(neutral_path, scale=unit_m)
    neutral = mesh.vertices
    neutral_key = obj_face_key(neutral_path.read_bytes())
    deltas = np.empty((len(shapes), len(neutral), 3), dtype=np.float32)
    for k, p in enumerate(shapes):
        v, key = read_obj_shape(p, scale=unit_m)
        if v.shape != neutral.shape:
            raise KDInputError(f"{p}: {len(v)} vertices, expected {len(neutral)} as in {neutral_path.name}")
        if key is not None and key != neutral_key:
            _check_same_faces(p, mesh, neutral_path.name)
        deltas[k] = v - neutral
    triangles = mesh.triangles
    _check_surface(neutral_path, neutral, triangles)
    for k, share in reordered_shapes(neutral, deltas, triangles)[:1]:
        raise KDInputError(f"{shapes[k]}: {100 * share:.0f} % of the edges of {neutral_path.name} get over "
                           f"{STRETCH_FACTOR:g}× longer "
                           f"in it; expected the same vertices in the same order as {neutral_path.name} (this file's "
                           "vertices look reordered, or are in another unit)")
    uvs = None if mesh.uvs is None else mesh.uvs[mesh.uv_corners]
    try:
        rig = BlendshapeRig.create(neutral, deltas, triangles, [p.stem for p in shapes], name=d.name,
                                   polygons=(mesh.counts, mesh.corners), uvs=uvs, part_names=mesh.group_names,
                                   vertex_parts=mesh.vertex_groups(), source_unit_m=unit_m, check_units=False)
    except KDInputError as e:
        raise KDInputError(f"{d}: {e}") from None
    if cached is not None:
        save_npz(rig, cached)
    return rig


def _check_same_faces(path: Path, neutral, neutral_name: str) -> None:
    """Raise :class:`KDInputError` unless the OBJ at ``path`` has the polygons of ``neutral`` (an :class:`ObjMesh`)
    over the same vertex indices (a shape of another topology would blend scrambled deltas)."""
    mesh = read_obj_mesh(path)
    if len(mesh.counts) != len(neutral.counts):
        raise KDInputError(f"{path}: {len(mesh.counts)} faces, {neutral_name} has {len(neutral.counts)}; expected "
                           f"the topology of {neutral_name} (the same faces over the same vertex order)")
    if np.array_equal(mesh.counts, neutral.counts):
        if np.array_equal(mesh.corners, neutral.corners):
            return
        k = int(np.repeat(np.arange(len(mesh.counts)), mesh.counts)[np.argmax(mesh.corners != neutral.corners)])
    else:
        k = int(np.argmax(mesh.counts != neutral.counts))

    def face(m) -> str:
        start = int(m.counts[:k].sum())
        return "f " + " ".join(str(int(i) + 1) for i in m.corners[start:start + int(m.counts[k])])

    raise KDInputError(f"{path}: face {k + 1} is '{face(mesh)}', in {neutral_name} '{face(neutral)}'; expected the "
                       f"topology of {neutral_name} (the same faces over the same vertex order)")


def _check_surface(path: Path, vertices: np.ndarray, triangles: np.ndarray) -> None:
    """Raise :class:`KDInputError` naming ``path`` unless the neutral is a surface (:func:`surface_problem`)."""
    problem = surface_problem(vertices, triangles)
    if problem:
        raise KDInputError(f"{path}: {problem}")


def save_obj_folder(rig: BlendshapeRig, folder, *, unit_m: float = 1.0) -> Path:
    """Write the rig as ``neutral.obj`` + one OBJ per shape (full positions), for other tools: its polygons, UVs,
    parts as groups and smooth normals; lengths divided by ``unit_m`` (metres per written unit; 0.01 writes
    centimetres).

    Not everything survives: the skeleton (neck/head joints and skin weights) is not written, so the folder loads
    back without one, and :func:`load_obj_folder` reads the shapes in alphabetical order of their file names, not
    in ``rig.shape_names``' order. :func:`save_npz` keeps both.

    OBJ folders have no in-betweens (:attr:`~kdfaces.rig.BlendshapeRig.inbetweens`): every target is written as its
    own OBJ (``jawOpen@50.obj`` next to ``jawOpen.obj``), but the folder loads back linear in its shapes, so a rig
    with in-betweens gets one :class:`LostInbetweensWarning` naming the channels (npz and glTF keep them)."""
    d = Path(folder)
    if rig.inbetweens:
        lost = ", ".join(f"{rig.shape_names[c]!r} (" + ", ".join(f"{rig.shape_names[r]} at {f:g}" for r, f in
                                                                  zip(rows, full)) + ")"
                         for c, rows, full in rig.inbetweens)
        warnings.warn(f"{d}: OBJ folders cannot keep in-betweens; the folder loads back blending these channels' "
                      f"targets linearly, as separate shapes: {lost}. Write .npz or glTF to keep them",
                      LostInbetweensWarning, stacklevel=2)
    counts, corners = rig.polygon_counts, rig.polygon_corners
    groups = None
    if rig.vertex_parts is not None and rig.part_names:
        first = rig.vertex_parts[corners[np.concatenate([[0], np.cumsum(counts)[:-1]])]]
        names = (*rig.part_names, "mesh")
        groups = (names, np.where(first >= 0, first, len(names) - 1))
    s = 1.0 / float(unit_m)
    write_obj_mesh(d / "neutral.obj", rig.neutral * s, counts, corners, uvs=rig.uvs, groups=groups)
    for k, name in enumerate(rig.shape_names):
        write_obj_mesh(d / f"{name}.obj", (rig.neutral + rig.deltas[k].astype(np.float64)) * s, counts, corners,
                       uvs=rig.uvs, groups=groups)
    return d


def load_makehuman(base_obj, targets_dir, *, unit_m: float = MAKEHUMAN_UNIT_M) -> BlendshapeRig:
    """A MakeHuman base OBJ plus a folder of sparse ``.target`` files (``index dx dy dz``), both in decimetres."""
    neutral, faces = read_obj(base_obj, unit_m=unit_m)
    _check_surface(Path(base_obj), neutral, faces)
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
    try:
        return BlendshapeRig.create(neutral, deltas, faces, [p.stem for p in files], name=Path(base_obj).stem,
                                    check_units=False)
    except KDInputError as e:
        raise KDInputError(f"{tdir}: {e}") from None
