"""The shot file schema (pydantic v2): types, ranges and allowed keys of every table, in one place.

Validation is strict — a string is never read as a number, a number never as a path — and every key must be
known. A violation becomes one :class:`~kdfaces.errors.KDInputError` naming the file, the dotted field path
(``constraints[2].target.weights.jawOpen``) and what was expected, with a did-you-mean for a misspelt key. Ranges
that a user could mean but that are physically odd are checked where the physics lives, not here.
"""

from __future__ import annotations

import difflib
import math
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from .. import defaults
from ..errors import KDInputError

__all__ = ["ShotFile", "validate_shot", "dotted", "RENAMED_KEYS"]

#: Keys renamed in shot files: the old spelling still works for one release, with a DeprecationWarning.
RENAMED_KEYS = {"dynamics": {"damping": "damping_mode"}, "solver": {"damping": "step_scale"}}

Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
Vec3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]
# Physical plausibility: ranges a face shot stays within (a value outside is a typo or a unit mix-up, and some would
# ask for terabytes or hours of simulation); the message states the range.
Seconds = Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)]
TimeS = Annotated[float, Field(ge=-1e6, le=1e6, allow_inf_nan=False)]
Weight = Annotated[float, Field(ge=-2, le=2, allow_inf_nan=False)]
Degrees = Annotated[float, Field(ge=-180, le=180, allow_inf_nan=False)]
Metres = Annotated[float, Field(ge=-1, le=1, allow_inf_nan=False)]
Speed = Annotated[float, Field(ge=-100, le=100, allow_inf_nan=False)]
Interp = Literal["ease", "linear", "catmull-rom", "hermite"]


class _Table(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class RigTable(_Table):
    """``[rig]``: the rig file and the unit its numbers are in."""

    source: str = "default"
    units: Literal["m", "dm", "cm", "mm"] | None = None
    scale: Annotated[float, Field(gt=0, le=1e3, allow_inf_nan=False)] | None = None


class TrackTable(_Table):
    """``[[animation.tracks]]``: keys of some shapes' weights."""

    shapes: Annotated[list[str], Field(min_length=1)]
    times_s: Annotated[list[TimeS], Field(min_length=1)]
    values: Annotated[list[list[Weight]], Field(min_length=1)]
    interpolation: Interp = "ease"


class HeadTable(_Table):
    """``[animation.head]``: keys of the head's yaw, pitch and roll [degrees]."""

    times_s: Annotated[list[TimeS], Field(min_length=1)]
    yaw_deg: list[Degrees] | None = None
    pitch_deg: list[Degrees] | None = None
    roll_deg: list[Degrees] | None = None
    interpolation: Interp = "ease"


Radians = Annotated[float, Field(ge=-6.283185307179586, le=6.283185307179586, allow_inf_nan=False)]


class JointTable(_Table):
    """``[[animation.joints]]``: keys of one skeleton joint's own yaw, pitch and roll [rad] (share 1; radians so
    that angles read from a DCC's pose, e.g. the Blender extension's armature, are written bit for bit)."""

    joint: str
    times_s: Annotated[list[TimeS], Field(min_length=1)]
    yaw_rad: list[Radians] | None = None
    pitch_rad: list[Radians] | None = None
    roll_rad: list[Radians] | None = None
    interpolation: Interp = "ease"


class AnimationTable(_Table):
    """``[animation]``: the built-in demo, keys, or a Live Link Face CSV capture."""

    source: str = "demo"
    fps: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] | None = None
    start_s: TimeS | None = None
    end_s: TimeS | None = None
    tracks: list[TrackTable] = []
    head: HeadTable | None = None
    joints: list[JointTable] = []
    map: dict[str, str | list[str] | Literal[False]] = {}
    strict: bool = False


class SettleMapTable(_Table):
    """A per-vertex settle-time map: ``stiff_s`` over bone, ``loose_s`` in cheeks and lips."""

    stiff_s: Seconds
    loose_s: Seconds


class PartTable(_Table):
    """``[dynamics.parts.NAME]``: a part (OBJ group, glTF primitive, vertex group or ``piece:<k>``) made rigid or given
    its own settle time."""

    rigid: bool | None = None
    settle_time_s: Seconds | None = None


class DynamicsTable(_Table):
    """``[dynamics]``: the face's PD tracking, shape matching, KD window and step."""

    settle_time_s: Seconds | SettleMapTable = defaults.SETTLE_TIME_S
    damping_ratio: Annotated[float, Field(ge=1e-3, le=100, allow_inf_nan=False)] = defaults.DAMPING_RATIO
    shape_matching_alpha: Annotated[float, Field(ge=0, le=1)] = defaults.SHAPE_MATCHING_ALPHA
    damping_mode: Literal["relative", "absolute"] = defaults.DAMPING_MODE
    window_s: Literal["auto", "adaptive"] | Seconds = defaults.WINDOW_S
    step_s: Literal["frame"] | Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = "frame"
    areal_density_kg_m2: Annotated[float, Field(gt=0, le=1e4, allow_inf_nan=False)] = defaults.AREAL_DENSITY_KG_M2
    auto_rigid: bool = True
    parts: dict[str, PartTable] = {}


class TargetTable(_Table):
    """A constraint's target: a pose (weights, head angles [deg] or an OBJ), offset by ``offset_m``, or a velocity or
    end-effector point."""

    weights: dict[str, Weight] | None = None
    head_deg: Annotated[list[Degrees], Field(min_length=3, max_length=3)] | None = None
    obj: str | None = None
    offset_m: Annotated[list[Metres], Field(min_length=3, max_length=3)] | None = None
    velocity_mps: Annotated[list[Speed], Field(min_length=3, max_length=3)] | None = None
    point_m: Annotated[list[Annotated[float, Field(ge=-100, le=100, allow_inf_nan=False)]],
                      Field(min_length=3, max_length=3)] | None = None


class ConstraintTable(_Table):
    """``[[constraints]]``: what a KD state must meet at ``time_s``."""

    time_s: TimeS
    kind: Literal["pose", "subset", "velocity", "end_effector"]
    target: Literal["kinematic"] | TargetTable = "kinematic"
    group: str | Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=1)] | None = None
    width_s: Seconds = defaults.WIDTH_S
    curve: Literal["gaussian", "poly", "asymmetric"] = defaults.CURVE
    ease_out_s: Seconds | None = None
    label: str | None = None
    falloff_m: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] | None = None
    enabled: bool = True  # false: kept in the file (the authoring session's disabled rows), not solved


class SolverTable(_Table):
    """``[solver]``: the IKD update, its scale, tolerances and bounds."""

    update: Literal["secant", "paper"] = defaults.SOLVER_UPDATE
    step_scale: Annotated[float, Field(gt=0, le=1)] = defaults.STEP_SCALE
    tolerance_m: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = defaults.TOLERANCE_M
    tolerance_mps: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] = defaults.TOLERANCE_MPS
    max_iterations: Annotated[int, Field(ge=1, le=1000)] = defaults.MAX_ITERATIONS
    max_correction_m: Annotated[float, Field(gt=0, le=10, allow_inf_nan=False)] = defaults.MAX_CORRECTION_M
    snap_to_frames: bool = False


class ShotFile(_Table):
    """A whole shot file."""

    name: str | None = None
    rig: RigTable = RigTable()
    animation: AnimationTable = AnimationTable()
    dynamics: DynamicsTable = DynamicsTable()
    constraints: list[ConstraintTable] = []
    solver: SolverTable = SolverTable()

    @field_validator("constraints", mode="before")
    @classmethod
    def _tables(cls, v):
        if isinstance(v, list) and any(not isinstance(c, dict) for c in v):
            raise ValueError("expected an array of tables ([[constraints]] blocks)")
        return v


def dotted(loc) -> str:
    """``("constraints", 2, "target")`` → ``constraints[2].target``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def _model_at(loc) -> type[BaseModel] | None:
    """The table model that holds the field at ``loc`` (for did-you-mean on unknown keys)."""
    model: type[BaseModel] | None = ShotFile
    for part in loc[:-1]:
        if model is None or isinstance(part, int):
            continue
        field = model.model_fields.get(str(part))
        if field is None:
            return None
        model = _table_type(field.annotation)
    return model


def _table_type(annotation):
    import typing

    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _table_type(arg)
        if found is not None:
            return found
    return None


_TAGS = {"str", "float", "int", "list", "tuple", "bool", "dict"}


def _field_loc(loc) -> tuple:
    """``loc`` without pydantic's union-branch tags (``float``, ``literal['auto']``, ``SettleMapTable``)."""
    return tuple(p for p in loc if not (isinstance(p, str) and (
        "[" in p or p in _TAGS or p.startswith("constrained-") or (p[:1].isupper() and p.endswith("Table")))))


def _shown(value) -> str:
    if isinstance(value, dict | list):
        return type(value).__name__
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _wording(err: dict) -> str:
    import re

    ctx = err.get("ctx") or {}
    if err["type"] in ("too_short", "too_long") and ctx.get("min_length") == ctx.get("max_length", -1):
        return f"Input should be {ctx['min_length']} items"
    if err["type"] == "too_short":
        return f"Input should be at least {ctx.get('min_length')} items"
    if err["type"] == "greater_than" and ctx.get("gt") == 0:
        return "Input should be a positive number"
    if err["type"] == "finite_number":
        return "Input should be a finite number"
    msg = err["msg"].rstrip(".").removeprefix("Value error, ")
    return re.sub(r"a valid dictionary or instance of \w+", "a table", msg)


def _message(errors: list[dict]) -> str:
    """One line for the deepest failing field (union branches at that field joined by 'or')."""
    locs = [_field_loc(e["loc"]) for e in errors]
    deepest = max(locs, key=len)
    here = [e for e, loc in zip(errors, locs) if loc == deepest]
    where = dotted(deepest) or "(top level)"
    if any(e["type"] == "extra_forbidden" for e in here):
        model = _model_at(deepest)
        known = sorted(model.model_fields) if model is not None else []
        close = difflib.get_close_matches(str(deepest[-1]), known, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else (f"; expected one of {known}" if known else "")
        return f"{where}: unknown key{hint}"
    msgs = list(dict.fromkeys(_wording(e) for e in here))
    text = " or ".join(m[:1].lower() + m[1:] for m in msgs)
    if here[0]["type"] in ("missing", "value_error"):
        return f"{where}: {text}"
    return f"{where}: expected {text.replace('input should be ', '')} (got {_shown(here[0].get('input'))})"


def validate_shot(data: dict, path) -> ShotFile:
    """Validate parsed TOML ``data`` of the shot file ``path``; one :class:`KDInputError` for the first problem."""
    try:
        return ShotFile.model_validate(data)
    except ValidationError as e:
        errors = e.errors(include_url=False)
        first_field = _field_loc(errors[0]["loc"])[:2]
        same = [er for er in errors if _field_loc(er["loc"])[:2] == first_field]
        raise KDInputError(f"{path}: {_message(same)}") from None
