"""TOML shot files: rig, animation, dynamics, IKD constraints and solver settings in one place.

```toml
name = "smile-on-the-beat"

[rig]
source = "default"                 # or an .npz / glTF / OBJ folder / MakeHuman folder
units = "cm"                       # the file's unit: "m" (default), "dm", "cm", "mm"; or scale = 0.01 (m per unit)

[animation]
source = "demo"                    # "demo", "keys", or a Live Link Face CSV path
fps = 25                           # optional; start_s / end_s crop a capture
# with source = "keys":  end_s = 3.0  and
# [[animation.tracks]]  shapes = ["mouthSmileLeft"], times_s = [0, 1], values = [[0], [1]], interpolation = "ease"
# [animation.head]      times_s = [...], yaw_deg = [...], pitch_deg = [...], roll_deg = [...]
# [[animation.joints]]  joint = "neck01", times_s = [...], yaw_rad = [...], pitch_rad = [...], roll_rad = [...]
strict = false                     # a capture channel the rig lacks is skipped with a warning (true: an error)
[animation.map]                    # capture channel → the rig's shape(s); false drops the channel
# browInnerUp = ["browInnerUp_L", "browInnerUp_R"]   (side-split shapes are found by themselves)
# tongueOut = false

[dynamics]
settle_time_s = 0.25               # or { stiff_s = 0.12, loose_s = 0.4 } (per-vertex map: loose cheeks and lips)
damping_ratio = 0.3
shape_matching_alpha = 0.2
damping_mode = "relative"          # or "absolute" (the paper's −K_d·ẋ)
window_s = "auto"                  # or seconds, or "adaptive" (a window per frame, bounded by ε)
step_s = "frame"                   # the animation's frame interval (default), or seconds
auto_rigid = true                  # pieces no shape deforms (teeth, eyeballs) follow x_K exactly
[dynamics.parts]                   # by part (OBJ group / glTF primitive), vertex group, or "piece:<k>"
# teeth = { rigid = true }
# lips = { settle_time_s = 0.5 }

[[constraints]]
time_s = 2.4
kind = "pose"                      # pose | subset | velocity | end_effector
target = "kinematic"               # or a table: weights = {...}, head_deg = [yaw, pitch, roll], obj = "pose.obj",
                                   #   offset_m = [dx, dy, dz], velocity_mps = [vx, vy, vz], point_m = [x, y, z]
group = "lips"                     # subset / velocity / end_effector: a named group or vertex indices
width_s = 0.4                      # the animator's width σ of the correction bell
curve = "gaussian"                 # gaussian | poly | asymmetric (with ease_out_s)
# falloff_m = 0.05                 # subset / velocity / end_effector (not pose): the correction falls off to zero
                                   #   over this geodesic radius around the group (0: on the group only)

[solver]
update = "secant"                  # "paper" (Algorithm 1) or "secant"
step_scale = 1.0                   # 0.8 is the paper's "scaled"
tolerance_m = 1e-5
tolerance_mps = 1e-4
max_iterations = 20
snap_to_frames = false             # move constraints between frames onto the nearest frame (else a warning)
```

Paths inside a shot file are relative to the file. Every error names the file and the field. Defaults come from
:mod:`kdfaces.defaults`, the same ones the Python API uses.
"""

from __future__ import annotations

import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import defaults
from ..deprecation import renamed_attribute, warn_renamed
from ..errors import KDInputError
from ..ikd.bases import make_basis
from ..ikd.constraints import (
    Constraint,
    build_correction,
    end_effector_constraint,
    pose_constraint,
    subset_constraint,
    velocity_constraint,
)
from ..io.rigfiles import read_obj
from ..motion.curves import KeyframeCurve
from ..motion.joints import JointDrive, SkeletonAnimation
from ..motion.trajectory import FaceAnimation, KinematicTrajectory, ShapeTrack
from ..rig.groups import vertex_group
from ..rig.parts import part_vertices, rigid_pieces
from ..rig.poses import kinematic_pose
from .schema import RENAMED_KEYS, ShotFile, validate_shot

__all__ = ["Shot", "load_shot", "parse_shot", "read_shot_table", "dynamics_model", "settle_time", "DYNAMICS_DEFAULTS",
           "SOLVER_DEFAULTS", "WorkEstimate", "estimate_work"]

DYNAMICS_DEFAULTS = ShotFile().dynamics.model_dump()
SOLVER_DEFAULTS = ShotFile().solver.model_dump()


def _renamed(data: dict, where: str) -> dict:
    """``data`` with the old spellings of renamed keys replaced (each with a DeprecationWarning)."""
    out = dict(data)
    for section, names in RENAMED_KEYS.items():
        table = out.get(section)
        if not isinstance(table, dict):
            continue
        table = dict(table)
        for old, new in names.items():
            if old in table:
                if new in table:
                    raise KDInputError(f"{where}: {section}: both '{old}' (its old name) and '{new}' are set; keep "
                                       f"'{new}'")
                warn_renamed(f"{where}: {section}", old, new, stacklevel=4)
                table[new] = table.pop(old)
        out[section] = table
    return out


@dataclass
class Shot:
    """A parsed shot: everything needed to simulate KD and solve IKD.

    ``dynamics`` and ``solver`` hold the settings with defaults filled in (plain dicts); ``constraint_tables`` the
    validated ``[[constraints]]`` tables (build the constraints with :meth:`constraints`); ``channel_map`` and
    ``strict_channels`` say how the animation's channels map onto the rig's shapes.
    """

    path: Path
    name: str
    rig: object
    animation: FaceAnimation
    dynamics: dict
    solver: dict
    constraint_tables: list[dict] = field(default_factory=list)
    channel_map: dict = field(default_factory=dict)
    strict_channels: bool | None = None

    @property
    def trajectory(self) -> KinematicTrajectory:
        """The kinematic trajectory x_K of the shot's rig under its animation (built once)."""
        if not hasattr(self, "_trajectory"):
            self._trajectory = KinematicTrajectory(self.rig, self.animation, channel_map=self.channel_map,
                                                   strict=self.strict_channels, where=f"{self.path}: animation")
        return self._trajectory

    def work_estimate(self, **kwargs) -> WorkEstimate:
        """:func:`estimate_work` of this shot (keyword arguments as there)."""
        return estimate_work(self, **kwargs)

    @property
    def step_s(self) -> float:
        """The simulation step [s]: ``[dynamics] step_s``, by default the animation's frame interval."""
        s = self.dynamics["step_s"]
        return 1.0 / self.animation.fps if s == "frame" else float(s)

    step = renamed_attribute("step_s")

    def settle_time(self):
        """Scalar settle time [s] or the per-vertex (N,) map of the dynamics section (parts included)."""
        return settle_time(self.dynamics, self.rig, where=f"{self.path}: dynamics", channel_map=self.channel_map)

    def rigid(self) -> np.ndarray:
        """(N,) bool: vertices that follow x_K exactly (``[dynamics.parts]`` rigid parts and, with ``auto_rigid``,
        the pieces no shape deforms)."""
        return rigid_vertices(self.dynamics, self.rig, where=f"{self.path}: dynamics", channel_map=self.channel_map)

    def model(self, **overrides):
        """The face dynamics model of the shot's ``[dynamics]`` (keyword overrides for FaceModel.create)."""
        return dynamics_model(self.dynamics, self.rig, where=f"{self.path}: dynamics", channel_map=self.channel_map,
                              **overrides)

    def constraints(self, trajectory=None) -> list[Constraint]:
        """The shot's constraints, targets resolved against ``trajectory`` (default the kinematic trajectory)."""
        traj = self.trajectory if trajectory is None else trajectory
        out = [self._constraint(t, i, traj) for i, t in enumerate(self.constraint_tables)
               if t.get("enabled", True)]  # enabled = false: kept in the file, not solved
        if out:
            build_correction(out, (self.rig.num_vertices, 3), where=str(self.path))  # conflicts: errors now
        return out

    def solver_options(self) -> dict:
        """Keyword arguments of :func:`~kdfaces.ikd.solve_ikd` from the ``[solver]`` table (window aside)."""
        s = self.solver
        return dict(update=s["update"], step_scale=float(s["step_scale"]), tolerance_m=float(s["tolerance_m"]),
                    tolerance_mps=float(s["tolerance_mps"]), max_iterations=int(s["max_iterations"]),
                    max_correction_m=float(s["max_correction_m"]), snap_to_frames=bool(s["snap_to_frames"]))

    def _constraint(self, c: dict, i: int, traj) -> Constraint:
        where = f"{self.path}: constraints[{i}]"
        t = float(c["time_s"])
        a = self.animation
        if not (a.start_s <= t <= a.end_s):
            raise KDInputError(f"{where}.time_s: {t} s is outside the shot [{a.start_s}, {a.end_s}] s")
        kind = c["kind"]
        basis = make_basis(c["curve"], t, width_s=c["width_s"], ease_out_s=c["ease_out_s"])
        label = c["label"] if c["label"] is not None else f"{kind}@{t:g}s"
        n = self.rig.num_vertices
        tt = c["target"] if isinstance(c["target"], dict) else {}
        group = vertex_group(self.rig, c["group"], where=f"{where}.group", channel_map=self.channel_map) \
            if c["group"] is not None else None
        falloff = defaults.FALLOFF_M if c.get("falloff_m") is None else float(c["falloff_m"])
        if c.get("falloff_m") is not None and kind == "pose":
            raise KDInputError(f"{where}.falloff_m: applies to subset, velocity and end_effector constraints, not to a "
                               "pose constraint (it covers every vertex)")
        if kind in ("pose", "subset", "end_effector"):
            if tt.get("obj") is not None:
                try:
                    pose, _ = read_obj(self.path.parent / tt["obj"], unit_m=self.rig.source_unit_m)
                except KDInputError as e:
                    raise KDInputError(f"{where}.target.obj: {e}") from None
                if pose.shape != (n, 3):
                    raise KDInputError(f"{where}.target.obj: {len(pose)} vertices, rig has {n}")
            else:
                pose = kinematic_pose(traj, t, weights=tt.get("weights"), head_deg=tt.get("head_deg"),
                                      where=f"{where}.target")
            if tt.get("offset_m") is not None:
                pose = pose + np.asarray(tt["offset_m"], dtype=np.float64)
        if kind == "pose":
            return self._indexed(pose_constraint(t, pose, basis, num_vertices=n, label=label), i)
        if kind == "subset":
            if group is None:
                raise KDInputError(f"{where}: a subset constraint needs 'group'")
            return self._indexed(subset_constraint(t, pose, group, basis, num_vertices=n, falloff_m=falloff,
                                                        label=label), i)
        if kind == "end_effector":
            if group is None:
                raise KDInputError(f"{where}: an end_effector constraint needs 'group' (its vertices)")
            point = np.asarray(tt["point_m"], dtype=np.float64) if tt.get("point_m") is not None \
                else pose[group].mean(axis=0)
            return self._indexed(end_effector_constraint(t, point, group, basis, num_vertices=n,
                                                              falloff_m=falloff, label=label), i)
        if tt.get("velocity_mps") is not None:
            v = np.asarray(tt["velocity_mps"], dtype=np.float64)
        else:  # the kinematic velocity of the group: the KD motion passes through t with the animator's speed
            v = traj.evaluate([t], 1)[1][0][group if group is not None else slice(None)]
        return self._indexed(velocity_constraint(t, v, basis, group=group, num_vertices=n, falloff_m=falloff,
                                                    label=label), i)

    @staticmethod
    def _indexed(c: Constraint, i: int) -> Constraint:
        import dataclasses

        return dataclasses.replace(c, index=i)


@dataclass(frozen=True)
class WorkEstimate:
    """What simulating a shot will cost, from :func:`estimate_work` (nothing is sampled or simulated to know it).

    Attributes:
        frames: F, the frames of the shot; vertices: N (what the outputs hold); step_s: the simulation step h [s].
        simulated: R, the vertices a step advances (the face model's moving region,
            :func:`~kdfaces.rig.region.moving_region`; N without one): the KD, solve and full-simulation steps count
            R, the window scan (it samples every vertex) and the memory of the output trajectories N.
        window_s: the KD window asked for: seconds, ``"auto"`` or ``"adaptive"``.
        window_steps: n, simulation steps per KD state (``ceil(δ/h)``). Before the automatic window is known it is
            its lower bound 1 (the automatic window is never shorter than a step; 0 for adaptive windows, whose
            per-frame windows are found by their own scan), and ``lower_bound`` is True.
        kd_passes: passes of KD over every frame (2 with constraints: KD and IKD).
        scan_samples: step-grid times the window scans sample x_K at (0: none).
        kd_steps, solve_steps, full_steps, scan_steps: vertex-steps of the KD of every frame, of the IKD solve (its
            sweeps and the independent check), of the full simulations adaptive windows are checked against, and of
            the window scans (each sampled vertex counts :data:`~kdfaces.defaults.SCAN_COST`); their sum is
            :attr:`vertex_steps`, the number :data:`~kdfaces.defaults.MAX_STEPS` bounds.
        memory_bytes: the trajectories of every frame held at once (x_K, x_KD, x_IKD and one working copy; one more
            with adaptive windows) [bytes]; a chunked bake holds a chunk at a time instead.
    """

    path: Path
    frames: int
    vertices: int
    step_s: float
    window_s: object
    window_steps: int
    lower_bound: bool
    kd_passes: int
    scan_samples: int
    kd_steps: float
    solve_steps: float
    full_steps: float
    scan_steps: float
    memory_bytes: int
    simulated: int | None = None

    @property
    def vertex_steps(self) -> float:
        """kd_steps + solve_steps + full_steps + scan_steps [vertex-steps]: what
        :data:`~kdfaces.defaults.MAX_STEPS` bounds."""
        return self.kd_steps + self.solve_steps + self.full_steps + self.scan_steps

    def check(self, max_steps: float | None = defaults.MAX_STEPS, *, max_memory_bytes: int | None = None) -> None:
        """Raise :class:`KDInputError` (one line naming the shot file, the sizes and what to change) when
        :attr:`vertex_steps` exceeds ``max_steps`` (None: no limit) or, given ``max_memory_bytes``,
        :attr:`memory_bytes` exceeds it."""
        from ..resources import format_bytes

        if max_steps is not None and self.vertex_steps > max_steps:
            n = f"{'at least ' if self.lower_bound else ''}{self.window_steps:,} step"
            n += "s" if self.window_steps != 1 else ""
            r = self.vertices if self.simulated is None else self.simulated
            parts = [f"{self.frames:,} frames x {n} per KD state x {r:,} simulated vertices"
                     + (f" x {self.kd_passes} (KD and IKD)" if self.kd_passes > 1 else "")]
            if self.scan_steps:
                parts.append(f"a window scan of {self.scan_samples:,} times")
            if self.solve_steps:
                parts.append("the IKD solve")
            if self.full_steps:
                parts.append("full simulations")
            raise KDInputError(f"{self.path}: {' + '.join(parts)} plan {self.vertex_steps:.3g} vertex-steps, more "
                               f"than --max-steps {max_steps:.3g}; expected a shorter shot (animation.start_s, "
                               "end_s), a lower animation.fps, a shorter dynamics.window_s, or a larger --max-steps")
        if max_memory_bytes is not None and self.memory_bytes > max_memory_bytes:
            raise KDInputError(f"{self.path}: {self.frames:,} frames of {self.vertices:,} vertices need "
                               f"{format_bytes(self.memory_bytes)} for the kinematic, KD and IKD trajectories; "
                               f"expected at most the budget of {format_bytes(max_memory_bytes)} (check animation.fps "
                               "and the shot's length, bake long takes with the chunked bake, or raise --max-memory)")


def estimate_work(shot: Shot, *, window_s=None, solve: bool = True, window_auto_s: float | None = None,
                  scan: bool = True) -> WorkEstimate:
    """The work of simulating ``shot`` as :func:`~kdfaces.shots.run_shot` does, from its sizes alone: frames ×
    steps per KD state × vertices, and memory (see :class:`WorkEstimate`; call :meth:`WorkEstimate.check` to refuse
    beyond a limit). Made before the window scan, the IKD solve or any allocation, so it is instant for any shot.

    ``window_s`` overrides the shot's ``dynamics.window_s`` (seconds, ``"auto"`` or ``"adaptive"``);
    ``window_auto_s``, the automatic window once it is known [s], replaces the lower bound of one step per KD state;
    ``solve``: the IKD solve and the KD of the corrected trajectory are counted when the shot has constraints;
    ``scan``: the automatic window's scan of x_K over the step grid is counted (``run_shot`` always makes it, for
    the summary; a bake only for ``"auto"``).
    """
    from ..kd import window_steps
    from ..window import grid_size

    a = shot.animation
    h = shot.step_s
    frames, vertices = a.num_frames, shot.rig.num_vertices
    sim = _simulated_vertices(shot.rig)  # R: what a step costs (outputs and the scan stay N)
    window = shot.dynamics["window_s"] if window_s is None else window_s
    samples = grid_size(a, h)
    lower = False
    if window == "adaptive":
        n, lower = 0, True
    elif window == "auto":
        if window_auto_s is None:
            n, lower = 1, True
        else:
            n = window_steps(max(float(window_auto_s), h), h)
    elif isinstance(window, str) or isinstance(window, bool) or not isinstance(window, int | float):
        raise KDInputError(f"window: expected positive seconds, 'auto' or 'adaptive', got {window!r}")
    else:
        n = window_steps(float(window), h)
    tables = shot.constraint_tables if solve else []
    states = len(tables) + sum(1 for c in tables if c["kind"] == "velocity")  # velocity: x(t) and x(t − h)
    passes = 2 if tables else 1
    kd = float(passes) * frames * n * sim
    it = int(shot.solver["max_iterations"]) if tables else 0
    solve_steps = float(it + 1) * states * max(n, 1) * sim  # sweeps and the independent check
    adaptive = window == "adaptive"
    full = float(passes) * samples * sim if adaptive else 0.0
    scans = (1 if scan or window == "auto" else 0) + (passes if adaptive else 0)
    scan_steps = float(scans) * samples * vertices * defaults.SCAN_COST
    memory = (4 + adaptive) * frames * vertices * 3 * 8
    return WorkEstimate(path=shot.path, frames=frames, vertices=vertices, step_s=h, window_s=window, window_steps=n,
                        lower_bound=lower, kd_passes=passes, scan_samples=samples if scans else 0, kd_steps=kd,
                        solve_steps=solve_steps, full_steps=full, scan_steps=scan_steps, memory_bytes=int(memory),
                        simulated=sim)


def _simulated_vertices(rig) -> int:
    """R, the vertices the shot's face model simulates: its moving region under the default
    :data:`~kdfaces.defaults.FACE_REGION` ("auto", as :meth:`~kdfaces.dynamics.FaceModel.from_rig` chooses it; a
    rig with no shapes and no skeleton simulates every vertex), N with ``None``."""
    from ..rig.region import moving_region

    if defaults.FACE_REGION is None or not (rig.num_shapes or rig.skeleton is not None):
        return int(rig.num_vertices)
    return len(moving_region(rig))


def settle_time(dynamics: dict, rig, *, where: str = "dynamics", channel_map: dict | None = None):
    """The settle time [s] of a ``[dynamics]`` table: a number, or a per-vertex (N,) map (the soft-tissue map, and
    parts with their own ``settle_time_s``); ``channel_map`` (the shot's ``[animation.map]``) helps the map find the
    rig's soft-tissue shapes."""
    from ..dynamics.gains import soft_tissue_settle_map

    st = dynamics["settle_time_s"]
    base = soft_tissue_settle_map(rig, stiff_s=st["stiff_s"], loose_s=st["loose_s"], channel_map=channel_map) \
        if isinstance(st, dict) else float(st)
    own = {name: p for name, p in (dynamics.get("parts") or {}).items() if p.get("settle_time_s") is not None}
    if not own:
        return base
    out = np.broadcast_to(np.asarray(base, dtype=np.float64), (rig.num_vertices,)).copy()
    for name, p in own.items():
        idx = part_vertices(rig, name, where=f"{where}.parts.{name}", channel_map=channel_map)
        out[idx] = float(p["settle_time_s"])
    return out


def rigid_vertices(dynamics: dict, rig, *, where: str = "dynamics", channel_map: dict | None = None) -> np.ndarray:
    """(N,) bool: the ``[dynamics]`` table's rigid vertices (see :meth:`Shot.rigid`; ``channel_map`` as for
    :func:`settle_time`)."""
    mask = rigid_pieces(rig) if dynamics.get("auto_rigid", True) else np.zeros(rig.num_vertices, dtype=bool)
    for name, p in (dynamics.get("parts") or {}).items():
        if p.get("rigid") is not None:
            mask[part_vertices(rig, name, where=f"{where}.parts.{name}", channel_map=channel_map)] = bool(p["rigid"])
    return mask


def dynamics_model(dynamics: dict, rig, *, where: str = "dynamics", channel_map: dict | None = None, **overrides):
    """A :class:`~kdfaces.dynamics.FaceModel` on ``rig`` from a ``[dynamics]`` table (defaults filled in;
    ``channel_map``, the shot's ``[animation.map]``, as for :func:`settle_time`)."""
    from ..dynamics import FaceModel

    d = {**DYNAMICS_DEFAULTS, **dynamics}
    rigid = rigid_vertices(d, rig, where=where, channel_map=channel_map)
    kwargs = dict(settle_time_s=settle_time(d, rig, where=where, channel_map=channel_map),
                  damping_ratio=float(d["damping_ratio"]),
                  shape_matching_alpha=float(d["shape_matching_alpha"]), damping_mode=d["damping_mode"],
                  areal_density_kg_m2=float(d["areal_density_kg_m2"]), rigid=rigid if rigid.any() else None)
    kwargs.update(overrides)
    return FaceModel.from_rig(rig, **kwargs)


def _animation(a, base: Path, where: str, rig) -> FaceAnimation:
    from ..io.livelinkface import check_stretch, livelinkface_animation, read_livelinkface
    from .builtin import demo_animation

    if a.source == "demo":
        anim = demo_animation()
        start = anim.start_s if a.start_s is None else a.start_s
        end = anim.end_s if a.end_s is None else a.end_s
        if not anim.start_s <= start < end <= anim.end_s:
            raise KDInputError(f"{where}: start_s, end_s: the demo animation runs [{anim.start_s:g}, "
                               f"{anim.end_s:g}] s; got [{start:g}, {end:g}]")
        return FaceAnimation(anim.tracks, anim.skeleton, start, end, a.fps or anim.fps, anim.name)
    if a.source == "keys":
        tracks = []
        for i, tr in enumerate(a.tracks):
            w = f"{where}.tracks[{i}]"
            rig.shape_indices(list(tr.shapes), where=f"{w}.shapes")
            if len(tr.values) != len(tr.times_s) or any(len(row) != len(tr.shapes) for row in tr.values):
                raise KDInputError(f"{w}.values: expected {len(tr.times_s)} rows (one per key in times_s) of "
                                   f"{len(tr.shapes)} numbers (one per shape)")
            tracks.append(ShapeTrack(tuple(tr.shapes), _curve(tr.times_s, tr.values, tr.interpolation, w)))
        drives = ()
        if a.head is not None:
            hd, w = a.head, f"{where}.head"
            n = len(hd.times_s)
            cols = []
            for key in ("yaw_deg", "pitch_deg", "roll_deg"):
                vals = getattr(hd, key)
                if vals is not None and len(vals) != n:
                    raise KDInputError(f"{w}.{key}: expected {n} angles (one per key in times_s), got {len(vals)}")
                cols.append(np.zeros(n) if vals is None else np.asarray(vals, dtype=np.float64))
            drives = (JointDrive(_curve(hd.times_s, np.radians(np.stack(cols, axis=1)), hd.interpolation, w)),)
        for i, jt in enumerate(a.joints):  # one joint's own angles [rad], share 1
            w = f"{where}.joints[{i}]"
            if rig.skeleton is None or jt.joint not in rig.skeleton.names:
                raise KDInputError(f"{w}.joint: {jt.joint!r} is not a joint of rig {rig.name!r} (joints: "
                                   f"{list(rig.skeleton.names) if rig.skeleton is not None else 'none'})")
            n = len(jt.times_s)
            cols = []
            for key in ("yaw_rad", "pitch_rad", "roll_rad"):
                vals = getattr(jt, key)
                if vals is not None and len(vals) != n:
                    raise KDInputError(f"{w}.{key}: expected {n} angles (one per key in times_s), got {len(vals)}")
                cols.append(np.zeros(n) if vals is None else np.asarray(vals, dtype=np.float64))
            drives += (JointDrive(_curve(jt.times_s, np.stack(cols, axis=1), jt.interpolation, w),
                                  shares={jt.joint: 1.0}),)
        if a.end_s is None:
            raise KDInputError(f"{where}: keyed animations need 'end_s'")
        start = 0.0 if a.start_s is None else a.start_s
        if not a.end_s > start:
            raise KDInputError(f"{where}.end_s: expected end_s > start_s ({start:g} s), got {a.end_s:g}")
        return FaceAnimation(tuple(tracks), SkeletonAnimation(drives), start, a.end_s, a.fps or 25.0, name="keys")
    take = read_livelinkface(base / a.source)
    start = 0.0 if a.start_s is None else float(a.start_s)
    end = float(take.times[-1]) if a.end_s is None else float(a.end_s)
    check_stretch(take, start, end, names=(f"{where}.start_s", f"{where}.end_s"))
    return livelinkface_animation(take, fps=a.fps, start_s=start, end_s=end)


def _curve(times, values, interpolation: str, where: str) -> KeyframeCurve:
    v = np.asarray(values, dtype=np.float64)
    if interpolation == "ease":  # Hermite with zero tangents: every key is an ease-in/ease-out hold
        return KeyframeCurve.create(times, v, interpolation="hermite", tangents=np.zeros_like(v), where=where)
    return KeyframeCurve.create(times, v, interpolation=interpolation, where=where)


def parse_shot(data: dict, path, *, rig=None, rig_units: str | None = None, cache_dir=None,
               max_steps: float | None = None) -> Shot:
    """A :class:`Shot` from parsed TOML ``data``; ``path`` names the file in errors and anchors relative paths.

    ``rig`` (a path, "default", or a loaded :class:`~kdfaces.rig.BlendshapeRig`) replaces the file's
    ``[rig] source``; ``rig_units`` its ``units``. ``cache_dir`` keeps parsed OBJ-folder rigs by content hash.
    ``max_steps`` [vertex-steps]: refuse a shot whose :func:`estimate_work` is larger (None: no check here;
    :func:`~kdfaces.shots.run_shot` checks it anyway).

    Beyond the schema, a shot must mean something: an animation in which nothing moves (every channel and head
    angle holds one value, or the channels that change drive no shape of the rig) is an error unless the shot has
    constraints (IKD then makes the motion), and so is an animation none of whose channels drives a shape.
    """
    from ..io.rigfiles import load_rig
    from ..rig.blendshapes import BlendshapeRig

    path = Path(path)
    where = str(path)
    if not isinstance(data, dict):
        raise KDInputError(f"{where}: expected TOML tables")
    f = validate_shot(_renamed(data, where), path)
    if isinstance(rig, BlendshapeRig):
        rig_obj = rig
    else:
        src = f.rig.source if rig is None else str(rig)
        units = rig_units if rig_units is not None else (f.rig.units if rig is None else None)
        scale = f.rig.scale if rig is None and rig_units is None else None
        rig_path = src if src == "default" or rig is not None else path.parent / src
        try:
            rig_obj = load_rig(rig_path, units=units, unit_m=scale, cache_dir=cache_dir, unit_name="scale")
        except KDInputError as e:
            raise KDInputError(f"{where}: rig.source: {e}") from None
    try:
        anim = _animation(f.animation, path.parent, f"{where}: animation", rig_obj)
    except KDInputError as e:
        if str(e).startswith(where):
            raise
        raise KDInputError(f"{where}: animation.source: {e}") from None
    dyn = f.dynamics.model_dump()
    dyn["parts"] = {k: v.model_dump() for k, v in f.dynamics.parts.items()}
    strict = True if anim.strict_channels else f.animation.strict
    step = f.dynamics.step_s
    if step != "frame" and step > anim.duration:
        raise KDInputError(f"{where}: dynamics.step_s: {step:g} s is longer than the shot ({anim.duration:g} s); "
                           "expected a step of at most the frame interval")
    if step != "frame" and step > 1.0 / anim.fps * (1 + 1e-9):
        warnings.warn(f"{where}: dynamics.step_s = {step:g} s is longer than the frame interval "
                      f"{1.0 / anim.fps:g} s: frames between steps are reached by partial steps", stacklevel=3)
    shot = Shot(path=path, name=f.name or path.stem, rig=rig_obj, animation=anim, dynamics=dyn,
                solver=f.solver.model_dump(), constraint_tables=[c.model_dump() for c in f.constraints],
                channel_map=dict(f.animation.map), strict_channels=strict)
    shot.settle_time()  # part names are checked now, not at the first simulation
    shot.constraints()  # validate targets, groups, widths, times and same-time conflicts up front
    if not shot.constraint_tables and not shot.trajectory.moves():
        raise KDInputError(_still_message(shot, f.animation, where))
    if max_steps is not None:
        estimate_work(shot).check(max_steps)
    return shot


def _still_message(shot: Shot, a, where: str) -> str:
    """The error for a shot in which nothing moves: what holds still, and what to change."""
    traj = shot.trajectory
    varying = [str(n) for t in shot.animation.tracks for n, c in zip(t.names, t.curve.constant_channels()) if not c]
    unused = [n for n in varying if traj.channel_resolution.get(n) in ("skipped", "dropped")]
    if unused:
        return (f"{where}: animation: nothing moves: the channel(s) that change ({', '.join(unused[:3])}"
                f"{', ...' if len(unused) > 3 else ''}) drive no shape of rig {shot.rig.name!r}; expected them mapped "
                "in [animation.map] (channel = rig shape)")
    if shot.animation.skeleton.drives and shot.rig.skeleton is None:
        return (f"{where}: animation: nothing moves: only the head turns, and rig {shot.rig.name!r} has no "
                "skeleton; expected blend-shape motion, or a rig with a neck/head skeleton")
    if a.source in ("keys", "demo"):
        return (f"{where}: animation: nothing moves (every track holds one value and the head does not turn), so "
                "KD would return the still pose; expected keys that change (animation.tracks values, "
                "animation.head angles) or [[constraints]] for IKD to meet")
    return (f"{where}: animation.source: nothing moves in {a.source} between {shot.animation.start_s:g} and "
            f"{shot.animation.end_s:g} s (every row holds the same weights and head angles), so KD would return the "
            "still pose; expected a take with motion, another stretch (animation.start_s, end_s), or [[constraints]]")


def read_shot_table(path) -> dict:
    """The parsed TOML of a shot file (one clear error when missing or malformed)."""
    p = Path(path)
    if not p.exists():
        raise KDInputError(f"{p}: file not found")
    if p.is_dir():
        raise KDInputError(f"{p}: expected a TOML shot file, got a folder")
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise KDInputError(f"{p}: not a UTF-8 text file (byte {e.start}); expected a TOML shot file") from None
    except OSError as e:
        raise KDInputError(f"{p}: cannot read ({e.strerror})") from None
    if "\x00" in text:
        raise KDInputError(f"{p}: a binary file, not a TOML shot file")
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise KDInputError(f"{p}: not valid TOML ({e})") from None
    if not table:  # an empty file would silently run the built-in defaults (the demo animation)
        raise KDInputError(f"{p}: the shot file is empty; expected at least an [animation] table (keys, a capture "
                           "or source = \"demo\")")
    return table


def load_shot(path, *, rig=None, rig_units: str | None = None, cache_dir=None,
              max_steps: float | None = None) -> Shot:
    """Read and validate a TOML shot file (``rig`` and ``rig_units`` replace its ``[rig]`` source and units;
    ``max_steps`` refuses a shot whose work estimate is larger, see :func:`parse_shot`)."""
    return parse_shot(read_shot_table(path), Path(path), rig=rig, rig_units=rig_units, cache_dir=cache_dir,
                      max_steps=max_steps)
