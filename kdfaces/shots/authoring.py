"""Authoring IKD targets: edit a shot's constraints, solve while you edit, save back into the shot file (paper §6.6:
scrub, set a constraint at the frame, solve, change the target, solve again; §7).

Every interaction of a viewer (or a notebook) is one plain method of :class:`AuthoringSession`; a viewer only maps
mouse and keys to them:

- ``add_point(time_s, vertex)`` — an ``end_effector`` constraint on one picked vertex with the default falloff; its
  target handle starts at the vertex's displayed KD position; ``drag(row, point_m)`` moves it, ``set_offset_mm``
  types an offset from the kinematic pose instead;
- ``add_group(time_s, group)`` — a ``subset``: hold the group where the kinematic pose has it;
- ``add_pose(time_s, weights=..., head_deg=...)`` — a ``pose`` from shape weights and head angles at this frame;
- ``add_velocity(time_s, group)`` — a ``velocity`` constraint, target 0 ("stop here");
- ``set_field(row, name, value)`` (time_s, width_s, curve, ease_out_s, falloff_m, enabled, label, group, target),
  ``enable``/``disable``, ``delete``, ``undo``/``redo`` (every edit), ``solve(progress, cancel)``, ``save(path)``.

Edits never raise: each returns an :class:`Outcome` (true when applied) and records its message in
:attr:`AuthoringSession.status`. A refused edit changes nothing: a target farther than ``[solver] max_correction_m``
from where the displayed KD state has the constrained point (no correction that size can reach it), a time outside
the shot (or a velocity constraint's t − h before its start), a second pose constraint at one time, a value the shot
file schema rejects, saving onto a read-only path or over a file changed on disk since it was opened. Constraints
at one time share one correction slot and so one bell (width, curve, ease-out): a new constraint at such a time
takes that bell, and a width/curve edit applies to every constraint of the slot (the status says so). Two targets
that contradict each other at one time (a point on a held group that is sent elsewhere) are a *conflict*: each row
says so in its ``status`` and :meth:`AuthoringSession.solve` refuses until it is resolved. A solve that cannot meet
a constraint says why in its row (out of reach, not met within the sweeps, ...).

Solving while you edit: :meth:`AuthoringSession.solve` warm-starts from the previous solution's correction, and its
:class:`~kdfaces.ikd.solver.SolveCache` reuses every lift factorisation, interpolation LU and secant model the edit did
not change. The solution of every constraint set solved is remembered (the last :data:`SOLUTIONS_KEPT`), so an undo
back to a solved state shows that solution again without solving. The first solve of a session starts from f = 0,
exactly as ``kdfaces run`` does, so a file saved after it (or after an undo back to it) reproduces the session's
result bit for bit through :func:`~kdfaces.shots.run_shot`.

Saving writes the rows back as ``[[constraints]]`` tables with ``tomlkit``: the user's comments, key order and
formatting stay for everything the session did not change (a changed key keeps its line and comment, a new row is
appended after the last table; a deleted row's table goes, and the comment lines just above the next table, which
TOML attaches to the deleted one, go with it). The file is written atomically (a temporary file renamed over it,
:mod:`kdfaces.io.atomic`), after the previous content was copied to ``<shot file>.bak`` (e.g. ``demo.toml.bak``,
replaced by each save). Nothing is written when the file on disk changed since it was opened or last saved (its
SHA-256 is compared), when the target is read-only, or when the new text would not load as a shot. Disabled rows are
saved with ``enabled = false`` (``kdfaces run`` skips them).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
import stat
import tomllib
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import defaults
from ..errors import KDError, KDInputError

__all__ = ["AuthoringSession", "Row", "Outcome", "POINT_KIND", "ROW_FIELDS", "BELL_FIELDS", "SOLUTIONS_KEPT",
           "BACKUP_SUFFIX"]

#: The kind of a picked point's constraint.
POINT_KIND = "end_effector"
#: The fields :meth:`AuthoringSession.set_field` edits (shot-file keys of ``[[constraints]]``, plus ``enabled``).
ROW_FIELDS = ("time_s", "kind", "group", "target", "width_s", "curve", "ease_out_s", "falloff_m", "label", "enabled")
#: Fields of the correction bell: one per slot (time and kind), so an edit applies to every row of the slot.
BELL_FIELDS = ("width_s", "curve", "ease_out_s")
#: Solutions remembered per constraint set (undo back to a solved state shows its solution without solving).
SOLUTIONS_KEPT = 32
#: The backup of the shot file written before each save: ``<shot file name>`` + this.
BACKUP_SUFFIX = ".bak"


@dataclass
class Outcome:
    """What an edit did: ``ok`` (applied; the object is true then), the status ``message``, and ``row``, the row
    it made or changed (None when refused or not about one row)."""

    ok: bool
    message: str
    row: int | None = None

    def __bool__(self) -> bool:
        return self.ok


@dataclass
class Row:
    """One constraint of the session: its shot-file table and what the last solve said about it.

    Attributes:
        table: the ``[[constraints]]`` keys as they will be saved (``time_s`` [s], ``kind``, ``group`` name or vertex
            ids, ``target`` "kinematic" or a table of ``offset_m``/``point_m`` [m], ``weights``, ``head_deg`` [deg],
            ``velocity_mps`` [m/s], ``width_s`` [s], ``curve``, ``falloff_m`` [m], ``label``); keys the file did not
            have are absent (their defaults apply).
        enabled: solved when true; kept (saved with ``enabled = false``) when not.
        origin: the row's table index in the file as opened or last saved (None: a new row).
        error_before_m, error_after_m: its error at the start and at the end of the last solve [m, or m/s for a
            velocity constraint] (None before a solve or when disabled); gradient_ratio: the last solve's
            :meth:`~kdfaces.ikd.IKDResult.gradient_ratios` entry (None for a sharp lift).
        status: one line: "met", "out of reach: ...", "conflicts with row k: ...", "disabled", "not solved", ...
    """

    table: dict
    enabled: bool = True
    origin: int | None = None
    error_before_m: float | None = None
    error_after_m: float | None = None
    gradient_ratio: float | None = None
    status: str = "not solved"

    @property
    def kind(self) -> str:
        """pose | subset | velocity | end_effector."""
        return self.table["kind"]

    @property
    def time_s(self) -> float:
        """t_i [s]."""
        return float(self.table["time_s"])

    @property
    def label(self) -> str:
        """The row's label (the shot file's default ``<kind>@<time>s`` when it has none)."""
        lab = self.table.get("label")
        return lab if lab is not None else f"{self.kind}@{self.time_s:g}s"

    @property
    def group(self):
        """A group name, vertex ids (list of int), or None (pose)."""
        return self.table.get("group")

    @property
    def target(self):
        """"kinematic" or the target table (dict)."""
        return self.table.get("target", "kinematic")

    @property
    def width_s(self) -> float:
        """The correction bell's width σ [s]."""
        return float(self.table.get("width_s", defaults.WIDTH_S))

    @property
    def curve(self) -> str:
        """gaussian | poly | asymmetric."""
        return self.table.get("curve", defaults.CURVE)

    @property
    def falloff_m(self) -> float | None:
        """The lift's falloff radius [m] (None for a pose constraint, which has none)."""
        if self.kind == "pose":
            return None
        f = self.table.get("falloff_m")
        return float(defaults.FALLOFF_M if f is None else f)

    @property
    def unit(self) -> str:
        """Unit of the errors in mm: "mm/s" for a velocity constraint, else "mm"."""
        return "mm/s" if self.kind == "velocity" else "mm"

    @property
    def error_before_mm(self) -> float | None:
        """:attr:`error_before_m` in mm (mm/s)."""
        return None if self.error_before_m is None else 1e3 * self.error_before_m

    @property
    def error_after_mm(self) -> float | None:
        """:attr:`error_after_m` in mm (mm/s)."""
        return None if self.error_after_m is None else 1e3 * self.error_after_m

    def key(self) -> str:
        """What the row asks for, as text (rows with equal keys build equal constraints)."""
        return json.dumps([self.table, self.enabled], sort_keys=True)


def _plain(value):
    """``value`` as plain TOML-able Python (numpy scalars and arrays → float/int/list)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


def _read_only(path: Path) -> bool:
    """True when ``path`` may not be written: no write permission for this process, or no write bit at all in its
    mode (a file marked read-only is respected even by a process, such as root, that could write it)."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return True
    return not os.access(path, os.W_OK) or not (mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


class AuthoringSession:
    """An open shot file whose ``[[constraints]]`` are edited, solved and saved (see the module docstring).

    Args:
        shot_path: the TOML shot file.
        rig: a loaded rig (or path) replacing the file's ``[rig] source`` (as :func:`~kdfaces.shots.load_shot`).
        window_s: KD window [s] or "auto"/"adaptive" (default the shot's; adaptive shots solve with the automatic
            window, as ``kdfaces run`` does).
        device, threads: of the :class:`~kdfaces.dynamics.FaceSystem` (as :func:`~kdfaces.shots.run_shot`).
        system: a KD system to use instead of building one from the shot's ``[dynamics]``.

    Opening a file that does not load as a shot raises :class:`~kdfaces.errors.KDInputError`; after that nothing
    raises to the caller.

    Attributes:
        path: the shot file; shot: the parsed :class:`~kdfaces.shots.Shot`; rows: the constraints (:class:`Row`).
        system, trajectory (x_K), window_s [s], step_s [s]: what the solves simulate.
        result: the current :class:`~kdfaces.ikd.IKDResult` (None before a solve, or when the rows changed to a set
            not solved yet: see :attr:`stale`); status: the last message; messages: every message.
        cache: the :class:`~kdfaces.ikd.solver.SolveCache` shared by the session's solves.
    """

    def __init__(self, shot_path, *, rig=None, window_s=None, device: str = "cpu", threads: int = defaults.THREADS,
                 system=None):
        from ..ikd.solver import SolveCache
        from .shotfile import parse_shot

        self.path = Path(shot_path)
        raw, text = self._read(self.path)
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise KDInputError(f"{self.path}: not valid TOML ({e})") from None
        self.shot = parse_shot(data, self.path, rig=rig)
        self._disk_hash = _sha256(raw)
        self._text = text
        self.trajectory = self.shot.trajectory
        self.step_s = float(self.shot.step_s)
        self.start_s, self.end_s = float(self.shot.animation.start_s), float(self.shot.animation.end_s)
        self.times = np.asarray(self.shot.animation.frame_times, dtype=np.float64)
        tables = data.get("constraints", []) or []
        self.rows: list[Row] = [self._row_from_file(t, i) for i, t in enumerate(tables)]
        self._saved_key = self._rows_key()
        self.device, self.threads = device, int(threads)
        self.system = system if system is not None else self._build_system()
        self.window_s = self._window(window_s)
        self.options = self.shot.solver_options()
        self.max_correction_m = float(self.options["max_correction_m"])
        self.cache = SolveCache()
        self.result = None
        self._result_key = None
        self._solutions: OrderedDict = OrderedDict()
        self._states: OrderedDict = OrderedDict()
        self._undo: list[tuple[str, list[Row]]] = []
        self._redo: list[tuple[str, list[Row]]] = []
        self.busy = False
        self.messages: list[str] = []
        self.status = ""
        self._check_conflicts()
        self._say(f"opened {self.path.name}: {len(self.rows)} constraints")

    # --- opening ------------------------------------------------------------------------------------------------
    @staticmethod
    def _read(path: Path) -> tuple[bytes, str]:
        if not path.is_file():
            raise KDInputError(f"{path}: file not found; expected a TOML shot file")
        try:
            raw = path.read_bytes()
            return raw, raw.decode("utf-8")
        except UnicodeDecodeError as e:
            raise KDInputError(f"{path}: not a UTF-8 text file (byte {e.start}); expected a TOML shot file") from None
        except OSError as e:
            raise KDInputError(f"{path}: cannot read ({e.strerror})") from None

    @staticmethod
    def _row_from_file(table: dict, i: int) -> Row:
        t = {k: _plain(v) for k, v in table.items() if k != "enabled"}
        return Row(table=t, enabled=bool(table.get("enabled", True)), origin=i)

    def _build_system(self):
        from ..dynamics import FaceSystem

        return FaceSystem(self.shot.model(), device=self.device, threads=self.threads)

    def _window(self, window_s) -> float:
        w = self.shot.dynamics["window_s"] if window_s is None else window_s
        if w in ("auto", "adaptive"):
            from ..window import automatic_window

            # as run_shot: the automatic window of the shot's model, at least one step
            model = getattr(self.system, "model", None)
            est = automatic_window(model if model is not None else self.system, self.trajectory, step_s=self.step_s,
                                   max_steps=defaults.MAX_STEPS)
            return float(max(est.window_s, self.step_s))
        if isinstance(w, bool) or not isinstance(w, int | float) or not w > 0:
            raise KDInputError(f"window_s: expected positive seconds, 'auto' or 'adaptive', got {w!r}")
        return float(w)

    def set_system(self, system, window_s: float | None = None) -> Outcome:
        """Use another KD system (changed dynamics: settle time, damping) and optionally window [s]: every solution
        and secant model is dropped (they depend on the dynamics); lift factorisations stay (they depend on the
        mesh only)."""
        self.system = system
        if window_s is not None:
            self.window_s = float(window_s)
        self.cache.models = {}
        self._solutions.clear()
        self._states.clear()
        self.result, self._result_key = None, None
        for r in self.rows:
            r.error_before_m = r.error_after_m = r.gradient_ratio = None
            if not r.status.startswith("conflict"):
                r.status = "not solved" if r.enabled else "disabled"
        return self._say("dynamics changed: solve again", ok=True)

    # --- what the viewer shows ----------------------------------------------------------------------------------
    @property
    def stale(self) -> bool:
        """True when the rows differ from those :attr:`result` solved (or nothing was solved)."""
        return self.result is None or self._result_key != self._rows_key()

    @property
    def dirty(self) -> bool:
        """True when the rows differ from the file as opened or last saved."""
        return self._saved_key != self._rows_key()

    @property
    def can_undo(self) -> bool:
        """Whether there is an edit to :meth:`undo`."""
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        """Whether there is an undone edit to :meth:`redo`."""
        return bool(self._redo)

    @property
    def undo_label(self) -> str | None:
        """What :meth:`undo` would undo (None: nothing)."""
        return self._undo[-1][0] if self._undo else None

    @property
    def redo_label(self) -> str | None:
        """What :meth:`redo` would redo (None: nothing)."""
        return self._redo[-1][0] if self._redo else None

    @property
    def ikd_trajectory(self):
        """x_K + f of :attr:`result` (None before a solve)."""
        return None if self.result is None else self.result.trajectory

    def state(self, time_s: float, which: str = "final") -> np.ndarray:
        """Vertex positions (N, 3) [m] at ``time_s`` [s]: ``"kinematic"`` x_K, ``"kd"`` the KD state of x_K, or
        ``"final"`` (as in :meth:`ShotRun.states <kdfaces.shots.ShotRun.states>`) the KD state of the current
        solution's x_K + f, the KD state of x_K before a solve (``"ikd"`` is accepted as another name for it).
        A constraint time of the current solution returns the state the solve ended with (no simulation)."""
        from ..kd import simulate_kd

        t = float(time_s)
        if which == "kinematic":
            return self.trajectory.positions([t])[0]
        if which not in ("kd", "ikd", "final"):
            raise KDInputError(f"state: which: expected 'kinematic', 'kd' or 'final', got {which!r}")
        traj = self.trajectory if (which == "kd" or self.result is None) else self.result.trajectory
        if traj is not self.trajectory:
            for c, x in zip(self.result.constraints, self.result.states):
                if abs(c.time_s - t) <= 1e-9:
                    return x
        key = (getattr(traj, "version", id(traj)), id(self.system), self.window_s, round(t, 9))
        x = self._states.get(key)
        if x is None:
            x = np.asarray(simulate_kd(self.system, traj, [t], self.window_s, step_s=self.step_s)[0],
                           dtype=np.float64)
            self._states[key] = x
            while len(self._states) > 16:
                self._states.popitem(last=False)
        return x

    def nearest_vertex(self, point_m, time_s: float, which: str = "final") -> int:
        """The vertex of the displayed state at ``time_s`` [s] nearest to ``point_m`` (3,) [m] (a screen pick's
        surface point)."""
        x = self.state(time_s, which)
        return int(np.argmin(((x - np.asarray(point_m, dtype=np.float64)[None]) ** 2).sum(axis=1)))

    def vertices(self, row: int) -> np.ndarray:
        """The vertex ids (G,) a row constrains (every vertex for a pose)."""
        from ..rig.groups import vertex_group

        g = self.rows[row].group
        if g is None:
            return np.arange(self.shot.rig.num_vertices)
        if isinstance(g, str):
            return np.asarray(vertex_group(self.shot.rig, g, channel_map=self.shot.channel_map), dtype=np.int64)
        return np.asarray(g, dtype=np.int64)

    def handle(self, row: int) -> np.ndarray | None:
        """Where a row's drag handle sits (3,) [m]: an end effector's target point, a subset's or pose's target
        centroid (over its group); None for a velocity constraint (nothing to drag) or a row that does not build."""
        try:
            c = self._build(row)
        except KDError:
            return None
        if c.kind == "end_effector":
            return np.asarray(c.target, dtype=np.float64).copy()
        if c.kind == "velocity":
            return None
        return np.asarray(c.target, dtype=np.float64).mean(axis=0)

    def measured(self, row: int, which: str = "final") -> np.ndarray | None:
        """The row's measured point (3,) [m] in the displayed KD state at its time (an end effector's weighted point,
        a group's centroid), to draw beside its handle; None for a velocity constraint or a row that does not
        build."""
        try:
            c = self._build(row)
        except KDError:
            return None
        if c.kind == "velocity":
            return None
        x = self.state(c.time_s, which)
        return c.weights @ x[c.indices] if c.kind == "end_effector" else x[c.indices].mean(axis=0)

    # --- building constraints -----------------------------------------------------------------------------------
    def _validated(self, table: dict, i: int) -> dict:
        """The row's table with every default filled in, as the shot file's schema validates it."""
        from pydantic import ValidationError

        from .schema import ConstraintTable, _message

        try:
            return ConstraintTable.model_validate(table).model_dump()
        except ValidationError as e:
            raise KDInputError(f"{self.path}: constraints[{i}]: {_message(e.errors(include_url=False))}") from None

    def _build(self, i: int, rows: list[Row] | None = None):
        """Row ``i``'s :class:`~kdfaces.ikd.Constraint`, built exactly as the shot file's loader builds it."""
        rows = self.rows if rows is None else rows
        return self.shot._constraint(self._validated(rows[i].table, i), i, self.trajectory)

    def constraints(self) -> list:
        """The enabled rows' constraints, in row order (what :meth:`solve` and ``kdfaces run`` solve)."""
        return [self._build(i) for i, r in enumerate(self.rows) if r.enabled]

    def _rows_key(self, rows: list[Row] | None = None) -> str:
        return json.dumps([r.key() for r in (self.rows if rows is None else rows)])

    # --- messages and edits -------------------------------------------------------------------------------------
    def _say(self, message: str, *, ok: bool = True, row: int | None = None) -> Outcome:
        self.status = message
        self.messages.append(message)
        return Outcome(ok, message, row)

    def _refuse(self, message: str) -> Outcome:
        return self._say(f"refused: {message}; nothing changed", ok=False)

    def _commit(self, description: str, rows: list[Row], touched: list[int], row: int | None = None,
                note: str = "") -> Outcome:
        """Check ``rows`` (the rows after the edit; ``touched``: the rows whose constraint changed) and make them
        the session's, or refuse the edit."""
        if self.busy:
            return self._refuse("a solve is running (cancel it first)")
        for i in touched:
            problem = self._check_row(i, rows)
            if problem is not None:
                return self._refuse(problem)
        self._undo.append((description, copy.deepcopy(self.rows)))
        self._redo.clear()
        self.rows = rows
        self._after_change()
        return self._say(description + (f" ({note})" if note else ""), row=row)

    def _after_change(self) -> None:
        """Row results of the solved set (remembered solutions), else stale; conflicts marked."""
        key = self._rows_key()
        if key in self._solutions:
            self.result, self._result_key = self._solutions[key][0], key
            for r, saved in zip(self.rows, self._solutions[key][1]):
                r.error_before_m, r.error_after_m, r.gradient_ratio, r.status = saved
            self._solutions.move_to_end(key)
        else:
            for r in self.rows:
                if r.enabled and r.status in ("disabled",):
                    r.status = "not solved"
                if not r.enabled:
                    r.status = "disabled"
        self._check_conflicts()

    def _check_row(self, i: int, rows: list[Row]) -> str | None:
        """Why row ``i`` of ``rows`` is not an acceptable edit (None: it is)."""
        r = rows[i]
        where = f"row {i} ({r.label!r})"
        try:
            table = self._validated(r.table, i)
        except KDInputError as e:
            return str(e).replace(f"{self.path}: constraints[{i}]: ", f"{where}: ")
        t = float(table["time_s"])
        if not (self.start_s - 1e-9 <= t <= self.end_s + 1e-9):
            return f"{where}: time_s {t:g} s is outside the shot [{self.start_s:g}, {self.end_s:g}] s"
        if table["kind"] == "velocity" and t - self.step_s < self.start_s - 1e-9:
            return (f"{where}: a velocity constraint needs t − h ≥ the shot start ({t:g} − {self.step_s:g} < "
                    f"{self.start_s:g} s)")
        if r.enabled and table["kind"] == "pose":
            for j, o in enumerate(rows):
                if j != i and o.enabled and o.kind == "pose" and abs(o.time_s - t) <= 1e-9:
                    return f"{where}: row {j} ({o.label!r}) is already a pose constraint at {t:g} s (one per time)"
        try:
            c = self._build(i, rows)
        except KDError as e:
            return f"{where}: {str(e).replace(str(self.path) + ': ', '')}"
        if r.enabled and c.kind != "velocity":
            try:
                x = self.state(c.time_s, "final")
            except KDError as e:
                return f"{where}: {e}"
            q = c.weights @ x[c.indices] if c.kind == "end_effector" else x[c.indices]
            far = float(np.linalg.norm(np.atleast_2d(c.target - q), axis=-1).max())
            if far > self.max_correction_m:
                return (f"{where}: the target is {far * 1e3:.0f} mm from where the KD state has it, beyond "
                        f"max_correction_m = {self.max_correction_m * 1e3:.0f} mm (no allowed correction reaches it)")
        return None

    def _check_conflicts(self) -> list[tuple[int, int, str]]:
        """Mark rows whose targets contradict another row at the same time; returns (i, j, message) pairs."""
        from ..ikd.constraints import build_correction

        found = []
        enabled = [i for i, r in enumerate(self.rows) if r.enabled]
        built = {}
        for i in enabled:
            try:
                built[i] = self._build(i)
            except KDError as e:
                found.append((i, i, str(e)))
        for r in self.rows:
            if r.status.startswith("conflict"):
                r.status = "not solved" if r.enabled else "disabled"
        for a in built:
            for b in built:
                if b <= a or abs(built[a].time_s - built[b].time_s) > 1e-9:
                    continue
                try:
                    build_correction([built[a], built[b]], (self.shot.rig.num_vertices, 3))
                except KDInputError as e:
                    msg = str(e).split(": ", 1)[-1]
                    found.append((a, b, msg))
        for a, b, msg in found:
            for i, j in ((a, b), (b, a)):
                other = f"row {j} ({self.rows[j].label!r})" if i != j else "itself"
                self.rows[i].status = f"conflicts with {other} at {self.rows[i].time_s:g} s: {msg}"
        return found

    def _slot_bell(self, table: dict, rows: list[Row], skip: int | None = None) -> dict:
        """The bell fields of an enabled row sharing ``table``'s slot (time and slot kind), or {}."""
        kind = "velocity" if table["kind"] == "velocity" else "position"
        for j, o in enumerate(rows):
            if j == skip or not o.enabled:
                continue
            okind = "velocity" if o.kind == "velocity" else "position"
            if okind == kind and abs(o.time_s - float(table["time_s"])) <= 1e-9:
                return {k: o.table[k] for k in BELL_FIELDS if k in o.table} | (
                    {"width_s": o.width_s} if "width_s" not in o.table else {})
        return {}

    def _add(self, table: dict, description: str) -> Outcome:
        table = _plain(table)
        rows = copy.deepcopy(self.rows)
        bell = self._slot_bell(table, rows)
        note = ""
        if bell:
            for k in BELL_FIELDS:
                table.pop(k, None)
            table.update(bell)
            note = f"width {float(bell['width_s']):g} s of the constraints already at {float(table['time_s']):g} s"
        rows.append(Row(table=table))
        return self._commit(description, rows, [len(rows) - 1], row=len(rows) - 1, note=note)

    # --- adding -------------------------------------------------------------------------------------------------
    def add_point(self, time_s: float, vertex: int, *, offset_m=None, point_m=None, label: str | None = None
                  ) -> Outcome:
        """An end-effector constraint on the picked ``vertex`` at ``time_s`` [s], with the default falloff: its target
        is ``point_m`` (3,) [m], or the kinematic position + ``offset_m`` (3,) [m], or (neither given) the vertex's
        position in the displayed KD state — the handle appears there, to be dragged (:meth:`drag`)."""
        try:
            t, v = float(time_s), int(vertex)
        except (TypeError, ValueError):
            return self._refuse(f"add_point: expected a time in seconds and a vertex id, got {time_s!r}, {vertex!r}")
        n = self.shot.rig.num_vertices
        if not 0 <= v < n:
            return self._refuse(f"add_point: vertex {v} is not a vertex of the rig (0 … {n - 1})")
        if not (self.start_s - 1e-9 <= t <= self.end_s + 1e-9):
            return self._refuse(f"add_point: time_s {t:g} s is outside the shot [{self.start_s:g}, {self.end_s:g}] s")
        if point_m is not None and offset_m is not None:
            return self._refuse("add_point: give point_m or offset_m, not both")
        if offset_m is not None:
            target = {"offset_m": _plain(np.asarray(offset_m, dtype=np.float64).reshape(-1))}
        else:
            p = self.state(t, "final")[v] if point_m is None else np.asarray(point_m, dtype=np.float64).reshape(-1)
            target = {"point_m": _plain(p)}
        table = {"time_s": t, "kind": POINT_KIND, "group": [v], "target": target,
                 "label": label if label is not None else f"point {v}"}
        return self._add(table, f"added point {v} at {t:g} s")

    def add_group(self, time_s: float, group, *, label: str | None = None) -> Outcome:
        """A subset constraint: hold ``group`` (a group name or vertex ids) where the kinematic pose has it at
        ``time_s`` [s]."""
        table = {"time_s": time_s, "kind": "subset", "group": _plain(group)}
        if label is not None:
            table["label"] = label
        return self._add(table, f"added group {group if isinstance(group, str) else 'of vertices'} at {time_s:g} s")

    def add_pose(self, time_s: float, *, weights: dict | None = None, head_deg=None, label: str | None = None
                 ) -> Outcome:
        """A pose constraint at ``time_s`` [s]: the rig posed with shape ``weights`` {name: weight} and head angles
        ``head_deg`` (yaw, pitch, roll) [deg] (either defaults to the animation's at that time; neither: the
        kinematic pose)."""
        target: dict | str = {}
        if weights is not None:
            target["weights"] = {str(k): float(w) for k, w in dict(weights).items()}
        if head_deg is not None:
            target["head_deg"] = _plain(np.asarray(head_deg, dtype=np.float64).reshape(-1))
        table = {"time_s": time_s, "kind": "pose", "target": target or "kinematic"}
        if label is not None:
            table["label"] = label
        return self._add(table, f"added pose at {time_s:g} s")

    def add_velocity(self, time_s: float, group, *, label: str | None = None) -> Outcome:
        """A velocity constraint: ``group`` (name or vertex ids) at rest (0 m/s) at ``time_s`` [s] ("stop here")."""
        table = {"time_s": time_s, "kind": "velocity", "group": _plain(group),
                 "target": {"velocity_mps": [0.0, 0.0, 0.0]}}
        if label is not None:
            table["label"] = label
        return self._add(table, f"added velocity stop at {time_s:g} s")

    # --- editing ------------------------------------------------------------------------------------------------
    def _row_index(self, row) -> int | None:
        try:
            i = int(row)
        except (TypeError, ValueError):
            return None
        return i if 0 <= i < len(self.rows) else None

    def drag(self, row: int, point_m) -> Outcome:
        """Move row ``row``'s handle to ``point_m`` (3,) [m]: an end effector's target point, or a subset's or pose's
        target translated by the handle's move (its ``offset_m``)."""
        i = self._row_index(row)
        if i is None:
            return self._refuse(f"drag: no row {row!r}")
        try:
            p = np.asarray(point_m, dtype=np.float64).reshape(3)
        except (TypeError, ValueError):
            return self._refuse(f"drag: expected a point (3,) in metres, got {point_m!r}")
        if not np.isfinite(p).all():
            return self._refuse("drag: the point is not finite")
        r = self.rows[i]
        if r.kind == "velocity":
            return self._refuse(f"drag: row {i} is a velocity constraint (nothing to drag; set its target)")
        rows = copy.deepcopy(self.rows)
        target = dict(r.target) if isinstance(r.target, dict) else {}
        if r.kind == "end_effector":
            target.pop("offset_m", None)
            target["point_m"] = _plain(p)
        else:
            h = self.handle(i)
            if h is None:
                return self._refuse(f"drag: row {i} does not build")
            off = np.asarray(target.get("offset_m", [0.0, 0.0, 0.0]), dtype=np.float64) + (p - h)
            target["offset_m"] = _plain(off)
        rows[i].table["target"] = target
        return self._commit(f"moved the target of row {i} ({r.label!r})", rows, [i], row=i)

    def set_offset_mm(self, row: int, offset_mm) -> Outcome:
        """Row ``row``'s target: the kinematic pose moved by ``offset_mm`` (3,) [mm] (end effector, subset, pose)."""
        i = self._row_index(row)
        if i is None:
            return self._refuse(f"set_offset_mm: no row {row!r}")
        try:
            off = np.asarray(offset_mm, dtype=np.float64).reshape(3) * 1e-3
        except (TypeError, ValueError):
            return self._refuse(f"set_offset_mm: expected three numbers in mm, got {offset_mm!r}")
        r = self.rows[i]
        if r.kind == "velocity":
            return self._refuse(f"set_offset_mm: row {i} is a velocity constraint")
        target = dict(r.target) if isinstance(r.target, dict) else {}
        target.pop("point_m", None)
        target["offset_m"] = _plain(off)
        rows = copy.deepcopy(self.rows)
        rows[i].table["target"] = target
        return self._commit(f"set the offset of row {i} ({r.label!r}) to {np.round(off * 1e3, 3).tolist()} mm",
                            rows, [i], row=i)

    def set_field(self, row: int, name: str, value) -> Outcome:
        """Set field ``name`` (:data:`ROW_FIELDS`) of row ``row`` to ``value`` (time_s [s], width_s [s], ease_out_s
        [s], falloff_m [m], curve, label, group, kind, target, enabled); None removes an optional field (its default
        applies). A bell field (:data:`BELL_FIELDS`) changes every enabled row of the slot; a row moved to a time
        that has constraints takes their bell."""
        i = self._row_index(row)
        if i is None:
            return self._refuse(f"set_field: no row {row!r}")
        if name not in ROW_FIELDS:
            return self._refuse(f"set_field: {name!r} is not a constraint field; expected one of {ROW_FIELDS}")
        if name == "enabled":
            return self.set_enabled(i, value)
        rows = copy.deepcopy(self.rows)
        r = rows[i]
        value = _plain(value)
        if name in ("time_s", "width_s", "ease_out_s", "falloff_m") and value is not None:
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                return self._refuse(f"row {i}: {name}: expected a number, got {value!r}")
            value = float(value)
        old = r.table.get(name)
        if value is None:
            r.table.pop(name, None)
        else:
            r.table[name] = value
        touched, note = [i], ""
        if name in BELL_FIELDS:
            mates = self._slot_mates(i, rows)
            for j in mates:
                if value is None:
                    rows[j].table.pop(name, None)
                else:
                    rows[j].table[name] = value
            touched += mates
            if mates:
                note = f"also rows {mates}: constraints at one time share one correction curve"
        elif name in ("time_s", "kind"):
            bell = self._slot_bell(r.table, rows, skip=i)
            if bell:
                for k in BELL_FIELDS:
                    r.table.pop(k, None)
                r.table.update(bell)
                note = f"it takes the width {float(bell['width_s']):g} s of the constraints at {r.time_s:g} s"
        return self._commit(f"set {name} of row {i} ({r.label!r}) from {old!r} to {value!r}", rows, touched, row=i,
                            note=note)

    def _slot_mates(self, i: int, rows: list[Row]) -> list[int]:
        r = rows[i]
        kind = "velocity" if r.kind == "velocity" else "position"
        return [j for j, o in enumerate(rows) if j != i and o.enabled and r.enabled
                and ("velocity" if o.kind == "velocity" else "position") == kind and abs(o.time_s - r.time_s) <= 1e-9]

    def set_enabled(self, row: int, on) -> Outcome:
        """Enable (solve) or disable (keep, not solve) row ``row``."""
        i = self._row_index(row)
        if i is None:
            return self._refuse(f"set_enabled: no row {row!r}")
        on = bool(on)
        if self.rows[i].enabled == on:
            return self._say(f"row {i} is already {'enabled' if on else 'disabled'}", row=i)
        rows = copy.deepcopy(self.rows)
        rows[i].enabled = on
        note = ""
        if on:
            bell = self._slot_bell(rows[i].table, rows, skip=i)
            if bell and any(rows[i].table.get(k, bell.get(k)) != bell.get(k) for k in BELL_FIELDS) \
                    or (bell and rows[i].width_s != float(bell["width_s"])):
                for k in BELL_FIELDS:
                    rows[i].table.pop(k, None)
                rows[i].table.update(bell)
                note = f"it takes the width {float(bell['width_s']):g} s of the constraints at {rows[i].time_s:g} s"
        return self._commit(f"{'enabled' if on else 'disabled'} row {i} ({rows[i].label!r})", rows,
                            [i] if on else [], row=i, note=note)

    def enable(self, row: int) -> Outcome:
        """:meth:`set_enabled` (row, True)."""
        return self.set_enabled(row, True)

    def disable(self, row: int) -> Outcome:
        """:meth:`set_enabled` (row, False)."""
        return self.set_enabled(row, False)

    def delete(self, row: int) -> Outcome:
        """Remove row ``row`` (undo brings it back)."""
        i = self._row_index(row)
        if i is None:
            return self._refuse(f"delete: no row {row!r}")
        rows = copy.deepcopy(self.rows)
        gone = rows.pop(i)
        return self._commit(f"deleted row {i} ({gone.label!r})", rows, [])

    def undo(self) -> Outcome:
        """Undo the last edit (a remembered solution of the rows it returns to is shown again)."""
        if self.busy:
            return self._refuse("a solve is running (cancel it first)")
        if not self._undo:
            return self._say("nothing to undo", ok=False)
        description, rows = self._undo.pop()
        self._redo.append((description, copy.deepcopy(self.rows)))
        self.rows = rows
        self._after_change()
        return self._say(f"undid: {description}")

    def redo(self) -> Outcome:
        """Redo the last undone edit."""
        if self.busy:
            return self._refuse("a solve is running (cancel it first)")
        if not self._redo:
            return self._say("nothing to redo", ok=False)
        description, rows = self._redo.pop()
        self._undo.append((description, copy.deepcopy(self.rows)))
        self.rows = rows
        self._after_change()
        return self._say(f"redid: {description}")

    # --- solving ------------------------------------------------------------------------------------------------
    def solve(self, progress=None, cancel=None, *, warm: bool = True):
        """Solve IKD for the enabled rows; returns the :class:`~kdfaces.ikd.IKDResult` (None when nothing was
        solved: no enabled rows, a conflict, cancelled) and fills each row's errors, gradient ratio and status.

        ``progress(sweep, max_sweeps, errors)`` is called after every sweep (``errors`` (C,) [m or m/s]);
        ``cancel()`` is asked before every sweep (True: stop; the previous solution stays). ``warm``: start from the
        current solution's correction (the first solve of a session always starts from f = 0). A set of rows
        solved before is not solved again. Run it on a worker thread to keep a viewer responsive: edits are
        refused while it runs (:attr:`busy`).
        """
        from ..ikd.solver import solve_ikd
        from ..resources import single_threaded_blas

        if self.busy:
            self._refuse("a solve is already running")
            return None
        key = self._rows_key()
        if key in self._solutions:
            self._after_change()
            self._say("solved (this set of constraints was solved before)")
            return self.result
        enabled = [i for i, r in enumerate(self.rows) if r.enabled]
        if not enabled:
            self.result, self._result_key = None, key
            self._say("nothing to solve: no enabled constraints (showing KD)", ok=False)
            return None
        conflicts = self._check_conflicts()
        if conflicts:
            a, b, msg = conflicts[0]
            self._say(f"not solved: row {a} and row {b} conflict ({msg})", ok=False)
            return None
        try:
            constraints = [self._build(i) for i in enabled]
        except KDError as e:
            self._say(f"not solved: {e}", ok=False)
            return None
        warm_start = self.result.correction if (warm and self.result is not None) else None
        opts = dict(self.options)
        callback = None
        if progress is not None:
            def callback(it, err):
                progress(it, opts["max_iterations"], np.asarray(err))
        self.busy = True
        try:
            with single_threaded_blas():
                result = solve_ikd(self.system, self.trajectory, constraints, window_s=self.window_s,
                                   step_s=self.step_s, callback=callback, cancel=cancel, cache=self.cache,
                                   warm_start=warm_start, **opts)
        except KDError as e:
            self._say(f"not solved: {e}", ok=False)
            return None
        finally:
            self.busy = False
        if result.reason == "cancelled":
            self._say(f"solve cancelled after {result.iterations} sweeps; showing the previous solution", ok=False)
            return None
        self._record(result, enabled, key)
        return result

    def _record(self, result, enabled: list[int], key: str) -> None:
        tol = {True: float(self.options["tolerance_mps"]), False: float(self.options["tolerance_m"])}
        ratios = result.gradient_ratios() or [None] * len(enabled)
        for r in self.rows:
            r.error_before_m = r.error_after_m = r.gradient_ratio = None
            r.status = "disabled"
        for k, i in enumerate(enabled):
            r = self.rows[i]
            r.error_before_m = float(result.errors_before[k])
            r.error_after_m = float(result.errors_after[k])
            r.gradient_ratio = None if ratios[k] is None else float(ratios[k])
            left = f"{r.error_after_m * 1e3:.3g} {r.unit} left"
            if r.error_after_m <= tol[r.kind == "velocity"]:
                r.status = "met"
            elif result.reason == "out_of_reach":
                r.status = (f"out of reach: {left} (the target needs a correction beyond max_correction_m = "
                            f"{self.max_correction_m * 1e3:.0f} mm, or no correction brings it closer)")
            elif result.reason == "max_iterations":
                r.status = f"not met within {result.iterations} sweeps: {left} (solve again to continue)"
            else:
                r.status = f"not met ({result.reason}): {left}"
        self.result, self._result_key = result, key
        self._solutions[key] = (result, [(r.error_before_m, r.error_after_m, r.gradient_ratio, r.status)
                                         for r in self.rows])
        while len(self._solutions) > SOLUTIONS_KEPT:
            self._solutions.popitem(last=False)
        met = sum(self.rows[i].status == "met" for i in enabled)
        self._say(f"IKD {result.reason}: {met}/{len(enabled)} constraints met, {result.iterations} sweeps, "
                  f"{result.wall_s:.2f} s")

    # --- saving -------------------------------------------------------------------------------------------------
    def save(self, path=None) -> Outcome:
        """Write the rows into the shot file (or ``path``) as ``[[constraints]]`` tables, keeping everything else of
        the file as it is (see the module docstring: atomic, a ``.bak`` backup, refused over a file changed on disk
        since it was opened or last saved, onto a read-only path, or when the result would not load)."""
        import tomlkit

        from ..io.atomic import write_bytes_atomic
        from .shotfile import parse_shot

        if self.busy:
            return self._refuse("a solve is running (cancel it first)")
        target = self.path if path is None else Path(path)
        try:
            raw, _ = self._read(self.path)
        except KDInputError as e:
            return self._refuse(f"save: {e}")
        if _sha256(raw) != self._disk_hash:
            return self._refuse(f"save: {self.path} changed on disk since it was opened; reopen it (or save to "
                                "another path)")
        if target.exists() and (target.is_dir() or _read_only(target)):
            return self._refuse(f"save: {target} is {'a folder' if target.is_dir() else 'read-only'}")
        if not target.parent.is_dir() or _read_only(target.parent):
            return self._refuse(f"save: cannot write in {target.parent} (missing or read-only)")
        try:
            doc = tomlkit.parse(self._text)
            self._write_rows(doc)
            text = tomlkit.dumps(doc)
            parse_shot(tomllib.loads(text), target if target.parent == self.path.parent else self.path,
                       rig=self.shot.rig)
        except (KDError, tomllib.TOMLDecodeError, ValueError, TypeError) as e:
            return self._refuse(f"save: the saved file would not load ({e})")
        try:
            if target.exists():
                write_bytes_atomic(target.with_name(target.name + BACKUP_SUFFIX), target.read_bytes())
            write_bytes_atomic(target, text.encode("utf-8"))
        except (KDError, OSError) as e:
            return self._refuse(f"save: {e}")
        if target.resolve() == self.path.resolve():
            self._text = text
            self._disk_hash = _sha256(text.encode("utf-8"))
            for k, r in enumerate(self.rows):
                r.origin = k
            self._saved_key = self._rows_key()
        return self._say(f"saved {len(self.rows)} constraints to {target} (backup {target.name}{BACKUP_SUFFIX})")

    def _write_rows(self, doc) -> None:
        """Replace ``doc``'s ``[[constraints]]`` (a tomlkit document of the opened file) by the rows, keeping each
        original table (comments, order, formatting) and changing only its keys that changed."""
        import tomlkit

        old = doc.get("constraints")
        originals = list(old) if old is not None else []
        if old is not None:
            # tables that no row keeps any more go; the others stay in place
            keep = {r.origin for r in self.rows if r.origin is not None}
            for k in sorted(set(range(len(originals))) - keep, reverse=True):
                del old[k]
            position = {o: n for n, o in enumerate(sorted(keep))}
        else:
            position = {}
        aot = old
        for r in self.rows:
            new = dict(r.table)
            if not r.enabled:
                new["enabled"] = False
            if r.origin is not None and r.origin < len(originals):
                table = aot[position[r.origin]]
                for k in [k for k in list(table.keys()) if k not in new]:
                    if k == "enabled" and r.enabled:
                        if table[k] is not True:
                            del table[k]
                        continue
                    del table[k]
                for k, v in new.items():
                    if k not in table or _plain(table[k].unwrap() if hasattr(table[k], "unwrap") else table[k]) != v:
                        table[k] = _toml_value(v)
            else:
                table = tomlkit.table()
                for k in ROW_FIELDS:
                    if k in new:
                        table[k] = _toml_value(new[k])
                table.add(tomlkit.nl())
                if aot is None:
                    aot = tomlkit.aot()
                    doc.append("constraints", aot)
                aot.append(table)


def _toml_value(v):
    """A tomlkit item for a row value: dicts as inline tables (``target = { offset_m = [...] }``)."""
    import tomlkit

    if isinstance(v, dict):
        t = tomlkit.inline_table()
        for k, x in v.items():
            t[k] = _toml_value(x)
        return t
    return tomlkit.item(v)

