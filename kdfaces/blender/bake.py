"""Bake and hand-off: an object's KD (and IKD) to a point cache, and the shot file that reproduces it.

Library functions first (no ``bpy`` needed), the Blender glue after them, the operators last and thin (the shot
file itself is :mod:`kdfaces.blender.shot`):

- :func:`bake_shot`: :func:`~kdfaces.shots.run_shot` of a shot with its final trajectory streamed chunk by chunk
  into a point-cache writer (:func:`~kdfaces.io.export.open_export`), exactly as ``kdfaces run --export`` streams
  it: a PC2 bake of the shot is the same bytes as ``kdfaces run --export pc2`` of the shot file (for a welded
  Blender mesh, :mod:`kdfaces.blender.scene`, the bake stores the mesh's vertices: that command's float32 points
  gathered through the weld, the header's point count the mesh's). ``cancel()`` is
  asked before each chunk is written; when it says so the writer is discarded (no partial file) and
  :class:`BakeCancelled` is raised.
- Blender: :func:`bake_object` (bake, then
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

from kdfaces.errors import KDInputError

from .shot import (
    RIG_SUFFIX,
    Cancelled,
    object_dynamics,
    object_shot,
    object_shot_settings,
    rig_constraint_tables,
    write_shot_file,
)

__all__ = ["BakeCancelled", "bake_shot", "mesh_cache_frame_start", "bake_object", "setup_mesh_cache",
           "export_object_shot", "set_scene_from_shot", "bake_key", "store_run_correction", "BAKE_KINDS", "CLASSES"]

#: What a Blender bake can write: a PC2 point cache (with a Mesh Cache modifier) or USD.
BAKE_KINDS = ("pc2", "usd")


class BakeCancelled(Cancelled):
    """A bake stopped by its ``cancel`` callback (Esc): nothing was written."""


# --- library: bakes -----------------------------------------------------------------------------------------------

def bake_shot(shot, path, *, kind: str = "pc2", cancel=None, unit_m: float = 1.0, vertex_map=None, **run_options):
    """Run ``shot`` (:func:`~kdfaces.shots.run_shot`: KD of every frame, IKD for its constraints) and stream its
    final trajectory into the point cache ``path`` (``kind`` ``"pc2"``, ``"usd"`` or ``"usda"``; lengths in units of
    ``unit_m`` metres). The writer is the one ``kdfaces run --export`` opens, with the same arguments, and it
    receives the same chunks: a PC2 bake is byte for byte that command's PC2 of the same shot file.

    ``vertex_map``: for a PC2, the rig vertex of each vertex of the mesh the cache is for (M,) (a welded Blender
    mesh: :attr:`kdfaces.blender.scene.ObjectEntry.weld`): the file then stores ``positions[:, vertex_map]``, the
    mesh's M points in its order (:class:`~kdfaces.io.pointcache.PC2Writer`'s ``vertex_map``), so its float32
    values are those of ``kdfaces run --export pc2`` gathered through the same map and its header differs only in
    the point count. USD bakes hold the rig's own mesh (its vertices and faces) and ignore it.

    ``cancel``: a callable asked before each chunk is written; when it returns True the bake stops, the writer
    discards its temporary file (nothing appears at ``path``) and :class:`BakeCancelled` is raised.
    ``run_options`` go to :func:`~kdfaces.shots.run_shot`. Returns ``(path, run)``.
    """
    from kdfaces.io.export import open_export
    from kdfaces.io.pointcache import PC2Writer
    from kdfaces.shots.run import run_shot

    a = shot.animation
    if kind == "pc2" and vertex_map is not None:  # the mesh's vertices: the same writer, gathering each block
        writer = PC2Writer(Path(path), a.frame_times, num_vertices=shot.rig.num_vertices, fps=a.fps, unit_m=unit_m,
                           vertex_map=vertex_map)
    else:
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

def export_object_shot(obj, scene, path) -> Path:
    """"Export shot file": write ``path`` (``.toml``) and ``<stem>_rig.npz`` for ``obj`` (see
    :func:`write_shot_file`); ``kdfaces run PATH --export pc2`` then writes what :func:`bake_object` writes (for a
    welded mesh, on the rig's vertices: the bake's PC2 is that cache gathered through
    :attr:`~kdfaces.blender.scene.ObjectEntry.weld`). The constraints name rig vertices
    (:func:`~kdfaces.blender.shot.rig_constraint_tables`)."""
    from .ikd import constraint_tables
    from .scene import object_animation, object_rig

    p = Path(path)
    tables = rig_constraint_tables(obj, scene, constraint_tables(obj, scene))
    return write_shot_file(p, object_rig(obj, scene), object_animation(obj, scene),
                           dynamics=object_dynamics(obj, scene), constraints=tables, name=p.stem)


def setup_mesh_cache(obj, scene, path, *, name: str = "KD cache"):
    """Add (or reuse) ``obj``'s Mesh Cache modifier ``name`` playing the PC2 ``path``: format PC2, time mode
    "Frame" in scene time, the start frame that puts shot frame k at scene frame frame_start + k
    (:func:`mesh_cache_frame_start`), the toolkit's y-up axes (the modifier's forward +Z, up −Y: what turns the
    file's points p into :func:`kdfaces.blender.scene.from_kd` (p), checked in tests/test_blender_ikd_bake.py), last
    in the stack. Returns the modifier."""
    from .importer import MESH_CACHE_AXES, setup_pc2_modifier

    return setup_pc2_modifier(obj, path, frame_start=mesh_cache_frame_start(int(scene.frame_start)), name=name,
                              axes=MESH_CACHE_AXES)


def bake_object(obj, scene, path, *, kind: str = "pc2", cancel=None, modifier: bool = True):
    """Bake ``obj``'s KD (and IKD, when it has constraints) over the scene's range to the point cache ``path``:
    :func:`bake_shot` of :func:`object_shot` (so the PC2 is byte for byte ``kdfaces run --export pc2`` of the
    exported shot file; a welded mesh's PC2 holds the mesh's vertices, that command's float32 points gathered
    through :attr:`~kdfaces.blender.scene.ObjectEntry.weld`, so it drives the mesh Blender has), in metres (scene
    unit scale 1) or Blender units. With a PC2 and ``modifier``, the object
    gets a Mesh Cache modifier playing it (:func:`setup_mesh_cache`); the run's IKD correction is stored with the
    object. ``cancel()`` (Esc) is asked before each chunk: then :class:`BakeCancelled` is raised, no file is left
    and the scene is as it was. Returns ``(path, run)``."""
    from .ikd import constraint_tables
    from .scene import object_entry, scene_unit_m

    if kind not in BAKE_KINDS:
        raise KDInputError(f"bake kind {kind!r}: expected one of {list(BAKE_KINDS)}")
    tables = constraint_tables(obj, scene)
    shot = object_shot(obj, scene, tables)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    written, run = bake_shot(shot, p, kind=kind, cancel=cancel, unit_m=scene_unit_m(scene),
                             vertex_map=object_entry(obj, scene).weld)
    store_run_correction(obj, run, bake_key(obj, scene, tables))
    if kind == "pc2" and modifier:
        setup_mesh_cache(obj, scene, written)
    return written, run


def bake_key(obj, scene, tables) -> str:
    """What a bake's IKD correction is stored under: the constraints ``tables`` and the object's shot settings
    (:func:`~kdfaces.blender.ikd.constraints_key`), read when the bake starts."""
    from .ikd import constraints_key

    return constraints_key(tables, object_shot_settings(obj, scene))


def store_run_correction(obj, run, key: str) -> None:
    """Store ``run``'s IKD correction (if it solved one) with ``obj`` under ``key`` (:func:`bake_key`), with the
    solve's report, as Solve IKD stores its own (:func:`~kdfaces.blender.ikd.store_correction`)."""
    from .ikd import store_correction

    r = run.ikd_result
    if r is None:
        return
    store_correction(obj, r.correction, key=key,
                     report={"reason": r.reason, "converged": bool(r.converged), "iterations": int(r.iterations),
                             "wall_s": float(r.wall_s), "window_s": float(run.window_s),
                             "labels": [c.label for c in r.constraints],
                             "errors_m": [float(x) for x in r.errors_after],
                             "units": [c.unit for c in r.constraints], "warm": False})


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
                from .ikd import constraint_tables

                tables = constraint_tables(obj, scene)
                self._shot = object_shot(obj, scene, tables)
                self._key = bake_key(obj, scene, tables)
            except Exception as e:  # noqa: BLE001
                self.report({"ERROR"}, _one_line(e))
                return {"CANCELLED"}
            from .scene import object_entry, scene_unit_m

            self._obj_name, self._path_out = obj.name, path
            self._cancel = threading.Event()
            self._outcome = {}
            kind, unit_m, shot = str(self.kind), scene_unit_m(scene), self._shot  # no Blender data on the worker
            weld = object_entry(obj, scene).weld

            def work():
                try:
                    self._outcome["ok"] = bake_shot(shot, path, kind=kind, cancel=self._cancel.is_set, unit_m=unit_m,
                                                    vertex_map=weld)
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
            if obj is not None:  # as the blocking bake: the run's IKD correction, then the Mesh Cache
                store_run_correction(obj, run, self._key)
                if self.kind == "pc2":
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

    def draw_bake(layout, context) -> None:
        """The Bake panel: bake to PC2 (Mesh Cache) or USD, and Export shot file."""
        ob = context.active_object
        if ob is None or ob.type != "MESH":
            layout.label(text="Select a mesh with shape keys", icon="INFO")
            return
        row = layout.row(align=True)
        row.operator("kdfaces.bake", text="Bake PC2", icon="FILE_CACHE").kind = "pc2"
        row.operator("kdfaces.bake", text="Bake USD", icon="EXPORT").kind = "usd"
        layout.operator("kdfaces.export_shot", icon="FILE_TEXT")
        md = ob.modifiers.get("KD cache")
        if md is not None and md.type == "MESH_CACHE":
            layout.label(text=f"cache: {Path(md.filepath).name}", icon="MOD_MESHDEFORM")

    def _bake_panel(parent: str, space: str, region: str, **extra):
        name = f"KDFACES_PT_bake_{parent.rsplit('_', 1)[-1]}"
        return type(name, (bpy.types.Panel,),
                    {"bl_label": "Bake and hand-off", "bl_idname": name, "bl_parent_id": parent,
                     "bl_space_type": space, "bl_region_type": region, "bl_options": {"DEFAULT_CLOSED"},
                     "__doc__": "Bake KD/IKD to a point cache, export the shot file",
                     "draw": lambda self, context: draw_bake(self.layout, context), **extra})

    CLASSES = (KDFACES_OT_bake, KDFACES_OT_export_shot,
               _bake_panel("KDFACES_PT_sidebar", "VIEW_3D", "UI", bl_category="KD"),
               _bake_panel("KDFACES_PT_object", "PROPERTIES", "WINDOW", bl_context="object"))


def _one_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__
