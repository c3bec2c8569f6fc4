"""``kdfem view``: the scrubbing viewer of §6.6 (Fig. 11) for the hat, like ``kdfaces view`` for faces.

Every displayed frame is the hat's KD state at that frame's time, computed history-free (one ``simulate_kd`` over
the window δ ending there), so scrubbing back and forth or jumping costs the same per frame; its time in ms is shown
on screen. A timeline slider picks the frame of the demo animation (the head nods and turns); sliders set δ and the
material (Young's modulus E, Rayleigh α); a checkbox (key ``r``) toggles between the reduced hat (modes in the head
frame, :class:`~kdfem.fem.reduced.ReducedHatSystem`, the default: a state costs about a millisecond) and the full
FEM (:class:`~kdfem.fem.system.HatSystem`). Keys: ``space`` play/stop, ``r`` full/reduced, ``Left``/``Right`` one
frame. Every slider and key calls a plain method of :class:`HatViewer`, so tests drive it programmatically;
``kdfem view --screenshot FILE --frame F`` renders one frame off-screen.

The hat's tip has a draggable target (paper §4.4, as ``kdfem door`` solves it): ``t`` puts a target handle (a sphere
widget) on the tip's KD position at the current frame, dragging it (:meth:`HatViewer.set_tip_target`) or typing an
offset (:meth:`HatViewer.offset_tip_target_mm`) moves it, and ``i`` (:meth:`HatViewer.solve_tip`) solves IKD on the
head posture: an end-effector constraint on the tip at the frame's time whose error maps to the neck and head
angles through J⁺ of the chain Jacobian (eq. 4-5); the corrected head and hat are shown, with the tip error before
and after. ``c`` clears the target.
"""

from __future__ import annotations

import time

import numpy as np

from kdfaces import defaults
from kdfaces.errors import KDInputError
from kdfaces.kd import simulate_kd, window_steps
from kdfaces.viz.figures import SKIN
from kdfaces.viz.viewer import PlotterWindow, check_screenshot_path, check_view_arguments, check_window_size

__all__ = ["HatViewer", "view_hat", "add_view_parser", "HAT_COLOR", "TARGET_COLOR"]

#: The hat's colour on screen; the tip target handle's.
HAT_COLOR = "#c8102e"
TARGET_COLOR = "#1a9850"


def _mm(d) -> str:
    """A displacement (3,) [m] as "(x, y, z)" in mm."""
    return "(" + ", ".join(f"{1e3 * v:+.1f}" for v in d) + ")"


class HatViewer(PlotterWindow):
    """A pyvista window over the hat demo: timeline, play/stop, δ and material sliders, full/reduced toggle.

    Args:
        rig: "default" or a rig file (with a head joint).
        off_screen: render without a window (screenshots, tests).
        size: window (width, height) in pixels.
        window_s: KD window δ [s] (default the demo's, ``defaults.HAT_WINDOW_S``).
        step_s: simulation step [s] (default ``defaults.HAT_STEP_S``).
        reduced: start with the reduced hat (else the full FEM).
        youngs_pa: Young's modulus E [Pa] (default the demo hat's).
        modes: modes of the reduced hat.
        widgets: draw the sliders, the toggle and the play button (they also appear in screenshots).
        cache_dir: where tets of a non-default hat are cached.

    Attributes:
        frame: the displayed frame index into ``times``; times: the demo's frame times [s], shape (F,).
        points: the displayed hat node positions [m], shape (N, 3).
        last_ms: wall time of the last KD state [ms].
    """

    def __init__(self, *, rig="default", off_screen: bool = False, size=(960, 720), window_s: float | None = None,
                 step_s: float = defaults.HAT_STEP_S, reduced: bool = True, youngs_pa: float | None = None,
                 modes: int = 24, widgets: bool = True, cache_dir=None):
        from kdfaces.io.rigfiles import load_rig
        from kdfaces.motion.trajectory import KinematicTrajectory
        from kdfaces.shots.builtin import demo_animation

        from .fem.attachment import attached_nodes
        from .fem.default_hat import DEFAULT_MATERIAL, hat_tetmesh
        from .geometry.tetmesh import embed_surface

        self.rig = load_rig(rig)
        anim = demo_animation()
        self.trajectory = KinematicTrajectory(self.rig, anim)
        self.joints = self.trajectory.joints
        self.step_s = float(step_s)
        self.times = np.round(anim.frame_times / self.step_s) * self.step_s  # frames on the step grid
        self.surface_mesh, self.mesh, _ = hat_tetmesh(cache_dir=cache_dir)
        self.attached = attached_nodes(self.mesh.nodes, self.rig.neutral)
        self.embedding = embed_surface(self.mesh, self.surface_mesh.vertices)
        self.youngs_pa = float(DEFAULT_MATERIAL.youngs_pa if youngs_pa is None else youngs_pa)
        self.rayleigh_alpha = float(defaults.RAYLEIGH_ALPHA)
        self.modes = int(modes)
        self.reduced = bool(reduced)
        self._systems: dict = {}
        self.window_s = float(defaults.HAT_WINDOW_S if window_s is None else window_s)
        window_steps(self.window_s, self.step_s)
        self.animation = anim
        rest_surface = self.embedding.apply(self.mesh, self.mesh.nodes)
        #: the tip: the render-surface vertex highest on the rest hat (as ``kdfem door`` picks it)
        self.tip = int(np.argmax(rest_surface[:, 1]))
        nodes, w = self.mesh.tets[self.embedding.tet[self.tip]], self.embedding.weights[self.tip]
        keep = w != 0
        self._tip_nodes, self._tip_weights = np.asarray(nodes[keep]), w[keep] / w[keep].sum()
        self.tip_target = None  # (3,) [m] at ``tip_time_s``, or None
        self.tip_time_s = None
        self.width_s = float(defaults.WIDTH_S)
        self.ikd = None  # the last tip solve (IKDResult), or None
        self.ikd_stale = False
        self._ikd_face = None  # the face riding on the corrected joints
        self.ikd_message = "tip target: none (t: set one at this frame)"
        self.frame = 0
        self.playing = False
        self.last_ms = 0.0
        self._build_scene(off_screen, size, widgets)
        self.update()

    # --- dynamics ----------------------------------------------------------------------------------------------
    @property
    def system(self):
        """The hat system for the current material and full/reduced choice (built once per combination)."""
        from .fem.materials import Material
        from .fem.model import FEMModel
        from .fem.reduced import ReducedHatSystem
        from .fem.system import HatSystem

        key = (self.youngs_pa, self.rayleigh_alpha, self.reduced)
        if key not in self._systems:
            from .fem.default_hat import DEFAULT_MATERIAL

            material = Material(youngs_pa=self.youngs_pa, poisson_ratio=DEFAULT_MATERIAL.poisson_ratio,
                                density_kg_m3=DEFAULT_MATERIAL.density_kg_m3, model=DEFAULT_MATERIAL.model)
            model = FEMModel(self.mesh, material, self.attached, rayleigh_alpha=self.rayleigh_alpha,
                             rayleigh_beta=defaults.RAYLEIGH_BETA)
            self._systems[key] = (ReducedHatSystem(model, embedding=self.embedding, modes=self.modes)
                                  if self.reduced else HatSystem(model, embedding=self.embedding))
        return self._systems[key]

    def state(self, frame: int | None = None) -> np.ndarray:
        """Hat node positions (N, 3) [m] of ``frame`` (default the displayed one); sets ``last_ms``."""
        k = self.frame if frame is None else frame
        t0 = time.perf_counter()
        x = simulate_kd(self.system, self.shown_joints, [self.times[k]], self.window_s, step_s=self.step_s)[0]
        self.last_ms = 1e3 * (time.perf_counter() - t0)
        return x

    @property
    def shown_joints(self):
        """The joint trajectory the display follows: the tip solve's corrected θ(t) once solved, else θ_K(t)."""
        return self.joints if self.ikd is None else self.ikd.trajectory

    def tip_point(self, x: np.ndarray | None = None) -> np.ndarray:
        """The tip's position (3,) [m] in hat node positions ``x`` (N, 3) (default the displayed KD state): the
        embedding's barycentric combination of its tet's nodes, the point the tip constraint measures."""
        x = self.points if x is None else np.asarray(x, dtype=np.float64)
        return self._tip_weights @ x[self._tip_nodes]

    # --- the tip target (t, drag, i, c) ------------------------------------------------------------------------
    def add_tip_target(self) -> None:
        """Key ``t``: a tip target at the current frame, on the tip's displayed KD position (drag it or offset it)."""
        self.tip_time_s = float(self.times[self.frame])
        self._set_target(self.tip_point())

    def set_tip_target(self, point_m) -> None:
        """Dragging the target handle: the tip target at ``point_m`` (3,) [m] (a target at the current frame is
        made first if there is none)."""
        p = np.asarray(point_m, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise KDInputError(f"tip target: expected a finite point (x, y, z) in metres, got {point_m!r}")
        if self.tip_target is None:
            self.tip_time_s = float(self.times[self.frame])
        self._set_target(p)

    def offset_tip_target_mm(self, dx_mm: float, dy_mm: float, dz_mm: float) -> None:
        """Typed offset: the tip target at the tip's KD position (before this solve's correction, at the target's
        frame) plus (dx, dy, dz) [mm]."""
        d = np.array([dx_mm, dy_mm, dz_mm], dtype=np.float64)
        if not np.isfinite(d).all():
            raise KDInputError(f"tip target offset: expected finite millimetres, got {(dx_mm, dy_mm, dz_mm)!r}")
        if self.tip_target is None:
            self.tip_time_s = float(self.times[self.frame])
        k = int(np.argmin(np.abs(self.times - self.tip_time_s)))
        base = simulate_kd(self.system, self.joints, [self.times[k]], self.window_s, step_s=self.step_s)[0]
        self._set_target(self.tip_point(base) + 1e-3 * d)

    def clear_tip_target(self) -> None:
        """Key ``c``: remove the tip target and its solve (the uncorrected posture is shown again)."""
        self.tip_target = self.tip_time_s = self.ikd = self._ikd_face = None
        self.ikd_stale = False
        self.ikd_message = "tip target: none (t: set one at this frame)"
        self.update()

    def _set_target(self, p: np.ndarray) -> None:
        self.tip_target = np.array(p, dtype=np.float64)
        if self.ikd is not None:
            self.ikd_stale = True
        self.ikd_message = (f"tip target at t = {self.tip_time_s:.2f} s: "
                            f"{_mm(self.tip_target - self._uncorrected_tip())} mm from the KD tip (i: solve)")
        self.update()

    def _uncorrected_tip(self) -> np.ndarray:
        k = int(np.argmin(np.abs(self.times - self.tip_time_s)))
        return self.tip_point(simulate_kd(self.system, self.joints, [self.times[k]], self.window_s,
                                          step_s=self.step_s)[0])

    def tip_constraint(self):
        """The end-effector constraint of the tip target (:func:`kdfaces.ikd.end_effector_constraint` on the
        tip's nodes and barycentric weights, a Gaussian bell of width ``width_s`` [s] at ``tip_time_s``)."""
        from kdfaces.ikd.bases import make_basis
        from kdfaces.ikd.constraints import end_effector_constraint

        if self.tip_target is None:
            raise KDInputError("tip target: none set (key t, or drag the handle, first)")
        return end_effector_constraint(self.tip_time_s, self.tip_target, self._tip_nodes,
                                       make_basis(defaults.CURVE, self.tip_time_s, width_s=self.width_s),
                                       weights=self._tip_weights, num_vertices=self.mesh.num_nodes, label="tip")

    def solve_tip(self):
        """Key ``i``: IKD on the head posture for the tip target (eq. 4-5: the tip's error maps to the neck and
        head angles through J⁺ of the chain Jacobian at its KD position fixed in the head frame, §4.4); shows
        the corrected head and hat and the tip error before/after. Returns the
        :class:`~kdfaces.ikd.solver.IKDResult`, or None (with a message) without a target."""
        from kdfaces.ikd.solver import solve_ikd
        from kdfaces.motion.trajectory import KinematicTrajectory

        if self.tip_target is None:
            self.ikd_message = "tip target: none to solve for (key t, or drag the handle, first)"
            self.update_text()
            return None
        r = solve_ikd(self.system, self.joints, [self.tip_constraint()], window_s=self.window_s,
                      step_s=self.step_s, tolerance_m=defaults.TOLERANCE_M)
        self.ikd, self.ikd_stale = r, False
        self._ikd_face = KinematicTrajectory(self.rig, self.animation, joints=r.trajectory)
        self.ikd_message = (f"tip IKD: {r.reason}, {r.iterations} sweeps, {r.wall_s:.2f} s   tip error "
                            f"{1e3 * r.errors_before[0]:.2f} -> {1e3 * r.errors_after[0]:.4f} mm")
        self.update()
        return r

    # --- callbacks (sliders, keys, buttons) --------------------------------------------------------------------
    def set_window(self, value) -> None:
        """Window slider: KD window δ [s] (rounded up to whole steps by ``simulate_kd``)."""
        window_steps(float(value), self.step_s)
        self.window_s = float(value)
        self._parameters_changed()

    def set_youngs(self, value_kpa) -> None:
        """Material slider: Young's modulus E [kPa]."""
        v = float(value_kpa)
        if not (np.isfinite(v) and v > 0):
            raise KDInputError(f"Young's modulus: expected positive kPa, got {value_kpa}")
        self.youngs_pa = 1e3 * v
        self._parameters_changed()

    def set_damping(self, value) -> None:
        """Material slider: Rayleigh α [1/s] (mass damping, relative to the head)."""
        v = float(value)
        if not (np.isfinite(v) and v >= 0):
            raise KDInputError(f"Rayleigh alpha: expected a non-negative number of 1/s, got {value}")
        self.rayleigh_alpha = v
        self._parameters_changed()

    def set_reduced(self, reduced) -> None:
        """Toggle (key ``r``): the reduced hat (True) or the full FEM (False)."""
        self.reduced = bool(reduced)
        self._parameters_changed()

    def _parameters_changed(self) -> None:
        if self.ikd is not None:
            self.ikd_stale = True  # still shown (against the new hat) until solved again
        self.update()

    def toggle_reduced(self) -> None:
        """Switch between the reduced hat and the full FEM."""
        self.set_reduced(not self.reduced)

    # --- scene -------------------------------------------------------------------------------------------------
    def _build_scene(self, off_screen: bool, size, widgets: bool) -> None:
        import pyvista as pv

        def poly(points, faces):
            f = np.asarray(faces, dtype=np.int64)
            return pv.PolyData(np.asarray(points, dtype=np.float64).copy(),
                               np.hstack([np.full((len(f), 1), 3), f]).ravel())

        self.head = poly(self.rig.neutral, self.rig.faces)
        self.hat = poly(self.surface_mesh.vertices, self.surface_mesh.faces)
        self.plotter = pl = pv.Plotter(off_screen=off_screen, window_size=tuple(size), lighting="three lights")
        pl.set_background("white")
        pl.add_mesh(self.head, color=SKIN, smooth_shading=True, specular=0.2)
        pl.add_mesh(self.hat, color=HAT_COLOR, smooth_shading=True, specular=0.3)
        self._target_sphere = pv.Sphere(radius=0.006, center=(0.0, 0.0, 0.0))
        self._target_rest = np.asarray(self._target_sphere.points).copy()
        self._target_actor = pl.add_mesh(self._target_sphere, color=TARGET_COLOR)
        self._target_actor.SetVisibility(False)
        self._tip_actor = None
        self._target_widget = None
        self._off_screen = off_screen
        center = np.array([0.0, 0.86, 0.0])
        d = np.array([0.9, 0.25, 0.6])
        sliders = [("window", self.set_window, (self.step_s, max(1.5, self.window_s)), self.window_s, "window [s]"),
                   ("youngs", self.set_youngs, (0.5, 30.0), self.youngs_pa / 1e3, "Young's modulus [kPa]"),
                   ("alpha", self.set_damping, (0.0, 5.0), self.rayleigh_alpha, "Rayleigh alpha [1/s]")]
        self._add_controls(center, center + 1.35 * d / np.linalg.norm(d), sliders, widgets=widgets,
                           off_screen=off_screen)
        if widgets:
            self._reduced_button = pl.add_checkbox_button_widget(self.set_reduced, value=self.reduced,
                                                                 position=(10, 60), size=36, color_on="#3b6fb6",
                                                                 color_off="grey")
            pl.add_text("reduced", position=(52, 68), font_size=9, color="black")
            pl.add_text("play", position=(52, 18), font_size=9, color="black")
        if not off_screen:
            pl.add_key_event("r", self.toggle_reduced)
            pl.add_key_event("t", self._guarded(self.add_tip_target))
            pl.add_key_event("i", self._guarded(self.solve_tip))
            pl.add_key_event("c", self._guarded(self.clear_tip_target))

    def update(self) -> None:
        """Recompute the displayed frame's KD state and redraw."""
        x = self.state()
        self.points = x
        self.hat.points = self.system.surface(x)
        face = self.trajectory if self._ikd_face is None else self._ikd_face
        self.head.points = face.positions([self.times[self.frame]])[0]
        self._draw_target()
        slider = self._sliders.get("frame")
        if slider is not None:
            slider.GetRepresentation().SetValue(self.frame)
        button = getattr(self, "_reduced_button", None)
        if button is not None:
            button.GetRepresentation().SetState(int(self.reduced))
        self.update_text()

    def _draw_target(self) -> None:
        """The target handle (at the target's frame only) and the tip's KD position as a point."""
        pl = self.plotter
        if self._tip_actor is not None:
            pl.remove_actor(self._tip_actor)
            self._tip_actor = None
        on = self.tip_target is not None and abs(self.times[self.frame] - self.tip_time_s) <= 0.5 * self.step_s
        self._target_actor.SetVisibility(bool(on))
        if on:
            self._target_sphere.points = self._target_rest + self.tip_target
            self._tip_actor = pl.add_points(self.tip_point()[None], color="#f28e2b", point_size=12,
                                            render_points_as_spheres=True, reset_camera=False)
            if not self._off_screen:
                if self._target_widget is None:
                    self._target_widget = pl.add_sphere_widget(self._guarded(self._drag), center=self.tip_target,
                                                               radius=0.008, color=TARGET_COLOR)
                else:
                    self._target_widget.SetCenter(*self.tip_target)
                self._target_widget.On()
        elif self._target_widget is not None:
            self._target_widget.Off()

    def _drag(self, center) -> None:
        if self.tip_target is None or not np.allclose(center, self.tip_target):
            self.set_tip_target(center)

    def status(self) -> str:
        """The on-screen text: frame, time, full/reduced, ms per KD state, window, material, the tip target."""
        n = len(self.times)
        kind = f"reduced ({self.modes} modes)" if self.reduced else "full FEM"
        return "\n".join([
            f"hat demo   frame {self.frame}/{n - 1}   t = {self.times[self.frame]:.2f} s   {kind}"
            + ("   [playing]" if self.playing else ""),
            f"KD state: {self.last_ms:.1f} ms   window {self.window_s:.3f} s "
            f"({window_steps(self.window_s, self.step_s)} steps of {1e3 * self.step_s:.0f} ms)",
            f"E = {self.youngs_pa / 1e3:.2f} kPa   Rayleigh alpha = {self.rayleigh_alpha:.2f} 1/s   "
            "(r: full/reduced, space: play, t: tip target, i: solve, c: clear)",
            self.ikd_message + ("  [stale: press i]" if self.ikd_stale else "")])

    # --- output ------------------------------------------------------------------------------------------------
    def show(self) -> None:
        """Open the interactive window (blocks until it is closed); playback at the animation's frame rate."""
        self._open_window(float(self.trajectory.fps), "kdfem view: the hat")

    def close(self) -> None:
        """Close the window and free the plotter."""
        self.plotter.close()


def view_hat(*, rig="default", screenshot=None, frame: int = 0, reduced: bool = True, window_s=None,
             youngs_pa=None, size=(960, 720), cache_dir=None) -> dict:
    """Open the hat viewer, or with ``screenshot`` render ``frame`` off-screen to a PNG. Returns a small summary
    (frame, time, full/reduced, ms per KD state); ``screenshot`` must be a ``.png`` path (checked first, see
    :func:`kdfaces.viz.viewer.check_screenshot_path`)."""
    size = check_window_size(size)
    if youngs_pa is not None and not (isinstance(youngs_pa, int | float) and np.isfinite(youngs_pa) and youngs_pa > 0):
        raise KDInputError(f"youngs_pa: expected a positive Young's modulus [Pa], got {youngs_pa!r}")
    if screenshot is not None:
        check_screenshot_path(screenshot)
    viewer = HatViewer(rig=rig, off_screen=screenshot is not None, size=size, window_s=window_s, reduced=reduced,
                       youngs_pa=youngs_pa, cache_dir=cache_dir)
    try:
        n = len(viewer.times)
        if not 0 <= int(frame) < n:
            raise KDInputError(f"--frame: {frame} is outside the animation's frames 0..{n - 1}")
        viewer.set_frame(int(frame))
        summary = {"frame": viewer.frame, "time_s": float(viewer.times[viewer.frame]),
                   "system": "reduced" if viewer.reduced else "full", "window_s": viewer.window_s,
                   "youngs_pa": viewer.youngs_pa, "kd_state_ms": viewer.last_ms}
    except BaseException:
        viewer.close()
        raise
    return viewer.finish(summary, screenshot)


def _view_command(args) -> dict:
    check_view_arguments(args)
    return view_hat(rig=args.rig, screenshot=args.screenshot, frame=args.frame, reduced=not args.full,
                    window_s=args.window, youngs_pa=None if args.youngs_kpa is None else 1e3 * args.youngs_kpa,
                    size=(args.width, args.height))


def add_view_parser(subparsers) -> None:
    """Add ``kdfem view [--screenshot FILE --frame F] [--full] [--window S] [--youngs-kpa E]``."""
    ap = subparsers.add_parser("view", help="scrub the hat's KD states interactively (or screenshot one frame)")
    ap.add_argument("--rig", default="default", help="rig: 'default' or an .npz rig with a head joint")
    ap.add_argument("--screenshot", metavar="FILE", help="render one frame off-screen to this PNG and exit")
    ap.add_argument("--frame", type=int, default=0, help="frame index for --screenshot (default 0)")
    ap.add_argument("--full", action="store_true", help="start with the full FEM instead of the reduced hat")
    ap.add_argument("--window", type=float, help=f"KD window δ [s] (default {defaults.HAT_WINDOW_S})")
    ap.add_argument("--youngs-kpa", type=float, help="Young's modulus E [kPa] (default the demo hat's 3)")
    ap.add_argument("--width", type=int, default=960, help="window width [px]")
    ap.add_argument("--height", type=int, default=720, help="window height [px]")
    ap.add_argument("--json", action="store_true", help="print the summary to stdout")
    ap.set_defaults(func=_view_command)
