"""Bake and hand-off: an object's KD (and IKD) to a point cache, and the shot file that reproduces it.

Library functions first (no ``bpy`` needed), the Blender glue after them, the operators last and thin:

- :func:`animation_table` / :func:`shot_table` / :func:`write_shot_file`: a shot file (the schema of
  :mod:`kdfaces.shots.schema`) for a rig, its animation, its ``[dynamics]`` and its constraint tables; the rig goes
  next to it as ``<stem>_rig.npz``. ``kdfaces run`` on that file rebuilds the same rig, the same x_K and the same
  constraints, so it computes the same trajectory.
- :func:`bake_shot`: :func:`~kdfaces.shots.run_shot` of a shot with its final trajectory streamed chunk by chunk
  into a point-cache writer (:func:`~kdfaces.io.export.open_export`), exactly as ``kdfaces run --export`` streams
  it: a PC2 bake of the shot is the same bytes as ``kdfaces run --export pc2`` of the shot file. ``cancel()`` is
  asked before each chunk is written; when it says so the writer is discarded (no partial file) and
  :class:`BakeCancelled` is raised.
- Blender: :func:`object_shot` (the object's shot, from the scene-reading module), :func:`bake_object` (bake, then
  a Mesh Cache modifier set up for the cache: format, frame mode, start frame), :func:`export_object_shot`
  ("Export shot file"), :func:`set_scene_from_shot` (fps and frame range from a shot).

Frame numbers (:mod:`kdfaces.blender.scene`): the scene's range [frame_start, frame_end] is the shot
[0, (frame_end − frame_start)/fps] s, shot frame k is scene frame frame_start + k; the Mesh Cache modifier is set
up so that the cache's shot frame k plays there (:func:`mesh_cache_frame_start`). A shot set into a scene
(:func:`set_scene_from_shot`) starts at :data:`kdfaces.defaults.FRAME_START`, the exports' convention.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from kdfaces.errors import KDInputError

__all__ = ["BakeCancelled", "animation_table", "shot_table", "write_shot_file", "bake_shot", "mesh_cache_frame_start",
           "object_shot", "bake_object", "setup_mesh_cache", "export_object_shot", "set_scene_from_shot",
           "BAKE_KINDS", "CLASSES"]

#: What a Blender bake can write: a PC2 point cache (with a Mesh Cache modifier) or USD.
BAKE_KINDS = ("pc2", "usd")
#: The rig written next to an exported shot file ``<stem>.toml``: ``<stem>_rig.npz``.
RIG_SUFFIX = "_rig.npz"


class BakeCancelled(Exception):
    """A bake stopped by its ``cancel`` callback (Esc): nothing was written."""


# --- library: shot files ------------------------------------------------------------------------------------------

def _curve_table(curve, where: str) -> tuple[list, list, str]:
    """(times_s, values, interpolation) of a :class:`~kdfaces.motion.curves.KeyframeCurve` as the shot file writes
    them: linear and Catmull-Rom curves as they are, Hermite curves with zero tangents as ``"ease"`` (the only
    Hermite curve the schema has); anything else is an error naming ``where``."""
    interp = curve.interpolation
    if interp == "hermite":
        if np.any(curve.tangents != 0.0):
            raise KDInputError(f"{where}: a Hermite curve with non-zero tangents has no shot-file form (the schema "
                               "keys 'ease', 'linear' and 'catmull-rom' curves); expected keys of one of those")
        interp = "ease"
    elif interp not in ("linear", "catmull-rom"):
        raise KDInputError(f"{where}: interpolation {interp!r} has no shot-file form")
    return [float(t) for t in curve.times], np.asarray(curve.values, dtype=np.float64).tolist(), interp


def animation_table(animation) -> dict:
    """The ``[animation]`` table (``source = "keys"``) of a :class:`~kdfaces.motion.FaceAnimation`: its shape
    tracks, its head drive (one yaw/pitch/roll drive on the default head-chain shares, written in degrees), start,
    end and fps. Float values are written exactly (TOML keeps every bit of a float), so the shot file's animation
    evaluates to the same numbers. Raises :class:`KDInputError` for what the schema cannot say (a root translation,
    several head drives, drives with other shares, Hermite tangents)."""
    from kdfaces.motion.joints import HEAD_CHAIN_SPLIT

    out = {"source": "keys", "fps": float(animation.fps), "start_s": float(animation.start_s),
           "end_s": float(animation.end_s), "strict": True}
    tracks = []
    for i, tr in enumerate(animation.tracks):
        t, v, interp = _curve_table(tr.curve, f"animation.tracks[{i}]")
        tracks.append({"shapes": [str(n) for n in tr.names], "times_s": t, "values": v, "interpolation": interp})
    if tracks:
        out["tracks"] = tracks
    sk = animation.skeleton
    if sk.root is not None:
        raise KDInputError("animation: a root translation has no shot-file form; expected the head's rotation only")
    if len(sk.drives) > 1:
        raise KDInputError(f"animation: {len(sk.drives)} joint drives; a shot file keys one head drive")
    if sk.drives:
        d = sk.drives[0]
        if dict(d.shares) != dict(HEAD_CHAIN_SPLIT):
            raise KDInputError("animation.head: a drive with its own joint shares has no shot-file form; expected "
                               "the default head-chain split")
        t, v, interp = _curve_table(d.curve, "animation.head")
        deg = np.degrees(np.asarray(v, dtype=np.float64))
        if not np.allclose(np.radians(deg), v, rtol=0, atol=0):
            raise KDInputError("animation.head: the angles do not survive degrees and back exactly")
        out["head"] = {"times_s": t, "yaw_deg": deg[:, 0].tolist(), "pitch_deg": deg[:, 1].tolist(),
                       "roll_deg": deg[:, 2].tolist(), "interpolation": interp}
    return out


def shot_table(*, name: str, rig_source: str, animation, dynamics: dict | None = None, constraints=(),
               solver: dict | None = None, channel_map: dict | None = None) -> dict:
    """A whole shot file as a dict (TOML tables): ``name``, ``[rig] source = rig_source`` (metres),
    :func:`animation_table` of ``animation``, ``[dynamics]`` (settings as in the schema; defaults fill the rest),
    ``[[constraints]]`` (tables as in the schema, e.g. from :func:`kdfaces.blender.ikd.constraint_tables`),
    ``[solver]`` and ``[animation.map]``."""
    table = {"name": str(name), "rig": {"source": str(rig_source), "units": "m"},
             "animation": animation_table(animation)}
    if channel_map:
        table["animation"]["map"] = dict(channel_map)
    if dynamics:
        table["dynamics"] = {k: v for k, v in dynamics.items() if v is not None}
    if constraints:
        table["constraints"] = [{k: v for k, v in c.items() if v is not None} for c in constraints]
    if solver:
        table["solver"] = dict(solver)
    return table


def _toml(value):
    import tomlkit

    if isinstance(value, dict):
        t = tomlkit.table()
        for k, v in value.items():
            t[k] = _toml(v)
        return t
    if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        aot = tomlkit.aot()
        for v in value:
            aot.append(_toml(v))
        return aot
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, dict | list | tuple):
        return tomlkit.item(_plain(value))
    return tomlkit.item(value)


def _plain(value):
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def _shot_name(name: str) -> str:
    """A file-safe stem from an object name (letters, digits, ``-``, ``_``; others become ``_``)."""
    out = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in str(name)).strip("_")
    return out or "shot"


def write_shot_file(path, rig, animation, *, dynamics: dict | None = None, constraints=(), solver: dict | None = None,
                    name: str | None = None, channel_map: dict | None = None) -> Path:
    """Write the shot file ``path`` (``.toml``) and its rig ``<stem>_rig.npz`` beside it (both atomically, the rig
    first); returns ``path``. The shot's ``name`` defaults to the file stem. Parsed back
    (:func:`~kdfaces.shots.load_shot`), it is the same shot: the rig's arrays, x_K and the constraints' targets are
    the same numbers (checked here before anything is written)."""
    import tomlkit

    from kdfaces.io.atomic import atomic_path
    from kdfaces.io.rigfiles import save_npz
    from kdfaces.shots.shotfile import parse_shot

    p = Path(path)
    if p.suffix != ".toml":
        raise KDInputError(f"{p}: expected a .toml shot file path")
    rig_path = p.with_name(p.stem + RIG_SUFFIX)
    table = shot_table(name=name or p.stem, rig_source=rig_path.name, animation=animation, dynamics=dynamics,
                       constraints=constraints, solver=solver, channel_map=channel_map)
    parse_shot(table, p, rig=rig)  # the schema's errors now, before a file exists
    doc = tomlkit.document()
    doc.add(tomlkit.comment("written by the kdfaces Blender extension (Export shot file); run: kdfaces run "
                            f"{p.name} --export pc2"))
    for k, v in table.items():
        doc[k] = _toml(v)
    save_npz(rig, rig_path)
    with atomic_path(p, ".toml") as tmp:
        Path(tmp).write_text(tomlkit.dumps(doc), encoding="utf-8")
    return p


# --- library: bakes -----------------------------------------------------------------------------------------------

def bake_shot(shot, path, *, kind: str = "pc2", cancel=None, unit_m: float = 1.0, **run_options):
    """Run ``shot`` (:func:`~kdfaces.shots.run_shot`: KD of every frame, IKD for its constraints) and stream its
    final trajectory into the point cache ``path`` (``kind`` ``"pc2"``, ``"usd"`` or ``"usda"``; lengths in units of
    ``unit_m`` metres). The writer is the one ``kdfaces run --export`` opens, with the same arguments, and it
    receives the same chunks: a PC2 bake is byte for byte that command's PC2 of the same shot file.

    ``cancel``: a callable asked before each chunk is written; when it returns True the bake stops, the writer
    discards its temporary file (nothing appears at ``path``) and :class:`BakeCancelled` is raised.
    ``run_options`` go to :func:`~kdfaces.shots.run_shot`. Returns ``(path, run)``.
    """
    from kdfaces.io.export import open_export
    from kdfaces.shots.run import run_shot

    a = shot.animation
    writer = open_export(Path(path), a.frame_times, kind=kind, num_vertices=shot.rig.num_vertices, rig=shot.rig,
                         fps=a.fps, name=shot.name, unit_m=unit_m)

    def sink(lo, hi, x):
        if cancel is not None and cancel():
            raise BakeCancelled(f"bake of {shot.name!r} cancelled at frame {lo} of {len(a.frame_times)}; nothing "
                                "was written")
        writer.write(x)

    with writer:
        run = run_shot(shot, sinks=[sink], **run_options)
    return writer.path, run


def mesh_cache_frame_start(scene_start_frame: int) -> float:
    """The Mesh Cache modifier's ``frame_start`` that shows shot frame 0 of a PC2 written by
    :func:`~kdfaces.io.pointcache.write_pc2` at ``scene_start_frame`` (and shot frame k at start + k): in "Frame"
    time mode the modifier shows sample ``scene frame − frame_start``, and the writer puts
    :data:`~kdfaces.io.pointcache.PC2_FRAME_OFFSET` samples before shot frame 0."""
    from kdfaces.io import pointcache

    return float(scene_start_frame - getattr(pointcache, "PC2_FRAME_OFFSET", 0))


# --- Blender ------------------------------------------------------------------------------------------------------

def _dynamics(obj, scene) -> dict:
    """The ``[dynamics]`` table of the object's KD settings and the window its live KD uses (the automatic window
    resolved to seconds, so ``kdfaces run`` simulates with exactly that δ)."""
    from .scene import kd_settings, object_window

    s = kd_settings(obj)
    settle = float(s.stiff_s) if s.stiff_s == s.loose_s else {"stiff_s": float(s.stiff_s),
                                                               "loose_s": float(s.loose_s)}
    window = object_window(obj, scene)
    return {"settle_time_s": settle, "damping_ratio": float(s.damping_ratio),
            "shape_matching_alpha": float(s.shape_matching_alpha),
            "window_s": window if isinstance(window, str) else float(window)}


def object_shot_settings(obj, scene) -> dict:
    """What the object's shot depends on besides its constraints (hashes of the rig and the animation, the KD
    settings and window): a stored IKD correction is current while these and the constraints are unchanged."""
    from .scene import object_entry

    e = object_entry(obj, scene)
    return {"rig": e.rig_key.hex(), "animation": e.anim_key.hex(), "dynamics": _dynamics(obj, scene)}


def object_shot_table(obj, scene, *, constraints=None, rig_source: str = "rig.npz") -> dict:
    """The object's shot file as a dict: its rig (``rig_source``), shape-key animation over the scene's range,
    ``[dynamics]`` from its KD settings, and its IKD constraints (``constraints``: tables, default
    :func:`kdfaces.blender.ikd.constraint_tables`)."""
    from .ikd import constraint_tables
    from .scene import object_animation

    tables = constraint_tables(obj, scene) if constraints is None else list(constraints)
    return shot_table(name=_shot_name(obj.name), rig_source=rig_source, animation=object_animation(obj, scene),
                      dynamics=_dynamics(obj, scene), constraints=tables)


def object_shot(obj, scene, *, constraints=None, path=None):
    """The object's :class:`~kdfaces.shots.Shot` (:func:`object_shot_table` parsed with the object's rig):
    what "Export shot file" writes, in memory. ``path`` names it in messages (default ``<object>.toml``)."""
    from kdfaces.shots.shotfile import parse_shot

    from .scene import object_rig

    table = object_shot_table(obj, scene, constraints=constraints)
    where = Path(path) if path is not None else Path(f"{_shot_name(obj.name)}.toml")
    return parse_shot(table, where, rig=object_rig(obj, scene))


def export_object_shot(obj, scene, path) -> Path:
    """"Export shot file": write ``path`` (``.toml``) and ``<stem>_rig.npz`` for ``obj`` (see
    :func:`write_shot_file`); ``kdfaces run PATH --export pc2`` then writes what :func:`bake_object` writes."""
    from .ikd import constraint_tables
    from .scene import object_animation, object_rig

    p = Path(path)
    return write_shot_file(p, object_rig(obj, scene), object_animation(obj, scene), dynamics=_dynamics(obj, scene),
                           constraints=constraint_tables(obj, scene), name=p.stem)


def setup_mesh_cache(obj, scene, path, *, name: str = "KD cache"):
    """Add (or reuse) ``obj``'s Mesh Cache modifier ``name`` playing the PC2 ``path``: format PC2, time mode
    "Frame" in scene time, the start frame that puts shot frame k at scene frame frame_start + k
    (:func:`mesh_cache_frame_start`), the toolkit's y-up axes (the modifier's forward +Z, up −Y: what turns the
    file's points p into :func:`kdfaces.blender.scene.from_kd` (p), checked in tests/test_blender_ikd_bake.py), last
    in the stack. Returns the modifier."""
    mod = obj.modifiers.get(name)
    if mod is None or mod.type != "MESH_CACHE":
        mod = obj.modifiers.new(name=name, type="MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = str(Path(path).resolve())
    mod.time_mode = "FRAME"
    mod.play_mode = "SCENE"
    mod.frame_start = mesh_cache_frame_start(int(scene.frame_start))
    mod.frame_scale = 1.0
    mod.forward_axis = "POS_Z"
    mod.up_axis = "NEG_Y"
    mod.deform_mode = "OVERWRITE"
    mod.interpolation = "LINEAR"
    mod.factor = 1.0
    return mod


def bake_object(obj, scene, path, *, kind: str = "pc2", cancel=None, modifier: bool = True):
    """Bake ``obj``'s KD (and IKD, when it has constraints) over the scene's range to the point cache ``path``:
    :func:`bake_shot` of :func:`object_shot` (so the PC2 is byte for byte ``kdfaces run --export pc2`` of the
    exported shot file), in metres (scene unit scale 1) or Blender units. With a PC2 and ``modifier``, the object
    gets a Mesh Cache modifier playing it (:func:`setup_mesh_cache`); the run's IKD correction is stored with the
    object. ``cancel()`` (Esc) is asked before each chunk: then :class:`BakeCancelled` is raised, no file is left
    and the scene is as it was. Returns ``(path, run)``."""
    from .ikd import constraint_tables, constraints_key, store_correction
    from .scene import scene_unit_m

    if kind not in BAKE_KINDS:
        raise KDInputError(f"bake kind {kind!r}: expected one of {list(BAKE_KINDS)}")
    tables = constraint_tables(obj, scene)
    shot = object_shot(obj, scene, constraints=tables)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    written, run = bake_shot(shot, p, kind=kind, cancel=cancel, unit_m=scene_unit_m(scene))
    if run.ikd_result is not None:
        r = run.ikd_result
        store_correction(obj, r.correction, key=constraints_key(tables, object_shot_settings(obj, scene)),
                         report={"reason": r.reason, "converged": bool(r.converged), "iterations": int(r.iterations),
                                 "wall_s": float(r.wall_s), "window_s": float(run.window_s),
                                 "labels": [c.label for c in r.constraints],
                                 "errors_m": [float(x) for x in r.errors_after],
                                 "units": [c.unit for c in r.constraints], "warm": False})
    if kind == "pc2" and modifier:
        setup_mesh_cache(obj, scene, written)
    return written, run


def set_scene_from_shot(scene, shot, *, start_frame: int | None = None) -> tuple[int, int]:
    """Set ``scene``'s fps (``render.fps``/``fps_base``: an integer rate exactly, else the nearest fraction with
    base 1.001 or the rate over 1000) and its frame range to the shot's: shot frame k at scene frame
    ``start_frame + k`` (default :data:`kdfaces.defaults.FRAME_START`). Returns the range."""
    from kdfaces import defaults

    fps = float(shot.animation.fps)
    start = int(defaults.FRAME_START if start_frame is None else start_frame)
    if abs(fps - round(fps)) < 1e-9:
        scene.render.fps, scene.render.fps_base = int(round(fps)), 1.0
    elif abs(fps * 1.001 - round(fps * 1.001)) < 1e-6:
        scene.render.fps, scene.render.fps_base = int(round(fps * 1.001)), 1.001
    else:
        base = math.ceil(fps) / fps
        scene.render.fps, scene.render.fps_base = int(math.ceil(fps)), base
    scene.frame_start = start
    scene.frame_end = start + shot.animation.num_frames - 1
    return scene.frame_start, scene.frame_end


# --- operators ----------------------------------------------------------------------------------------------------

bpy = sys.modules.get("bpy")  # loaded inside Blender; not imported elsewhere (see kdfaces.blender.ikd)

CLASSES = ()
if bpy is not None:
    import threading

    class KDFACES_OT_bake(bpy.types.Operator):
        """Bake the active object's KD (and IKD) over the scene's range to a point cache (Esc cancels: no file is
        left and the scene is as it was)"""

        bl_idname = "kdfaces.bake"
        bl_label = "Bake KD"
        bl_options = {"REGISTER"}

        filepath: bpy.props.StringProperty(name="File", subtype="FILE_PATH", default="//kd_cache.pc2")
        kind: bpy.props.EnumProperty(name="Format", items=[("pc2", "PC2 + Mesh Cache", ""), ("usd", "USD", "")],
                                     default="pc2")

        @classmethod
        def poll(cls, context):
            ob = context.active_object
            return ob is not None and ob.type == "MESH"

        def _path(self) -> Path:
            p = Path(bpy.path.abspath(self.filepath))
            want = ".pc2" if self.kind == "pc2" else ".usdc"
            return p if p.suffix == want else p.with_suffix(want)

        def execute(self, context):  # the blocking form (background mode, scripts)
            try:
                path, _ = bake_object(context.active_object, context.scene, self._path(), kind=self.kind)
            except Exception as e:  # noqa: BLE001 - one line in the report area
                self.report({"ERROR"}, _one_line(e))
                return {"CANCELLED"}
            self.report({"INFO"}, f"baked {path.name}")
            return {"FINISHED"}

        def invoke(self, context, event):  # modal: the bake runs on a worker thread, Esc sets the cancel flag
            obj, scene = context.active_object, context.scene
            path = self._path()
            # the scene's data is read here, on Blender's thread; the worker only simulates and writes
            try:
                self._shot = object_shot(obj, scene)
            except Exception as e:  # noqa: BLE001
                self.report({"ERROR"}, _one_line(e))
                return {"CANCELLED"}
            self._obj_name, self._path_out = obj.name, path
            self._cancel = threading.Event()
            self._outcome = {}

            def work():
                try:
                    from .scene import scene_unit_m

                    self._outcome["ok"] = bake_shot(self._shot, path, kind=self.kind, cancel=self._cancel.is_set,
                                                    unit_m=scene_unit_m(scene))
                except BaseException as e:  # noqa: BLE001 - reported on Blender's thread
                    self._outcome["error"] = e

            self._thread = threading.Thread(target=work, daemon=True)
            self._thread.start()
            self._timer = context.window_manager.event_timer_add(0.2, window=context.window)
            context.window_manager.modal_handler_add(self)
            return {"RUNNING_MODAL"}

        def modal(self, context, event):
            if event.type == "ESC":
                self._cancel.set()
            if event.type != "TIMER" or self._thread.is_alive():
                return {"RUNNING_MODAL"}
            context.window_manager.event_timer_remove(self._timer)
            if "error" in self._outcome:
                e = self._outcome["error"]
                self.report({"WARNING"} if isinstance(e, BakeCancelled) else {"ERROR"},
                            "bake cancelled; nothing was written" if isinstance(e, BakeCancelled) else _one_line(e))
                return {"CANCELLED"}
            path, run = self._outcome["ok"]
            obj = bpy.data.objects.get(self._obj_name)
            if obj is not None and self.kind == "pc2":
                setup_mesh_cache(obj, context.scene, path)
            self.report({"INFO"}, f"baked {path.name}: {run.num_frames} frames")
            return {"FINISHED"}

    class KDFACES_OT_export_shot(bpy.types.Operator):
        """Write the active object's shot file (TOML) and its rig, for kdfaces run"""

        bl_idname = "kdfaces.export_shot"
        bl_label = "Export shot file"

        filepath: bpy.props.StringProperty(name="File", subtype="FILE_PATH", default="//shot.toml")

        @classmethod
        def poll(cls, context):
            ob = context.active_object
            return ob is not None and ob.type == "MESH"

        def invoke(self, context, event):
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}

        def execute(self, context):
            p = Path(bpy.path.abspath(self.filepath))
            try:
                written = export_object_shot(context.active_object, context.scene, p.with_suffix(".toml"))
            except Exception as e:  # noqa: BLE001
                self.report({"ERROR"}, _one_line(e))
                return {"CANCELLED"}
            self.report({"INFO"}, f"wrote {written.name} and {written.stem}{RIG_SUFFIX}")
            return {"FINISHED"}

    CLASSES = (KDFACES_OT_bake, KDFACES_OT_export_shot)


def _one_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__
