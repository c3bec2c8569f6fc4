"""File › Import › kdfaces shot outputs: a shot's USD, PC2 and glTF/OBJ files into a Blender scene, timed right.

Blender's own importers bring the toolkit's files in faithfully, but none of them sets the scene's frame rate (USD
sets only the frame range, glTF and OBJ nothing) and a PC2 needs a Mesh Cache modifier set up by hand. The library
function :func:`import_shot_outputs` does both; the operator (:data:`CLASSES`, :func:`menu_functions`) is a thin
wrapper around it.

What it does with a shot's files (a folder, or a list of files; ``kdfaces run --export usd --export pc2 --export
pc2-gltf`` and ``kdfaces export-rig --format glb --animation SHOT.toml`` write them):

1. Reads what each file says about time, before touching the scene: ``summary.json`` (``fps``, ``frames``), the
   USD stage (``framesPerSecond``/``timeCodesPerSecond``, start and end time codes), the glTF animation's extras
   (``kdfaces_fps``, ``kdfaces_frame_start``: :func:`~kdfaces.io.gltf.save_gltf`) and each PC2 header (start
   frame, samples; PC2 stores no fps). Disagreeing rates are an error.
2. Sets the scene's fps (``render.fps``/``fps_base``) and frame range: shot frame k at scene frame
   :data:`~kdfaces.defaults.FRAME_START` + k, the exports' convention; so the glTF's keys land on frames.
3. Imports the meshes (glTF, then OBJ) and the USD with Blender's importers.
4. Puts each PC2 on the imported mesh with its vertex count (``<shot>.gltf.pc2`` on the glTF mesh,
   ``<shot>.pc2`` on the OBJ mesh; or on ``target``, e.g. the user's FBX mesh): a Mesh Cache modifier, format PC2,
   time mode "Frame" in scene time, Frame Start = the header's start, axes from the toolkit's y-up file space to
   the imported mesh's z-up space.

Bad input (no such file, nothing to import, an unreadable header, a PC2 that fits no mesh, rates that disagree) is
one :class:`~kdfaces.errors.KDInputError` naming the file; the scene is then left as it was (objects and data
blocks the failed import created are removed, fps and frame range restored).

This module never imports ``bpy`` itself (it uses the one Blender has loaded): the library half
(:func:`shot_timing`) runs anywhere, the operator is defined inside Blender.
"""

from __future__ import annotations

import json
import math
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kdfaces.defaults import FRAME_START
from kdfaces.errors import KDInputError

__all__ = ["ShotTiming", "shot_timing", "import_shot_outputs", "set_scene_fps", "setup_pc2_modifier", "CLASSES",
           "menu_functions", "pc2_axes", "MESH_CACHE_AXES", "IDENTITY_AXES"]

USD_SUFFIXES = (".usd", ".usdc", ".usda")
GLTF_SUFFIXES = (".gltf", ".glb")
#: The Mesh Cache modifier's (forward_axis, up_axis) that maps a PC2 in the toolkit's y-up file space (x, y, z)
#: onto a mesh whose own (local) coordinates are z-up, (x, −z, y), as Blender's glTF importer creates them;
#: measured on Blender 4.5. A mesh whose local coordinates are the file's (the OBJ importer puts the y-up → z-up
#: turn into the object's transform) takes the modifier's defaults, :data:`IDENTITY_AXES`.
#: :func:`setup_pc2_modifier` picks the one that fits the mesh (tests/test_blender_imports.py checks both).
MESH_CACHE_AXES = ("POS_Z", "NEG_Y")
IDENTITY_AXES = ("POS_Y", "POS_Z")
_PC2_HEADER = struct.Struct("<12siiffi")


@dataclass
class ShotTiming:
    """What a shot's files say about time: ``fps`` [1/s] (None if no file says), ``frame_start`` (the scene frame
    of shot frame 0), ``frames`` (count, or None), and the files by kind (``usd``, ``gltf``, ``obj``, ``pc2``: lists
    of paths; ``pc2_points``: each PC2's point count; ``pc2_start``: each PC2's header start)."""

    fps: float | None = None
    frame_start: int = FRAME_START
    frames: int | None = None
    usd: list = field(default_factory=list)
    gltf: list = field(default_factory=list)
    obj: list = field(default_factory=list)
    pc2: list = field(default_factory=list)
    pc2_points: dict = field(default_factory=dict)
    pc2_start: dict = field(default_factory=dict)
    summary: Path | None = None


def _files(paths_or_folder) -> list[Path]:
    items = [paths_or_folder] if isinstance(paths_or_folder, str | Path) else list(paths_or_folder)
    if not items:
        raise KDInputError("import: no files given; expected a shot's output folder or its USD/PC2/glTF/OBJ files")
    out = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            out.extend(sorted(q for q in p.iterdir() if q.is_file()))
        elif p.is_file():
            out.append(p)
        else:
            raise KDInputError(f"{p}: no such file or folder")
    return out


def _pc2_header(p: Path) -> tuple[int, float, int]:
    """(points, start frame, samples) of a PC2 file, checked against its size."""
    data = p.read_bytes()[:_PC2_HEADER.size]
    if len(data) < _PC2_HEADER.size:
        raise KDInputError(f"{p}: shorter than the 32-byte PC2 header")
    sig, version, points, start, _sampling, samples = _PC2_HEADER.unpack(data)
    if sig != b"POINTCACHE2\0" or version != 1 or points <= 0 or samples <= 0:
        raise KDInputError(f"{p}: not a PC2 point cache (signature {sig!r}, version {version}, {points} points, "
                           f"{samples} samples)")
    if p.stat().st_size != _PC2_HEADER.size + 12 * points * samples:
        raise KDInputError(f"{p}: {p.stat().st_size} bytes, expected {_PC2_HEADER.size + 12 * points * samples} "
                           f"for {samples} samples of {points} points")
    return int(points), float(start), int(samples)


def _usd_timing(p: Path) -> tuple[float, float, float]:
    """(framesPerSecond, start time code, end time code) of a USD stage (``pxr``: Blender ships it, so does
    usd-core)."""
    from pxr import Usd

    try:
        stage = Usd.Stage.Open(str(p))
    except Exception as e:  # noqa: BLE001 - USD raises Tf.ErrorException
        raise KDInputError(f"{p}: not a readable USD file ({str(e).strip().splitlines()[-1]})") from None
    if stage is None:
        raise KDInputError(f"{p}: not a readable USD file")
    fps = float(stage.GetFramesPerSecond()) if stage.HasAuthoredMetadata("framesPerSecond") else \
        float(stage.GetTimeCodesPerSecond())
    return fps, float(stage.GetStartTimeCode()), float(stage.GetEndTimeCode())


def _gltf_json(p: Path) -> dict:
    data = p.read_bytes()
    try:
        if data[:4] == b"glTF":  # GLB: 12-byte header, then the JSON chunk (length, type, bytes)
            length, kind = struct.unpack_from("<I4s", data, 12)
            if kind != b"JSON":
                raise ValueError("first chunk is not JSON")
            return json.loads(data[20:20 + length])
        return json.loads(data)
    except (ValueError, struct.error) as e:
        raise KDInputError(f"{p}: not a readable glTF file ({e})") from None


def shot_timing(paths_or_folder) -> ShotTiming:
    """Sort a shot's files by kind and read their timing (step 1 of :func:`import_shot_outputs`; no ``bpy``).

    Raises :class:`KDInputError` for a missing path, no importable file, an unreadable file or rates that disagree.
    """
    t = ShotTiming()
    rates: list[tuple[float, str]] = []
    starts: list[tuple[float, str]] = []
    for p in _files(paths_or_folder):
        suffix = p.suffix.lower()
        if p.name == "summary.json":
            try:
                s = json.loads(p.read_text())
            except (ValueError, OSError) as e:
                raise KDInputError(f"{p}: not a readable summary ({e})") from None
            t.summary = p
            if isinstance(s, dict) and isinstance(s.get("fps"), int | float):
                rates.append((float(s["fps"]), str(p)))
            if isinstance(s, dict) and isinstance(s.get("frames"), int):
                t.frames = int(s["frames"])
        elif suffix in USD_SUFFIXES:
            fps, start, end = _usd_timing(p)
            t.usd.append(p)
            rates.append((fps, str(p)))
            starts.append((start, str(p)))
            t.frames = t.frames or int(round(end - start)) + 1
        elif suffix in GLTF_SUFFIXES:
            doc = _gltf_json(p)
            t.gltf.append(p)
            for anim in doc.get("animations") or []:
                extras = anim.get("extras") if isinstance(anim, dict) else None
                if isinstance(extras, dict) and isinstance(extras.get("kdfaces_fps"), int | float):
                    rates.append((float(extras["kdfaces_fps"]), str(p)))
                    if isinstance(extras.get("kdfaces_frame_start"), int | float):
                        starts.append((float(extras["kdfaces_frame_start"]), str(p)))
        elif suffix == ".obj":
            t.obj.append(p)
        elif suffix == ".pc2":
            points, start, samples = _pc2_header(p)
            t.pc2.append(p)
            t.pc2_points[p], t.pc2_start[p] = points, start
            starts.append((start, str(p)))
            t.frames = t.frames or samples
    if not (t.usd or t.gltf or t.obj or t.pc2):
        raise KDInputError(f"import: no USD, PC2, glTF or OBJ file among {[str(p) for p in _files(paths_or_folder)]}")
    if rates:
        fps, where = rates[0]
        for other, w in rates[1:]:
            if not math.isclose(other, fps, rel_tol=1e-6):
                raise KDInputError(f"{w}: {other:g} fps, but {where} says {fps:g} fps")
        if not (math.isfinite(fps) and fps > 0):
            raise KDInputError(f"{where}: fps {fps!r}; expected a positive rate")
        t.fps = fps
    if starts:
        start, where = starts[0]
        for other, w in starts[1:]:
            if other != start:
                raise KDInputError(f"{w}: the shot's first frame is scene frame {other:g}, but {where} says "
                                   f"{start:g}")
        if start != int(start):
            raise KDInputError(f"{where}: the shot's first frame is scene frame {start:g}; expected a whole frame")
        t.frame_start = int(start)
    return t


# --- Blender ------------------------------------------------------------------------------------------------------

def set_scene_fps(scene, fps: float) -> None:
    """``scene.render.fps``/``fps_base`` for ``fps`` [1/s]: an integer rate exactly, an NTSC rate (29.97 …) as
    n / 1.001, anything else as ceil(fps) / base."""
    if abs(fps - round(fps)) < 1e-9:
        scene.render.fps, scene.render.fps_base = int(round(fps)), 1.0
    elif abs(fps * 1.001 - round(fps * 1.001)) < 1e-6:
        scene.render.fps, scene.render.fps_base = int(round(fps * 1.001)), 1.001
    else:
        scene.render.fps, scene.render.fps_base = int(math.ceil(fps)), math.ceil(fps) / fps


def _pc2_first_sample(path) -> np.ndarray:
    points = _pc2_header(Path(path))[0]
    return np.fromfile(path, dtype="<f4", count=3 * points, offset=_PC2_HEADER.size).reshape(points, 3)


def pc2_axes(obj, path) -> tuple[str, str]:
    """The (forward_axis, up_axis) for a PC2 ``path`` on mesh ``obj``: :data:`MESH_CACHE_AXES` when the mesh's
    local coordinates are the PC2's turned z-up, else :data:`IDENTITY_AXES` (the closer fit of the PC2's first
    sample to the mesh's own vertices, which differ from it by the shot's motion, millimetres to centimetres, not
    by a quarter turn)."""
    x = _pc2_first_sample(path).astype(np.float64)
    co = np.empty(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    z_up = np.stack([x[:, 0], -x[:, 2], x[:, 1]], axis=1)
    return MESH_CACHE_AXES if np.median(np.abs(co - z_up)) < np.median(np.abs(co - x)) else IDENTITY_AXES


def setup_pc2_modifier(obj, path, *, frame_start: float, name: str = "kdfaces cache",
                       axes: tuple[str, str] | None = None):
    """Give ``obj`` a Mesh Cache modifier (added, or the one named ``name``) playing the PC2 ``path``: format PC2,
    time mode "Frame", play mode "Scene", Frame Start ``frame_start`` (sample k at scene frame ``frame_start + k``),
    the modifier's (forward_axis, up_axis) ``axes`` (default: the pair that fits the mesh, :func:`pc2_axes`),
    overwrite, linear interpolation, last in the stack when added. Returns the modifier."""
    mod = obj.modifiers.get(name)
    if mod is None or mod.type != "MESH_CACHE":
        mod = obj.modifiers.new(name=name, type="MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = str(Path(path).resolve())
    mod.time_mode = "FRAME"
    mod.play_mode = "SCENE"
    mod.frame_start = float(frame_start)
    mod.frame_scale = 1.0
    mod.forward_axis, mod.up_axis = pc2_axes(obj, path) if axes is None else axes
    mod.deform_mode = "OVERWRITE"
    mod.interpolation = "LINEAR"
    mod.factor = 1.0
    return mod


_DATA_KINDS = ("objects", "meshes", "materials", "actions", "shape_keys", "cache_files", "images", "collections")


def _snapshot() -> dict:
    import bpy

    return {k: set(getattr(bpy.data, k)) for k in _DATA_KINDS}


def _remove_new(before: dict) -> None:
    """Remove the data blocks created since ``before`` (objects first, then the data they used)."""
    import bpy

    for kind in ("objects", "collections", "meshes", "materials", "actions", "cache_files", "images"):
        coll = getattr(bpy.data, kind)
        for block in set(coll) - before[kind]:
            try:
                coll.remove(block)
            except (ReferenceError, RuntimeError):  # already gone with its owner
                pass


def _import(op, where: Path, **kwargs) -> list:
    """Run a Blender import operator on ``where``; the objects it created."""
    import bpy

    before = set(bpy.data.objects)
    try:
        result = op(filepath=str(where), **kwargs)
    except RuntimeError as e:
        raise KDInputError(f"{where}: Blender could not import it ({str(e).strip().splitlines()[-1]})") from None
    if "FINISHED" not in result:
        raise KDInputError(f"{where}: Blender's importer did not finish ({sorted(result)})")
    return [o for o in bpy.data.objects if o not in before]


def import_shot_outputs(paths_or_folder, *, scene=None, target=None, fps: float | None = None) -> list:
    """Import a shot's outputs into ``scene`` (default: the context's) with the frame rate and range of the shot.

    Args:
        paths_or_folder: a folder (every USD, PC2, glTF, OBJ and ``summary.json`` in it) or a list of files.
        scene: the ``bpy.types.Scene``; default ``bpy.context.scene``.
        target: a mesh object for a PC2 that no imported mesh fits (e.g. the rig's FBX imported by hand); a PC2
            goes on the imported mesh with its vertex count first.
        fps: frames per second [1/s] when no file says (a PC2 alone); a file that says another rate is an error.

    Returns:
        The imported objects (``bpy.types.Object``), meshes with Mesh Cache modifiers among them.

    Raises:
        KDInputError: see the module docstring; the scene is as it was.
    """
    import bpy

    scene = bpy.context.scene if scene is None else scene
    timing = shot_timing(paths_or_folder)
    if fps is not None:
        if not (math.isfinite(fps) and fps > 0):
            raise KDInputError(f"import: fps must be a positive number, got {fps!r}")
        if timing.fps is not None and not math.isclose(fps, timing.fps, rel_tol=1e-6):
            raise KDInputError(f"import: fps {fps:g} given, but the files say {timing.fps:g}")
        timing.fps = float(fps)
    if timing.fps is None:
        raise KDInputError(f"import: no file says the frame rate ({[str(p) for p in timing.pc2]}: PC2 stores "
                           f"none); add the shot's summary.json or USD, or give fps")
    if timing.pc2 and not (timing.gltf or timing.obj) and target is None:
        raise KDInputError(f"{timing.pc2[0]}: a PC2 holds points only; import it with the rig's glTF or OBJ, or "
                           f"give a target mesh with {timing.pc2_points[timing.pc2[0]]} vertices")
    if target is not None and getattr(target, "type", None) != "MESH":
        raise KDInputError(f"import: target {getattr(target, 'name', target)!r} is not a mesh object")
    saved = (scene.render.fps, scene.render.fps_base, scene.frame_start, scene.frame_end, scene.frame_current)
    before = _snapshot()
    try:  # Blender's importers work on the context's scene
        with _nullcontext() if scene == bpy.context.scene else bpy.context.temp_override(scene=scene):
            set_scene_fps(scene, timing.fps)
            if timing.frames is not None:
                scene.frame_start = timing.frame_start
                scene.frame_end = timing.frame_start + max(timing.frames, 1) - 1
            objects = []
            for p in timing.gltf:
                objects += _import(bpy.ops.import_scene.gltf, p)
            for p in timing.obj:
                objects += _import(bpy.ops.wm.obj_import, p)
            meshes = [o for o in objects if o.type == "MESH"]
            for p in timing.usd:
                objects += _import(bpy.ops.wm.usd_import, p, set_frame_range=False)
            for p in timing.pc2:
                points = timing.pc2_points[p]
                fits = [o for o in meshes if len(o.data.vertices) == points]
                if not fits and target is not None and len(target.data.vertices) == points:
                    fits = [target]
                if not fits:
                    counts = {o.name: len(o.data.vertices) for o in meshes + ([target] if target else [])}
                    raise KDInputError(f"{p}: {points} points, but no mesh has that many vertices {counts} (a "
                                       f"glTF mesh takes <shot>.gltf.pc2, an OBJ or FBX mesh <shot>.pc2)")
                for o in fits:
                    setup_pc2_modifier(o, p, frame_start=timing.pc2_start[p])
            scene.frame_set(scene.frame_start)
    except BaseException:
        _remove_new(before)
        scene.render.fps, scene.render.fps_base = saved[0], saved[1]
        scene.frame_start, scene.frame_end = saved[2], saved[3]
        scene.frame_set(saved[4])
        raise
    return objects


class _nullcontext:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


# --- the operator -------------------------------------------------------------------------------------------------

# Blender has imported bpy before any extension module; elsewhere this module never loads it (a bpy module
# installed with pip is heavy and process-global), so the operator exists only inside Blender.
bpy = sys.modules.get("bpy")

CLASSES: tuple = ()


def menu_functions() -> list:
    """(menu, draw function) pairs to append on registration: File › Import › kdfaces shot outputs."""
    if bpy is None:
        return []
    return [(bpy.types.TOPBAR_MT_file_import, _menu_import)]


def register_extra() -> None:
    """Add the File › Import entry (called by the extension's ``register`` after :data:`CLASSES`)."""
    for menu, draw in menu_functions():
        menu.append(draw)


def unregister_extra() -> None:
    for menu, draw in menu_functions():
        menu.remove(draw)


if bpy is not None:
    from bpy.props import CollectionProperty, StringProperty
    from bpy_extras.io_utils import ImportHelper

    class KDFACES_OT_import_shot(bpy.types.Operator, ImportHelper):
        """Import a kdfaces shot's USD, PC2 and glTF/OBJ outputs with the shot's frame rate and range"""

        bl_idname = "kdfaces.import_shot"
        bl_label = "Import kdfaces Shot"
        bl_options = {"REGISTER", "UNDO"}

        filter_glob: StringProperty(default="*.usd;*.usdc;*.usda;*.pc2;*.gltf;*.glb;*.obj;summary.json",
                                    options={"HIDDEN"})
        files: CollectionProperty(type=bpy.types.OperatorFileListElement, options={"HIDDEN", "SKIP_SAVE"})
        directory: StringProperty(subtype="DIR_PATH", options={"HIDDEN", "SKIP_SAVE"})

        def execute(self, context):
            folder = Path(self.directory or Path(self.filepath).parent)
            names = [f.name for f in self.files if f.name]
            paths = [folder / n for n in names] if names else [Path(self.filepath) if self.filepath else folder]
            try:
                objects = import_shot_outputs(paths, scene=context.scene)
            except KDInputError as e:
                self.report({"ERROR"}, str(e))
                return {"CANCELLED"}
            s = context.scene
            self.report({"INFO"}, f"kdfaces: {len(objects)} objects at {s.render.fps / s.render.fps_base:g} fps, "
                                  f"frames {s.frame_start}–{s.frame_end}")
            return {"FINISHED"}

    def _menu_import(self, context):
        self.layout.operator(KDFACES_OT_import_shot.bl_idname, text="kdfaces shot outputs (.usd/.pc2/.glb)")

    CLASSES = (KDFACES_OT_import_shot,)
