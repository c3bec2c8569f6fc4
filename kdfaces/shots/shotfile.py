"""TOML shot files: rig, animation, dynamics, IKD constraints and solver settings in one place.

```toml
name = "smile-on-the-beat"

[rig]
source = "default"                 # or an .npz / glTF / OBJ folder / MakeHuman folder

[animation]
source = "demo"                    # "demo", "keys", or a Live Link Face CSV path
fps = 25                           # optional; start_s / end_s crop a capture
# with source = "keys":  end_s = 3.0  and
# [[animation.tracks]]  shapes = ["mouthSmileLeft"], times_s = [0, 1], values = [[0], [1]], interpolation = "ease"
# [animation.head]      times_s = [...], yaw_deg = [...], pitch_deg = [...], roll_deg = [...]

[dynamics]
settle_time_s = 0.25               # or { stiff_s = 0.12, loose_s = 0.4 } (per-vertex map: loose cheeks and lips)
damping_ratio = 0.3
shape_matching_alpha = 0.2
damping_mode = "relative"          # or "absolute" (the paper's −K_d·ẋ)
window_s = "auto"                  # or seconds
step_s = "frame"                   # the animation's frame interval (default), or seconds

[[constraints]]
time_s = 2.4
kind = "pose"                      # pose | subset | velocity | end_effector
target = "kinematic"               # or a table: weights = {...}, head_deg = [yaw, pitch, roll], obj = "pose.obj",
                                   #   offset_m = [dx, dy, dz], velocity_mps = [vx, vy, vz], point_m = [x, y, z]
group = "lips"                     # subset / velocity / end_effector: a named group or vertex indices
width_s = 0.4                      # the animator's width σ of the correction bell
curve = "gaussian"                 # gaussian | poly | asymmetric (with ease_out_s)
falloff_m = 0.05                   # subset / velocity / end_effector: the correction falls off to zero over this
                                   #   geodesic radius around the group (0: on the group only)

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
from ..ikd.solver import UPDATES, build_correction
from ..io.rigfiles import read_obj
from ..motion.curves import KeyframeCurve
from ..motion.joints import JointDrive, SkeletonAnimation
from ..motion.trajectory import FaceAnimation, KinematicTrajectory, ShapeTrack
from ..rig.groups import vertex_group
from ..rig.poses import kinematic_pose

__all__ = ["Shot", "load_shot", "parse_shot", "read_shot_table", "dynamics_model", "settle_time", "DYNAMICS_DEFAULTS",
           "SOLVER_DEFAULTS"]

DYNAMICS_DEFAULTS = {"settle_time_s": defaults.SETTLE_TIME_S, "damping_ratio": defaults.DAMPING_RATIO,
                     "shape_matching_alpha": defaults.SHAPE_MATCHING_ALPHA, "damping_mode": defaults.DAMPING_MODE,
                     "window_s": defaults.WINDOW_S, "step_s": "frame",
                     "areal_density_kg_m2": defaults.AREAL_DENSITY_KG_M2}
SOLVER_DEFAULTS = {"update": defaults.SOLVER_UPDATE, "step_scale": defaults.STEP_SCALE,
                   "tolerance_m": defaults.TOLERANCE_M, "tolerance_mps": defaults.TOLERANCE_MPS,
                   "max_iterations": defaults.MAX_ITERATIONS, "max_correction_m": defaults.MAX_CORRECTION_M,
                   "snap_to_frames": False}
#: Keys renamed in shot files: the old spelling still works for one release, with a DeprecationWarning.
RENAMED_KEYS = {"dynamics": {"damping": "damping_mode"}, "solver": {"damping": "step_scale"}}
_CONSTRAINT_KEYS = {"time_s", "kind", "target", "group", "width_s", "curve", "ease_out_s", "label", "falloff_m"}


def _renamed(table: dict, section: str, where: str) -> dict:
    out = dict(table)
    for old, new in RENAMED_KEYS.get(section, {}).items():
        if old in out:
            if new in out:
                raise KDInputError(f"{where}: both '{old}' (its old name) and '{new}' are set; keep '{new}'")
            warn_renamed(where, old, new, stacklevel=4)
            out[new] = out.pop(old)
    return out
_TARGET_KEYS = {"weights", "head_deg", "obj", "offset_m", "velocity_mps", "point_m"}


def _keys(table: dict, allowed: set, where: str) -> None:
    extra = set(table) - allowed
    if extra:
        raise KDInputError(f"{where}: unknown key(s) {sorted(extra)}; expected some of {sorted(allowed)}")


def _number(table: dict, key: str, where: str, *, positive: bool = False) -> float:
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
        raise KDInputError(f"{where}.{key}: expected a number, got {v!r}")
    if positive and v <= 0:
        raise KDInputError(f"{where}.{key}: expected a positive number, got {v!r}")
    return float(v)


@dataclass
class Shot:
    """A parsed shot: everything needed to simulate KD and solve IKD.

    ``dynamics`` and ``solver`` hold the settings with defaults filled in; ``constraint_tables`` the raw
    ``[[constraints]]`` tables (build the constraints with :meth:`constraints`).
    """

    path: Path
    name: str
    rig: object
    animation: FaceAnimation
    dynamics: dict
    solver: dict
    constraint_tables: list[dict] = field(default_factory=list)

    @property
    def trajectory(self) -> KinematicTrajectory:
        """The kinematic trajectory x_K of the shot's rig under its animation (built once)."""
        if not hasattr(self, "_trajectory"):
            self._trajectory = KinematicTrajectory(self.rig, self.animation)
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
        """Scalar settle time [s] or the per-vertex (N,) map of the dynamics section."""
        return settle_time(self.dynamics, self.rig)

    def model(self, **overrides):
        """The face dynamics model of the shot's ``[dynamics]`` (keyword overrides for FaceModel.create)."""
        return dynamics_model(self.dynamics, self.rig, **overrides)

    def constraints(self, trajectory=None) -> list[Constraint]:
        """The shot's constraints, targets resolved against ``trajectory`` (default the kinematic trajectory)."""
        traj = self.trajectory if trajectory is None else trajectory
        out = [self._constraint(t, i, traj) for i, t in enumerate(self.constraint_tables)]
        if out:
            build_correction(out, (self.rig.num_vertices, 3))  # same-time conflicts are errors now, not mid-solve
        return out

    def solver_options(self) -> dict:
        """Keyword arguments of :func:`~kdfaces.ikd.solve_ikd` from the ``[solver]`` table (window aside)."""
        s = self.solver
        return dict(update=s["update"], step_scale=float(s["step_scale"]), tolerance_m=float(s["tolerance_m"]),
                    tolerance_mps=float(s["tolerance_mps"]), max_iterations=int(s["max_iterations"]),
                    max_correction_m=float(s["max_correction_m"]), snap_to_frames=bool(s["snap_to_frames"]))

    def _constraint(self, c: dict, i: int, traj) -> Constraint:
        where = f"{self.path}: constraints[{i}]"
        _keys(c, _CONSTRAINT_KEYS, where)
        for key in ("time_s", "kind"):
            if key not in c:
                raise KDInputError(f"{where}: missing '{key}'")
        t = _number(c, "time_s", where)
        a = self.animation
        if not (a.start <= t <= a.end):
            raise KDInputError(f"{where}.time_s: {t} s is outside the shot [{a.start}, {a.end}] s")
        kind = c["kind"]
        width = _number(c, "width_s", where, positive=True) if "width_s" in c else defaults.WIDTH_S
        ease_out = _number(c, "ease_out_s", where, positive=True) if "ease_out_s" in c else None
        basis = make_basis(c.get("curve", defaults.CURVE), t, width_s=width, ease_out_s=ease_out)
        label = str(c.get("label", f"{kind}@{t:g}s"))
        n = self.rig.num_vertices
        target = c.get("target", "kinematic")
        if target != "kinematic" and not isinstance(target, dict):
            raise KDInputError(f"{where}.target: expected \"kinematic\" or a table, got {target!r}")
        tt = target if isinstance(target, dict) else {}
        _keys(tt, _TARGET_KEYS, f"{where}.target")
        group = vertex_group(self.rig, c["group"], where=f"{where}.group") if "group" in c else None
        falloff = _number(c, "falloff_m", where) if "falloff_m" in c else defaults.FALLOFF_M
        if "falloff_m" in c and (kind == "pose" or falloff < 0):
            raise KDInputError(f"{where}.falloff_m: expected non-negative metres on a subset, velocity or "
                               f"end_effector constraint, got {falloff!r} on a {kind} constraint")
        if kind in ("pose", "subset", "end_effector"):
            if "obj" in tt:
                pose, _ = read_obj(self.path.parent / tt["obj"])
                if pose.shape != (n, 3):
                    raise KDInputError(f"{where}.target.obj: {len(pose)} vertices, rig has {n}")
            else:
                pose = kinematic_pose(traj, t, weights=tt.get("weights"), head_deg=tt.get("head_deg"),
                                      where=f"{where}.target")
            if "offset_m" in tt:
                pose = pose + np.asarray(tt["offset_m"], dtype=np.float64)
        if kind == "pose":
            return pose_constraint(t, pose, basis, num_vertices=n, label=label)
        if kind == "subset":
            if group is None:
                raise KDInputError(f"{where}: a subset constraint needs 'group'")
            return subset_constraint(t, pose, group, basis, num_vertices=n, falloff_m=falloff, label=label)
        if kind == "end_effector":
            if group is None:
                raise KDInputError(f"{where}: an end_effector constraint needs 'group' (its vertices)")
            point = np.asarray(tt["point_m"], dtype=np.float64) if "point_m" in tt else pose[group].mean(axis=0)
            return end_effector_constraint(t, point, group, basis, num_vertices=n, falloff_m=falloff, label=label)
        if kind == "velocity":
            if "velocity_mps" in tt:
                v = np.asarray(tt["velocity_mps"], dtype=np.float64)
            else:  # the kinematic velocity of the group: the KD motion passes through t with the animator's speed
                v = traj.evaluate([t], 1)[1][0][group if group is not None else slice(None)]
            return velocity_constraint(t, v, basis, group=group, num_vertices=n, falloff_m=falloff, label=label)
        raise KDInputError(f"{where}.kind: {kind!r} unknown; expected pose, subset, velocity or end_effector")


def settle_time(dynamics: dict, rig):
    """The settle time of a ``[dynamics]`` table: seconds, or the per-vertex (N,) soft-tissue map on ``rig``."""
    st = dynamics["settle_time_s"]
    if isinstance(st, dict):
        from ..dynamics.gains import soft_tissue_settle_map

        return soft_tissue_settle_map(rig, stiff_s=st["stiff_s"], loose_s=st["loose_s"])
    return float(st)


def dynamics_model(dynamics: dict, rig, **overrides):
    """A :class:`~kdfaces.dynamics.FaceModel` on ``rig`` from a ``[dynamics]`` table (defaults filled in)."""
    from ..dynamics import FaceModel

    d = {**DYNAMICS_DEFAULTS, **dynamics}
    kwargs = dict(settle_time_s=settle_time(d, rig), damping_ratio=float(d["damping_ratio"]),
                  shape_matching_alpha=float(d["shape_matching_alpha"]), damping_mode=d["damping_mode"],
                  areal_density_kg_m2=float(d["areal_density_kg_m2"]))
    kwargs.update(overrides)
    return FaceModel.from_rig(rig, **kwargs)


def _animation(table: dict, base: Path, where: str, rig) -> FaceAnimation:
    from ..io.livelinkface import livelinkface_animation
    from .builtin import demo_animation

    _keys(table, {"source", "fps", "start_s", "end_s", "tracks", "head"}, where)
    source = table.get("source", "demo")
    fps = _number(table, "fps", where, positive=True) if "fps" in table else None
    if source == "demo":
        anim = demo_animation()
        if fps:
            anim = FaceAnimation(anim.tracks, anim.skeleton, anim.start, anim.end, fps, anim.name)
        return anim
    if source == "keys":
        tracks = []
        for i, tr in enumerate(table.get("tracks", [])):
            w = f"{where}.tracks[{i}]"
            _keys(tr, {"shapes", "times_s", "values", "interpolation"}, w)
            rig.shape_indices(list(tr["shapes"]), where=f"{w}.shapes")
            tracks.append(ShapeTrack(tuple(tr["shapes"]), _curve(tr["times_s"], tr["values"],
                                                                 tr.get("interpolation", "ease"), w)))
        drives = ()
        if "head" in table:
            hd, w = table["head"], f"{where}.head"
            _keys(hd, {"times_s", "yaw_deg", "pitch_deg", "roll_deg", "interpolation"}, w)
            n = len(hd["times_s"])
            ang = np.radians(np.stack([np.asarray(hd.get(k, [0.0] * n), dtype=np.float64)
                                       for k in ("yaw_deg", "pitch_deg", "roll_deg")], axis=1))
            drives = (JointDrive(_curve(hd["times_s"], ang, hd.get("interpolation", "ease"), w)),)
        if "end_s" not in table:
            raise KDInputError(f"{where}: keyed animations need 'end_s'")
        return FaceAnimation(tuple(tracks), SkeletonAnimation(drives), float(table.get("start_s", 0.0)),
                             _number(table, "end_s", where), fps or 25.0, name="keys")
    path = base / source
    kwargs = {"fps": fps}
    if "start_s" in table:
        kwargs["start"] = _number(table, "start_s", where)
    if "end_s" in table:
        kwargs["end"] = _number(table, "end_s", where)
    return livelinkface_animation(path, **kwargs)


def _curve(times, values, interpolation: str, where: str) -> KeyframeCurve:
    v = np.asarray(values, dtype=np.float64)
    if interpolation == "ease":  # Hermite with zero tangents: every key is an ease-in/ease-out hold
        return KeyframeCurve.create(times, v, interpolation="hermite", tangents=np.zeros_like(v), where=where)
    return KeyframeCurve.create(times, v, interpolation=interpolation, where=where)


def parse_shot(data: dict, path: Path, *, rig=None) -> Shot:
    """A :class:`Shot` from parsed TOML ``data``; ``path`` names the file in errors and anchors relative paths.

    ``rig`` (a path or "default") replaces the file's ``[rig] source``.
    """
    from ..io.rigfiles import load_rig

    path = Path(path)
    where = str(path)
    _keys(data, {"name", "rig", "animation", "dynamics", "constraints", "solver"}, where)
    rig_table = data.get("rig", {})
    _keys(rig_table, {"source"}, f"{where}: rig")
    src = rig_table.get("source", "default") if rig is None else str(rig)
    rig = load_rig(src if src == "default" or rig is not None else path.parent / src)
    anim = _animation(data.get("animation", {}), path.parent, f"{where}: animation", rig)
    dyn = dict(DYNAMICS_DEFAULTS)
    dyn_table = _renamed(data.get("dynamics", {}), "dynamics", f"{where}: dynamics")
    _keys(dyn_table, set(DYNAMICS_DEFAULTS), f"{where}: dynamics")
    dyn.update(dyn_table)
    w = dyn["window_s"]
    if w != "auto" and (isinstance(w, bool) or not isinstance(w, int | float) or not w > 0):
        raise KDInputError(f"{where}: dynamics.window_s: expected \"auto\" or positive seconds, got {w!r}")
    for key in ("damping_ratio", "areal_density_kg_m2"):
        _number(dyn, key, f"{where}: dynamics", positive=True)
    if dyn["step_s"] != "frame":
        _number(dyn, "step_s", f"{where}: dynamics", positive=True)
    st = dyn["settle_time_s"]
    if isinstance(st, dict):
        _keys(st, {"stiff_s", "loose_s"}, f"{where}: dynamics.settle_time_s")
        for key in ("stiff_s", "loose_s"):
            _number(st, key, f"{where}: dynamics.settle_time_s", positive=True)
    else:
        _number(dyn, "settle_time_s", f"{where}: dynamics", positive=True)
    solver = dict(SOLVER_DEFAULTS)
    solver_table = _renamed(data.get("solver", {}), "solver", f"{where}: solver")
    _keys(solver_table, set(SOLVER_DEFAULTS), f"{where}: solver")
    solver.update(solver_table)
    if solver["update"] not in UPDATES:
        raise KDInputError(f"{where}: solver.update: expected one of {UPDATES}, got {solver['update']!r}")
    constraints = data.get("constraints", [])
    if not isinstance(constraints, list):
        raise KDInputError(f"{where}: constraints: expected an array of tables ([[constraints]])")
    shot = Shot(path=path, name=str(data.get("name", path.stem)), rig=rig, animation=anim, dynamics=dyn,
                solver=solver, constraint_tables=constraints)
    shot.constraints()  # validate targets, groups, widths, times and same-time conflicts up front
    return shot


def read_shot_table(path) -> dict:
    """The parsed TOML of a shot file (one clear error when missing or malformed)."""
    p = Path(path)
    if not p.exists():
        raise KDInputError(f"{p}: file not found")
    try:
        return tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as e:
        raise KDInputError(f"{p}: not valid TOML ({e})") from None


def load_shot(path, *, rig=None) -> Shot:
    """Read and validate a TOML shot file (``rig`` replaces its ``[rig] source``)."""
    return parse_shot(read_shot_table(path), Path(path), rig=rig)
