"""``kdfaces punch --view``: the scrubbing viewer of §6.6 (Fig. 11) for the skeletal punch, with its fist target.

The arm is the punch of :mod:`kdfaces.articulated.punch` (paper §4.1, Fig. 4: the MakeHuman right arm, a relaxed
tension t̂, the fist keyframed onto a target at t_i). Every displayed frame is the arm's skeletal KD state at that
frame's time, computed history-free (one ``simulate_kd`` over the window δ ending there, as ``kdfaces view`` does for
faces); its time in ms is shown on screen. The kinematic arm is drawn as a grey ghost behind the KD (or IKD) arm.

The fist target at t_i is a handle (a sphere widget at the t_i frame): dragging it
(:meth:`PunchViewer.set_fist_target`) or typing an offset from the kinematic fist at t_i
(:meth:`PunchViewer.offset_fist_target_mm`) moves it, and ``i`` (:meth:`PunchViewer.solve`) solves IKD as
``kdfaces punch`` does: an end-effector constraint on the fist at t_i whose error maps to the arm's joint angles
through J⁺ of the chain Jacobian at the KD pose (eq. 4–5, 14), Algorithm 1's update, the punch's tolerance. The status
line shows the fist error before → after. A target the arm cannot reach (farther from the chain's root pivot than
the sum of its segments) or one farther than ``max_correction_m`` from the KD fist at t_i is refused with a message
in the status line, and nothing changes. ``c`` puts the target back on the punch's own.

Keys: ``space`` play/stop, ``Left``/``Right`` one frame, ``m`` kinematic → KD → IKD, ``i`` solve, ``c`` reset the
target. Sliders: the frame, δ, the tension t̂ and the correction width σ. Every slider and key calls a plain method of
:class:`PunchViewer`, so tests drive it off-screen; ``kdfaces punch --view --screenshot FILE`` renders the t_i frame.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from .. import defaults
from ..errors import KDInputError
from ..kd import simulate_kd, window_steps
from .viewer import PlotterWindow, check_screenshot_path, check_window_size

__all__ = ["PunchViewer", "view_punch", "add_view_options", "punch_view_command", "ARM_COLOR", "TARGET_COLOR"]

#: The KD (IKD) arm's colour; the kinematic ghost's; the fist target handle's; the KD fist's.
ARM_COLOR = "#1f5fa8"
GHOST_COLOR = "#a0a0a0"
TARGET_COLOR = "#1a9850"
FIST_COLOR = "#f28e2b"
_MODE_NAMES = {"kinematic": "kinematic", "kd": "KD", "ikd": "IKD"}
_TUBE_M, _JOINT_M, _TARGET_M = 0.016, 0.024, 0.018  # radii [m] of the arm's tubes, joint balls, the target


def _mm(d) -> str:
    """A displacement (3,) [m] as "(x, y, z)" in mm (round-off never shows as -0.0)."""
    return "(" + ", ".join(f"{round(1e3 * float(v), 1) + 0.0:+.1f}" for v in d) + ")"


class PunchViewer(PlotterWindow):
    """A pyvista window over the relaxed punch: timeline, play/stop, δ / tension / width sliders, the fist target.

    Args:
        off_screen: render without a window (screenshots, tests).
        size: window (width, height) in pixels.
        window_s: KD window δ [s]; settle_time_s: the arm's tension t̂ [s]; width_s: the correction width σ [s]
            (defaults the punch's: :data:`~kdfaces.articulated.punch.PUNCH_WINDOW_S`, ``PUNCH_SETTLE_S``,
            ``PUNCH_WIDTH_S``).
        coupling: On the Beat's parent-torque coupling ("paper" or "exact", as ``kdfaces punch --coupling``).
        engine: the skeletal engine ("mujoco").
        widgets: draw the sliders and the play button (they also appear in screenshots).

    Attributes:
        frame: the displayed frame index into ``times``; times: the punch's frame times [s], shape (F,).
        t_i_s: the punch's t_i [s]; punch_target: its own fist target (3,) [m]; fist_target: the current one (3,) [m].
        points: the displayed observed points (3J + P, 3) [m] (pivots and frame markers, then the fist).
        ikd: the last solve (:class:`~kdfaces.ikd.solver.IKDResult`) or None; ikd_stale: a parameter or the target
            changed since (still shown until solved again).
        message: the status line's last edit or solve message.
        last_ms: wall time of the last KD state [ms] (0 in kinematic mode).
    """

    def __init__(self, *, off_screen: bool = False, size=(960, 720), window_s: float | None = None,
                 settle_time_s: float | None = None, width_s: float | None = None, coupling: str = "paper",
                 engine: str | None = None, widgets: bool = True):
        from ..articulated.chains import arm_chain_model
        from ..articulated.control import COUPLINGS
        from ..articulated.engines import DEFAULT_ENGINE
        from ..articulated.punch import PUNCH_SETTLE_S, PUNCH_WIDTH_S, PUNCH_WINDOW_S, punch_trajectory

        if coupling not in COUPLINGS:
            raise KDInputError(f"coupling {coupling!r} unknown; expected one of {COUPLINGS}")
        self.coupling, self.engine = coupling, DEFAULT_ENGINE if engine is None else engine
        self.model = arm_chain_model()
        self.trajectory, self.t_i_s, target = punch_trajectory(self.model)
        self.punch_target = np.asarray(target, dtype=np.float64)
        self.step_s = 1.0 / float(self.trajectory.fps)
        self.times = np.asarray(self.trajectory.frame_times, dtype=np.float64)
        self.window_s = float(PUNCH_WINDOW_S if window_s is None else window_s)
        window_steps(self.window_s, self.step_s)
        self.settle_time_s = self._positive(PUNCH_SETTLE_S if settle_time_s is None else settle_time_s,
                                            "settle time")
        self.width_s = self._positive(PUNCH_WIDTH_S if width_s is None else width_s, "correction width")
        self.max_correction_m = float(defaults.MAX_CORRECTION_M)
        self._build_system()
        self.fist = self.system.point_index("fist")
        sk = self.model.skeleton
        J = self.model.num_joints
        #: the arm's reach [m]: its segments end to end from the root pivot (the fist can be no farther from it)
        seg = np.linalg.norm(np.diff(sk.positions, axis=0), axis=1).sum()
        self.reach_m = float(seg + np.linalg.norm(self.model.points_world(np.zeros((1, J, 3)), ["fist"])[0, 0]
                                                  - sk.positions[-1]))
        self.fist_target = self.punch_target.copy()
        self.ikd = None
        self.ikd_stale = False
        self.message = "fist target: the punch's (drag it, or offset_fist_target_mm; i: solve)"
        self.mode = "kd"
        self.frame = self.ti_frame
        self.playing = False
        self.last_ms = 0.0
        self._build_scene(off_screen, size, widgets)
        self.frame = self.ti_frame  # after the frame slider, which calls back with frame 0 as it is made
        self.update()

    @staticmethod
    def _positive(value, what: str) -> float:
        v = float(value)
        if not (np.isfinite(v) and v > 0):
            raise KDInputError(f"{what}: expected positive seconds, got {value!r}")
        return v

    # --- dynamics ----------------------------------------------------------------------------------------------
    def _build_system(self) -> None:
        from ..articulated.punch import PUNCH_SUBSTEP_S
        from ..articulated.system import SkeletalSystem

        self.system = SkeletalSystem(self.model, settle_time_s=self.settle_time_s, engine=self.engine,
                                     substep_s=PUNCH_SUBSTEP_S, coupling=self.coupling)
        self._kd_fist = None  # the uncorrected KD fist at t_i (3,) [m], computed on demand

    @property
    def ti_frame(self) -> int:
        """The frame index of t_i."""
        return int(np.argmin(np.abs(self.times - self.t_i_s)))

    @property
    def shown_trajectory(self):
        """θ(t) of the display: the solve's corrected trajectory in ``"ikd"`` mode once solved, else θ_K(t)."""
        return self.ikd.trajectory if (self.mode == "ikd" and self.ikd is not None) else self.trajectory

    def state(self, frame: int | None = None, mode: str | None = None) -> np.ndarray:
        """Observed points (3J + P, 3) [m] of ``frame`` in ``mode`` (default the displayed ones); sets ``last_ms``."""
        k = self.frame if frame is None else int(frame)
        mode = self.mode if mode is None else mode
        t = self.times[k]
        if mode == "kinematic":
            self.last_ms = 0.0
            return self.system.observe_kinematic(self.trajectory, [t])[0]
        traj = self.ikd.trajectory if (mode == "ikd" and self.ikd is not None) else self.trajectory
        t0 = time.perf_counter()
        x = simulate_kd(self.system, traj, [t], self.window_s, step_s=self.step_s)[0]
        self.last_ms = 1e3 * (time.perf_counter() - t0)
        return x

    def kd_fist(self) -> np.ndarray:
        """The uncorrected KD fist at t_i (3,) [m]: where the constraint's correction starts from."""
        if self._kd_fist is None:
            ms = self.last_ms
            self._kd_fist = self.state(self.ti_frame, "kd")[self.fist].copy()
            self.last_ms = ms
        return self._kd_fist

    def kinematic_fist(self) -> np.ndarray:
        """The kinematic fist at t_i (3,) [m] (on the punch's own target: the keyframe's IK put it there)."""
        return self.system.observe_kinematic(self.trajectory, [self.t_i_s])[0][self.fist]

    def fist_error_m(self) -> float:
        """|fist − target| [m] at t_i in the displayed trajectory (KD, or IKD once solved and shown)."""
        mode = "ikd" if (self.mode == "ikd" and self.ikd is not None) else "kd"
        if mode == "kd":
            return float(np.linalg.norm(self.kd_fist() - self.fist_target))
        ms = self.last_ms
        x = self.state(self.ti_frame, mode)
        self.last_ms = ms
        return float(np.linalg.norm(x[self.fist] - self.fist_target))

    # --- the fist target (drag, offset, i, c) ------------------------------------------------------------------
    def check_target(self, point_m) -> str | None:
        """Why ``point_m`` (3,) [m] cannot be the fist target (None: it can): not a finite point, beyond the arm's
        reach (:attr:`reach_m` from the root pivot), or farther than ``max_correction_m`` from the KD fist at t_i."""
        try:
            p = np.asarray(point_m, dtype=np.float64).reshape(3)
        except (TypeError, ValueError):
            return f"fist target: expected a point (x, y, z) in metres, got {point_m!r}"
        if not np.isfinite(p).all():
            return f"fist target: expected a finite point (x, y, z) in metres, got {point_m!r}"
        d = float(np.linalg.norm(p - self.model.skeleton.positions[0]))
        if d > self.reach_m:
            return (f"fist target {1e2 * d:.1f} cm from the shoulder's root pivot is beyond the arm's reach "
                    f"({1e2 * self.reach_m:.1f} cm)")
        c = float(np.linalg.norm(p - self.kd_fist()))
        if c > self.max_correction_m:
            return (f"fist target {1e2 * c:.1f} cm from the KD fist at t_i is beyond max_correction_m "
                    f"({1e2 * self.max_correction_m:.0f} cm)")
        return None

    def set_fist_target(self, point_m) -> bool:
        """Dragging the target handle: the fist target at t_i at ``point_m`` (3,) [m]. A target the arm cannot reach
        is refused (:meth:`check_target`): its message goes to the status line and nothing changes. Returns
        whether the target moved."""
        why = self.check_target(point_m)
        if why is not None:
            self.message = f"refused: {why}; nothing changed"
            self.update_text()
            return False
        self.fist_target = np.asarray(point_m, dtype=np.float64).reshape(3).copy()
        if self.ikd is not None:
            self.ikd_stale = True
        self.message = (f"fist target at t_i = {self.t_i_s:.2f} s: {_mm(self.fist_target - self.kinematic_fist())} "
                        f"mm from the kinematic fist, KD fist {1e3 * self.fist_error_m():.2f} mm away (i: solve)")
        self.update()
        return True

    def offset_fist_target_mm(self, dx_mm: float, dy_mm: float, dz_mm: float) -> bool:
        """Typed offset: the fist target at the kinematic fist at t_i (the punch's target) plus (dx, dy, dz) [mm]."""
        d = np.array([dx_mm, dy_mm, dz_mm], dtype=np.float64)
        if not np.isfinite(d).all():
            self.message = f"refused: fist target offset: expected finite millimetres, got {(dx_mm, dy_mm, dz_mm)!r}" \
                           "; nothing changed"
            self.update_text()
            return False
        return self.set_fist_target(self.kinematic_fist() + 1e-3 * d)

    def reset_fist_target(self) -> None:
        """Key ``c``: the punch's own target again, and no solve (the uncorrected arm is shown)."""
        self.fist_target = self.punch_target.copy()
        self.ikd, self.ikd_stale = None, False
        if self.mode == "ikd":
            self.mode = "kd"
        self.message = "fist target: the punch's (drag it, or offset_fist_target_mm; i: solve)"
        self.update()

    def constraint(self):
        """The end-effector constraint of the fist target: on the fist at t_i, a Gaussian bell of width ``width_s``
        (as ``kdfaces punch`` builds it)."""
        from ..ikd import GaussianBasis, end_effector_constraint

        return end_effector_constraint(self.t_i_s, self.fist_target, [self.fist], GaussianBasis(self.t_i_s,
                                                                                               self.width_s),
                                       num_vertices=len(self.points), label="fist on target")

    def solve(self):
        """Key ``i``: IKD for the fist target, as ``kdfaces punch`` solves it (eq. 4–5 through J⁺ of the arm's chain
        Jacobian at the KD pose, Algorithm 1's update, its tolerance and sweeps); shows the IKD arm and the fist
        error before → after. Returns the :class:`~kdfaces.ikd.solver.IKDResult`; a solve that fails (the solver
        refuses) leaves the previous one and says why in the status line (returns None)."""
        from ..articulated.punch import PUNCH_MAX_ITERATIONS, PUNCH_TOLERANCE_M
        from ..ikd import solve_ikd

        try:
            r = solve_ikd(self.system, self.trajectory, [self.constraint()], window_s=self.window_s,
                          step_s=self.step_s, update="paper", tolerance_m=PUNCH_TOLERANCE_M,
                          max_iterations=PUNCH_MAX_ITERATIONS, max_correction_m=self.max_correction_m)
        except KDInputError as e:
            self.message = f"fist IKD: {e}"
            self.update_text()
            return None
        self.ikd, self.ikd_stale, self.mode = r, False, "ikd"
        met = "met" if r.errors_after[0] <= PUNCH_TOLERANCE_M else "NOT met"
        self.message = (f"fist IKD: {r.reason}, {r.iterations} sweeps, {r.wall_s:.2f} s   fist error "
                        f"{1e3 * r.errors_before[0]:.2f} -> {1e3 * r.errors_after[0]:.4f} mm ({met}: tolerance "
                        f"{1e3 * PUNCH_TOLERANCE_M:g} mm)")
        self.update()
        return r

    # --- callbacks (sliders, keys, buttons) --------------------------------------------------------------------
    def set_window(self, value) -> None:
        """Window slider: KD window δ [s] (rounded up to whole steps by ``simulate_kd``)."""
        window_steps(float(value), self.step_s)
        if float(value) == self.window_s:
            return
        self.window_s = float(value)
        self._parameters_changed()

    def set_settle_time(self, value) -> None:
        """Tension slider: the arm's settle time t̂ [s] (a larger t̂ is a more relaxed arm)."""
        v = self._positive(value, "settle time")
        if v == self.settle_time_s:
            return
        self.settle_time_s = v
        self._build_system()
        self._parameters_changed()

    def set_width(self, value) -> None:
        """Correction-width slider: σ [s] of the fist constraint's bell (takes effect at the next solve)."""
        v = self._positive(value, "correction width")
        if v == self.width_s:
            return
        self.width_s = v
        self._parameters_changed()

    def _parameters_changed(self) -> None:
        self._kd_fist = None
        if self.ikd is not None:
            self.ikd_stale = True  # still shown (against the new parameters) until solved again
        self.update()

    # --- scene -------------------------------------------------------------------------------------------------
    def arm_points(self, x: np.ndarray) -> np.ndarray:
        """The arm's polyline (J + 2, 3) [m] in observed points ``x`` (3J + P, 3): the chest centre, the joint
        pivots, the fist (what ``kdfaces punch``'s figures draw)."""
        sk = self.model.skeleton
        J = self.model.num_joints
        pivots = np.asarray(x[: 3 * J: 3], dtype=np.float64)
        chest = np.array([0.0, sk.positions[0, 1], sk.positions[0, 2]]) + (pivots[0] - sk.positions[0])
        return np.vstack([chest, pivots, x[self.fist]])

    @staticmethod
    def _arm_mesh(points: np.ndarray, scale: float = 1.0):
        """Tubes along the arm's polyline (J + 2, 3) [m] and balls on its joints (not the fist: its own marker)."""
        import pyvista as pv

        tube = pv.lines_from_points(points).tube(radius=scale * _TUBE_M, n_sides=16)
        balls = pv.PolyData(points[:-1]).glyph(geom=pv.Sphere(radius=scale * _JOINT_M, theta_resolution=16,
                                                         phi_resolution=12), scale=False, orient=False)
        return tube.append_polydata(balls)

    def _build_scene(self, off_screen: bool, size, widgets: bool) -> None:
        import pyvista as pv

        kin = self.system.observe_kinematic(self.trajectory, self.times)
        self.plotter = pl = pv.Plotter(off_screen=off_screen, window_size=tuple(size), lighting="three lights")
        pl.set_background("white")
        x0 = self.state(self.frame)
        self.arm = self._arm_mesh(self.arm_points(x0))
        self.ghost = self._arm_mesh(self.arm_points(kin[self.frame]), 0.7)
        sk = self.model.skeleton  # a faint torso below the chest, for scale (the arm's root is fixed to it)
        w = abs(float(sk.positions[1, 0]))
        pl.add_mesh(pv.Box((-w, w, sk.positions[0, 1] - 0.55, sk.positions[0, 1] + 0.03, -0.09, 0.11)),
                    color=GHOST_COLOR, opacity=0.18)
        self._arm_actor = pl.add_mesh(self.arm, color=ARM_COLOR, smooth_shading=True, specular=0.3)
        self._ghost_actor = pl.add_mesh(self.ghost, color=GHOST_COLOR, opacity=0.45, smooth_shading=True)
        self._target_sphere = pv.Sphere(radius=_TARGET_M, center=(0.0, 0.0, 0.0))
        self._target_rest = np.asarray(self._target_sphere.points).copy()
        self._target_actor = pl.add_mesh(self._target_sphere, color=TARGET_COLOR, opacity=0.9)
        self._fist_actor = None
        self._target_widget = None
        self._off_screen = off_screen
        # the camera: the character's right side, a little from the front and above, on the punch's whole path
        path = np.vstack([self.arm_points(k) for k in kin] + [self.punch_target[None]])
        lo, hi = path.min(axis=0), path.max(axis=0)
        size_m = float(np.linalg.norm(hi - lo))
        d = np.array([-1.0, 0.35, 0.3])
        d /= np.linalg.norm(d)
        right = np.cross(-d, [0.0, 1.0, 0.0])
        center = 0.5 * (lo + hi) + 0.22 * size_m * right / np.linalg.norm(right)  # the arm left of the sliders
        position = center + 2.6 * size_m * d
        sliders = [("window", self.set_window, (self.step_s, max(1.0, self.window_s)), self.window_s, "window [s]"),
                   ("settle", self.set_settle_time, (0.03, 0.6), self.settle_time_s, "tension t^ [s]"),
                   ("sigma", self.set_width, (0.03, 0.5), self.width_s, "correction width [s]")]
        self._add_controls(center, position, sliders, widgets=widgets, off_screen=off_screen)
        if widgets:
            pl.add_text("play", position=(52, 18), font_size=9, color="black")
        if not off_screen:
            pl.add_key_event("m", self._guarded(self.cycle_mode))
            pl.add_key_event("i", self._guarded(self.solve))
            pl.add_key_event("c", self._guarded(self.reset_fist_target))

    def update(self) -> None:
        """Recompute the displayed frame's state and redraw."""
        x = self.state()
        ms = self.last_ms
        self.points = x
        self.arm.copy_from(self._arm_mesh(self.arm_points(x)))
        kin = self.system.observe_kinematic(self.trajectory, [self.times[self.frame]])[0]
        self.ghost.copy_from(self._arm_mesh(self.arm_points(kin), 0.7))
        self._ghost_actor.SetVisibility(self.mode != "kinematic")
        self._draw_target()
        self.last_ms = ms
        slider = self._sliders.get("frame")
        if slider is not None:
            slider.GetRepresentation().SetValue(self.frame)
        self.update_text()

    def _draw_target(self) -> None:
        """The target (always: a point in space), the displayed fist, and at the t_i frame the draggable handle."""
        pl = self.plotter
        self._target_sphere.points = self._target_rest + self.fist_target
        if self._fist_actor is not None:
            pl.remove_actor(self._fist_actor)
        self._fist_actor = pl.add_points(np.asarray(self.points[self.fist])[None], color=FIST_COLOR, point_size=16,
                                         render_points_as_spheres=True, reset_camera=False)
        if self._off_screen:
            return
        on = self.frame == self.ti_frame
        if on:
            if self._target_widget is None:
                self._target_widget = pl.add_sphere_widget(self._guarded(self._drag), center=self.fist_target,
                                                           radius=1.3 * _TARGET_M, color=TARGET_COLOR)
            else:
                self._target_widget.SetCenter(*self.fist_target)
            self._target_widget.On()
        elif self._target_widget is not None:
            self._target_widget.Off()

    def _drag(self, center) -> None:
        if not np.allclose(center, self.fist_target, atol=1e-9):
            if not self.set_fist_target(center) and self._target_widget is not None:
                self._target_widget.SetCenter(*self.fist_target)  # refused: the handle goes back

    def status(self) -> str:
        """The on-screen text: frame, time, mode, ms per KD state, window, tension, the fist target and solve."""
        n = len(self.times)
        shown = _MODE_NAMES[self.mode]
        if self.mode == "ikd" and self.ikd is None:
            shown = "IKD (not solved: showing KD)"
        at = "  (t_i)" if self.frame == self.ti_frame else ""
        fist = ""
        if self.frame == self.ti_frame and self.mode != "kinematic":
            fist = f"   fist {1e3 * np.linalg.norm(self.points[self.fist] - self.fist_target):.2f} mm from the target"
        return "\n".join([
            f"the relaxed punch   frame {self.frame}/{n - 1}   t = {self.times[self.frame]:.2f} s{at}   {shown}"
            + ("   [playing]" if self.playing else ""),
            f"KD state: {self.last_ms:.1f} ms   window {self.window_s:.2f} s "
            f"({window_steps(self.window_s, self.step_s)} steps of {1e3 * self.step_s:.0f} ms)   tension "
            f"{self.settle_time_s:.2f} s   width {self.width_s:.2f} s{fist}",
            "m: kinematic/KD/IKD   drag the green target at t_i   i: solve   c: reset   space: play",
            self.message + ("  [stale: press i]" if self.ikd_stale else "")])

    # --- output ------------------------------------------------------------------------------------------------
    def show(self) -> None:
        """Open the interactive window (blocks until it is closed); playback at the punch's frame rate."""
        self._open_window(float(self.trajectory.fps), "kdfaces punch --view: the relaxed punch")

    def close(self) -> None:
        """Close the window and free the plotter."""
        self.plotter.close()


def view_punch(*, screenshot=None, size=(960, 720), coupling: str = "paper") -> dict:
    """Open the punch viewer at the t_i frame, or with ``screenshot`` render that frame (KD, the punch's target)
    off-screen to a PNG (checked first, :func:`~kdfaces.viz.viewer.check_screenshot_path`). Returns a small summary
    (frame, t_i, window, ms per KD state, the fist's miss at t_i)."""
    size = check_window_size(size)
    if screenshot is not None:
        check_screenshot_path(screenshot)
    viewer = PunchViewer(off_screen=screenshot is not None, size=size, coupling=coupling)
    try:
        summary = {"frame": viewer.frame, "time_s": float(viewer.times[viewer.frame]), "t_i_s": viewer.t_i_s,
                   "window_s": viewer.window_s, "settle_time_s": viewer.settle_time_s, "kd_state_ms": viewer.last_ms,
                   "fist_error_m": viewer.fist_error_m()}
    except BaseException:
        viewer.close()
        raise
    return viewer.finish(summary, screenshot)


class _ViewAction(argparse.Action):
    """``--view``: also drops the default output folder (the viewer writes none; an explicit ``--out`` is refused)."""

    def __call__(self, parser, namespace, values, option_string=None):
        namespace.view = True
        if namespace.out == parser.get_default("out"):
            namespace.out = None


def add_view_options(parser) -> None:
    """Add ``--view [--screenshot FILE]`` to ``kdfaces punch``."""
    parser.add_argument("--view", action=_ViewAction, nargs=0, default=False,
                        help="open the punch viewer instead (scrub the KD arm, drag the fist target at t_i, solve)")
    parser.add_argument("--screenshot", metavar="FILE",
                        help="with --view: render the t_i frame off-screen to this PNG and exit")
    parser.add_argument("--width", type=int, default=960, help="with --view: window width [px]")
    parser.add_argument("--height", type=int, default=720, help="with --view: window height [px]")


def punch_view_command(args) -> dict:
    """``kdfaces punch --view``: :func:`view_punch` from parsed arguments (``--screenshot`` only with ``--view``;
    ``--out`` not with it)."""
    if not args.view:
        raise KDInputError("--screenshot: only with --view")
    if args.out is not None:
        raise KDInputError("--out: the punch viewer writes no folder; with --view give --screenshot FILE instead")
    return view_punch(screenshot=args.screenshot, size=(args.width, args.height), coupling=args.coupling)
