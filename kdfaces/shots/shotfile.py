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
from ..deprecation import warn_renamed
from ..errors import KDInputError
from ..ikd.bases import make_basis
from ..ikd.constraints import (
    Constraint,
    end_effector_constraint,
    pose_constraint,
    subset_constraint,
    velocity_constraint,
)
from ..ikd.solver import build_correction
from ..io.rigfiles import read_obj
from ..motion.curves import KeyframeCurve
from ..motion.joints import JointDrive, SkeletonAnimation
from ..motion.trajectory import FaceAnimation, KinematicTrajectory, ShapeTrack
from ..rig.groups import vertex_group
from ..rig.parts import part_vertices, rigid_pieces
from ..rig.poses import kinematic_pose
from .schema import RENAMED_KEYS, ShotFile, validate_shot

__all__ = ["Shot", "load_shot", "parse_shot", "read_shot_table", "dynamics_model", "settle_time", "DYNAMICS_DEFAULTS",
           "SOLVER_DEFAULTS"]

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
                                                   strict=self.strict_channels)
        return self._trajectory

    @property
    def step_s(self) -> float:
        """The simulation step [s]: ``[dynamics] step_s``, by default the animation's frame interval."""
        s = self.dynamics["step_s"]
        return 1.0 / self.animation.fps if s == "frame" else float(s)

    @property
    def step(self) -> float:
        """Deprecated name of :attr:`step_s`."""
        warn_renamed("Shot", "step", "step_s")
        return self.step_s

    def settle_time(self):
        """Scalar settle time [s] or the per-vertex (N,) map of the dynamics section (parts included)."""
        return settle_time(self.dynamics, self.rig, where=f"{self.path}: dynamics")

    def rigid(self) -> np.ndarray:
        """(N,) bool: vertices that follow x_K exactly (``[dynamics.parts]`` rigid parts and, with ``auto_rigid``,
        the pieces no shape deforms)."""
        return rigid_vertices(self.dynamics, self.rig, where=f"{self.path}: dynamics")

    def model(self, **overrides):
        """The face dynamics model of the shot's ``[dynamics]`` (keyword overrides for FaceModel.create)."""
        return dynamics_model(self.dynamics, self.rig, where=f"{self.path}: dynamics", **overrides)

    def constraints(self, trajectory=None) -> list[Constraint]:
        """The shot's constraints, targets resolved against ``trajectory`` (default the kinematic trajectory)."""
        traj = self.trajectory if trajectory is None else trajectory
        out = [self._constraint(t, i, traj) for i, t in enumerate(self.constraint_tables)]
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
        if not (a.start <= t <= a.end):
            raise KDInputError(f"{where}.time_s: {t} s is outside the shot [{a.start}, {a.end}] s")
        kind = c["kind"]
        basis = make_basis(c["curve"], t, width_s=c["width_s"], ease_out_s=c["ease_out_s"])
        label = c["label"] if c["label"] is not None else f"{kind}@{t:g}s"
        n = self.rig.num_vertices
        tt = c["target"] if isinstance(c["target"], dict) else {}
        group = vertex_group(self.rig, c["group"], where=f"{where}.group") if c["group"] is not None else None
        falloff = defaults.FALLOFF_M if c.get("falloff_m") is None else float(c["falloff_m"])
        if c.get("falloff_m") is not None and kind == "pose":
            raise KDInputError(f"{where}.falloff_m: applies to subset, velocity and end_effector constraints, not to a "
                               "pose constraint (it covers every vertex)")
        if kind in ("pose", "subset", "end_effector"):
            if tt.get("obj") is not None:
                try:
                    pose, _ = read_obj(self.path.parent / tt["obj"], scale=self.rig.source_unit_m)
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


def settle_time(dynamics: dict, rig, *, where: str = "dynamics"):
    """The settle time [s] of a ``[dynamics]`` table: a number, or a per-vertex (N,) map (the soft-tissue map, and
    parts with their own ``settle_time_s``)."""
    from ..dynamics.gains import soft_tissue_settle_map

    st = dynamics["settle_time_s"]
    base = soft_tissue_settle_map(rig, stiff_s=st["stiff_s"], loose_s=st["loose_s"]) if isinstance(st, dict) \
        else float(st)
    own = {name: p for name, p in (dynamics.get("parts") or {}).items() if p.get("settle_time_s") is not None}
    if not own:
        return base
    out = np.broadcast_to(np.asarray(base, dtype=np.float64), (rig.num_vertices,)).copy()
    for name, p in own.items():
        out[part_vertices(rig, name, where=f"{where}.parts.{name}")] = float(p["settle_time_s"])
    return out


def rigid_vertices(dynamics: dict, rig, *, where: str = "dynamics") -> np.ndarray:
    """(N,) bool: the ``[dynamics]`` table's rigid vertices (see :meth:`Shot.rigid`)."""
    mask = rigid_pieces(rig) if dynamics.get("auto_rigid", True) else np.zeros(rig.num_vertices, dtype=bool)
    for name, p in (dynamics.get("parts") or {}).items():
        if p.get("rigid") is not None:
            mask[part_vertices(rig, name, where=f"{where}.parts.{name}")] = bool(p["rigid"])
    return mask


def dynamics_model(dynamics: dict, rig, *, where: str = "dynamics", **overrides):
    """A :class:`~kdfaces.dynamics.FaceModel` on ``rig`` from a ``[dynamics]`` table (defaults filled in)."""
    from ..dynamics import FaceModel

    d = {**DYNAMICS_DEFAULTS, **dynamics}
    rigid = rigid_vertices(d, rig, where=where)
    kwargs = dict(settle_time_s=settle_time(d, rig, where=where), damping_ratio=float(d["damping_ratio"]),
                  shape_matching_alpha=float(d["shape_matching_alpha"]), damping_mode=d["damping_mode"],
                  areal_density_kg_m2=float(d["areal_density_kg_m2"]), rigid=rigid if rigid.any() else None)
    kwargs.update(overrides)
    return FaceModel.from_rig(rig, **kwargs)


def _animation(a, base: Path, where: str, rig) -> FaceAnimation:
    from ..io.livelinkface import livelinkface_animation
    from .builtin import demo_animation

    if a.source == "demo":
        anim = demo_animation()
        start = anim.start if a.start_s is None else a.start_s
        end = anim.end if a.end_s is None else a.end_s
        if not anim.start <= start < end <= anim.end:
            raise KDInputError(f"{where}: start_s, end_s: the demo animation runs [{anim.start:g}, {anim.end:g}] s; "
                               f"got [{start:g}, {end:g}]")
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
        if a.end_s is None:
            raise KDInputError(f"{where}: keyed animations need 'end_s'")
        start = 0.0 if a.start_s is None else a.start_s
        if not a.end_s > start:
            raise KDInputError(f"{where}.end_s: expected end_s > start_s ({start:g} s), got {a.end_s:g}")
        return FaceAnimation(tuple(tracks), SkeletonAnimation(drives), start, a.end_s, a.fps or 25.0, name="keys")
    kwargs = {"fps": a.fps}
    if a.start_s is not None:
        kwargs["start"] = a.start_s
    if a.end_s is not None:
        kwargs["end"] = a.end_s
    return livelinkface_animation(base / a.source, **kwargs)


def _curve(times, values, interpolation: str, where: str) -> KeyframeCurve:
    v = np.asarray(values, dtype=np.float64)
    if interpolation == "ease":  # Hermite with zero tangents: every key is an ease-in/ease-out hold
        return KeyframeCurve.create(times, v, interpolation="hermite", tangents=np.zeros_like(v), where=where)
    return KeyframeCurve.create(times, v, interpolation=interpolation, where=where)


def parse_shot(data: dict, path, *, rig=None, rig_units: str | None = None, cache_dir=None) -> Shot:
    """A :class:`Shot` from parsed TOML ``data``; ``path`` names the file in errors and anchors relative paths.

    ``rig`` (a path, "default", or a loaded :class:`~kdfaces.rig.BlendshapeRig`) replaces the file's
    ``[rig] source``; ``rig_units`` its ``units``. ``cache_dir`` keeps parsed OBJ-folder rigs by content hash.
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
            rig_obj = load_rig(rig_path, units=units, scale=scale, cache_dir=cache_dir)
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
    return shot


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
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise KDInputError(f"{p}: not valid TOML ({e})") from None


def load_shot(path, *, rig=None, rig_units: str | None = None, cache_dir=None) -> Shot:
    """Read and validate a TOML shot file (``rig`` and ``rig_units`` replace its ``[rig]`` source and units)."""
    return parse_shot(read_shot_table(path), Path(path), rig=rig, rig_units=rig_units, cache_dir=cache_dir)
