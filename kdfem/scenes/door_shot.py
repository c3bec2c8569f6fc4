"""The door scene's shot file (``kdfem door``, :mod:`kdfem.scenes.door`): its format, validation, and the estimate
of its work made before anything is built.

Shot file (TOML; every key optional except where noted, defaults are the built-in scene ``door.toml``)::

    name = "door"
    [rig]         source = "default"
    [hat]         surface = "default"  # or a closed surface mesh (.obj/.ply/.stl/.off) in metres, on the head
                  youngs_pa = 3000.0, poisson = 0.3, density_kg_m3 = 150.0, rayleigh_alpha = 1.0, rayleigh_beta = 0.01
                  edge_length_fac = 0.09, envelope_fac = 0.004, attach_distance_m = 0.02
    [walk]        speed_mps = 1.2, accelerate_s = 0.5, bob_m = 0.012, step_hz = 1.8, end_s = 2.6, fps = 100
    [door]        lintel_y_m = 1.012, front_z_m = 1.32, depth_m = 0.15, width_m = 0.9
    [kd]          window_s = 0.568, step_s = 0.01
    [[constraints]]  kind = "point"      # the tip at t_i: point = "tip" | { surface_vertex = i } | { node = i }
                     time_s = "collision"  # or seconds;  target = "below_lintel" or { point_m = [x, y, z] }
                     margin_m = 0.005, width_s = 0.2, curve = "gaussian"
    [[constraints]]  kind = "below"      # a point below the lintel minus margin_m at time_s (an inequality)
    [[constraints]]  kind = "clearance"  # every surface vertex under the door, over the pass (or start_s/end_s)
                     margin_m = 0.005, width_s = 0.2, adds = "point"  # or "plane": what a violation adds
    [solver]      update = "secant", step_scale = 1.0, tolerance_m = 1e-5, max_iterations = 20, max_rounds = 8
    [output]      movie = true, movie_fps = 25, filmstrip_columns = 5

Paths are relative to the shot file. Errors name the file and the dotted field. The work is estimated before
anything is built: frames (walk.end_s × walk.fps + 1) × the steps of one KD window (kd.window_s / kd.step_s) beyond
:data:`DOOR_MAX_STEPS`, or arrays over the frames beyond the memory budget, refuse the shot in one line naming the
field to change.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from kdfaces import defaults
from kdfaces.errors import KDInputError

__all__ = ["DOOR_SHOT", "DOOR_MAX_STEPS", "DoorShot", "load_door_shot", "check_door_work", "check_door_memory"]

#: The built-in door scene.
DOOR_SHOT = Path(__file__).resolve().parent / "door.toml"
#: The most KD steps a door shot may ask for: its frames (walk.end_s × walk.fps + 1) times the steps of one KD window
#: (kd.window_s / kd.step_s), the work of one pass of KD states over the walk (the run makes a few). The built-in
#: scene asks for 261 × 57 ≈ 15,000; a shot beyond the limit is refused before anything is built.
DOOR_MAX_STEPS = 1_000_000
#: The built-in scene's frame rate [1/s], walk length [s] and KD steps per window: which field a refused estimate
#: blames is the one furthest above these.
_BUILT_IN_WORK = {"walk.fps": 100.0, "walk.end_s": 2.6, "kd.step_s": 57.0}  # (kd.step_s: steps per window)

Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
Vec3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]


class _Table(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class _Rig(_Table):
    source: str = "default"


class _Hat(_Table):
    surface: str = "default"
    youngs_pa: Positive = 3.0e3
    poisson: Annotated[float, Field(gt=-1, lt=0.5)] = 0.3
    density_kg_m3: Positive = 150.0
    rayleigh_alpha: NonNegative = defaults.RAYLEIGH_ALPHA
    rayleigh_beta: NonNegative = defaults.RAYLEIGH_BETA
    edge_length_fac: Annotated[float, Field(gt=0, lt=1)] = defaults.TET_EDGE_LENGTH_FAC
    envelope_fac: Annotated[float, Field(gt=0, lt=0.1)] = defaults.TET_ENVELOPE_FAC
    attach_distance_m: Positive = 0.02


class _Walk(_Table):
    speed_mps: Finite = 1.2
    accelerate_s: Positive = 0.5
    bob_m: NonNegative = 0.012
    step_hz: Positive = 1.8
    end_s: Positive = 2.6
    fps: Positive = 100.0


class _Door(_Table):
    lintel_y_m: Finite = 1.012
    front_z_m: Finite = 1.32
    depth_m: Positive = 0.15
    width_m: Positive = 0.9


class _KD(_Table):
    window_s: Positive = defaults.HAT_WINDOW_S
    step_s: Positive = defaults.HAT_STEP_S


class _PointRef(_Table):
    surface_vertex: Annotated[int, Field(ge=0)] | None = None
    node: Annotated[int, Field(ge=0)] | None = None


class _Target(_Table):
    point_m: Vec3


class _Constraint(_Table):
    kind: Literal["point", "below", "clearance"]
    point: Literal["tip"] | _PointRef = "tip"
    time_s: Finite | Literal["collision"] = "collision"
    target: Literal["below_lintel"] | _Target = "below_lintel"
    margin_m: NonNegative = 0.005
    width_s: Positive = 0.2
    curve: Literal["gaussian", "poly", "asymmetric"] = "gaussian"
    start_s: Finite | None = None
    end_s: Finite | None = None
    adds: Literal["point", "plane"] = "point"
    label: str | None = None


class _Solver(_Table):
    update: Literal["paper", "secant"] = defaults.SOLVER_UPDATE
    step_scale: Annotated[float, Field(gt=0, le=1)] = defaults.STEP_SCALE
    tolerance_m: Positive = defaults.TOLERANCE_M
    max_iterations: Annotated[int, Field(ge=1)] = defaults.MAX_ITERATIONS
    max_rounds: Annotated[int, Field(ge=1)] = 8


class _Output(_Table):
    movie: bool = True
    movie_fps: Positive = 25.0
    filmstrip_columns: Annotated[int, Field(ge=2, le=12)] = 5


class DoorShot(_Table):
    """A parsed door shot file (see the module docstring for its tables and defaults)."""

    name: str = "door"
    rig: _Rig = _Rig()
    hat: _Hat = _Hat()
    walk: _Walk = _Walk()
    door: _Door = _Door()
    kd: _KD = _KD()
    constraints: list[_Constraint] = [_Constraint(kind="point"), _Constraint(kind="clearance")]
    solver: _Solver = _Solver()
    output: _Output = _Output()


def load_door_shot(path=None) -> tuple[DoorShot, Path]:
    """Read and validate a door shot file (default :data:`DOOR_SHOT`); returns (shot, the file's folder).

    One :class:`KDInputError` names the file, the dotted field and what was expected."""
    from kdfaces.shots.schema import dotted

    p = Path(DOOR_SHOT if path is None else path)
    try:
        data = tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise KDInputError(f"{p}: door shot file not found") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise KDInputError(f"{p}: not a readable TOML file ({e})") from None
    if not data:  # an empty file would silently run the built-in scene
        raise KDInputError(f"{p}: the door shot file is empty; expected the tables of a door scene (the built-in one "
                           f"is {DOOR_SHOT})")
    try:
        shot = DoorShot.model_validate(data)
    except ValidationError as e:
        err = e.errors(include_url=False)[0]
        raise KDInputError(f"{p}: {dotted(err['loc'])}: {err['msg']} (got {err.get('input')!r})") from None
    if not shot.constraints:
        raise KDInputError(f"{p}: constraints: expected at least one constraint")
    return shot, p.parent


def check_door_work(shot: DoorShot, *, where: str = "door shot", max_steps: int = DOOR_MAX_STEPS) -> tuple[int, int]:
    """(frames, KD steps per window) of a door shot, refused with one :class:`KDInputError` naming ``where`` and the
    field to change when frames × steps exceed ``max_steps`` (:data:`DOOR_MAX_STEPS`) or the walk cannot go
    forward. Pure arithmetic on the shot's numbers: nothing is built or allocated."""
    w, kd = shot.walk, shot.kd
    if not w.speed_mps > 0:
        raise KDInputError(f"{where}: walk.speed_mps: {w.speed_mps:g} m/s; expected a positive speed (the walk goes "
                           "forward, +z, through the door)")
    frames = float(np.floor(w.end_s * w.fps + 1e-9)) + 1.0  # floats: an absurd fps must not overflow
    steps = float(np.ceil(kd.window_s / kd.step_s - 1e-9))
    if frames * steps > max_steps:
        ratios = {"walk.fps": w.fps / _BUILT_IN_WORK["walk.fps"], "walk.end_s": w.end_s / _BUILT_IN_WORK["walk.end_s"],
                  "kd.step_s": steps / _BUILT_IN_WORK["kd.step_s"]}
        blame = max(ratios, key=ratios.get)
        value = {"walk.fps": f"{w.fps:g} frames/s", "walk.end_s": f"{w.end_s:g} s",
                 "kd.step_s": f"{kd.step_s:g} s"}[blame]
        change = {"walk.fps": "a lower walk.fps (the built-in scene: 100)",
                  "walk.end_s": "a shorter walk.end_s (the built-in scene: 2.6 s)",
                  "kd.step_s": "a longer kd.step_s or a shorter kd.window_s (the built-in scene: 0.01 s, 0.568 s)",
                  }[blame]
        raise KDInputError(f"{where}: {blame}: {value} asks for {frames:.3g} frames × {steps:.3g} KD steps per "
                           f"window = {frames * steps:.3g} steps, more than the limit of {max_steps:,}; expected "
                           f"{change}")
    return int(frames), int(steps)


def check_door_memory(shot: DoorShot, frames: int, nodes: int, surface: int, where: str) -> None:
    """Refuse a shot whose arrays over its frames would not fit the memory budget (before they are allocated): the
    pass's KD states before and after IKD and their surface points (T × (3 N + 4 V) doubles, a few copies), and the
    movie's frames at most as many again."""
    from kdfaces.resources import format_bytes, memory_budget_bytes

    movie_frames = min(frames, int(shot.walk.end_s * shot.output.movie_fps) + 1)
    need = 8 * 3 * (frames + movie_frames) * (3 * nodes + 4 * surface) * 2
    budget = memory_budget_bytes()
    if need > budget:
        raise KDInputError(f"{where}: walk.fps: {shot.walk.fps:g} frames/s over walk.end_s = {shot.walk.end_s:g} s is "
                           f"{frames:,} frames of a {nodes}-node hat, about {format_bytes(need)} of states, more than "
                           f"the memory budget of {format_bytes(budget)}; expected a lower walk.fps or a shorter "
                           "walk.end_s")
