"""The scrubbing viewer (paper §6.6, Fig. 11): a timeline that shows the KD state of any frame on demand.

Every displayed frame is computed history-free: one ``simulate_kd`` call over the window δ ending at that frame's
time, so scrubbing back and forth, or jumping, costs the same per frame (the time in ms is shown on screen).
Sliders change the settle time, damping ratio, window δ and the IKD correction width σ; the display toggles
between the kinematic pose, the KD state and the IKD state; a key solves IKD for the shot's constraints.

With adaptive windows (the shot's ``window_s = "adaptive"``, ``--window adaptive`` or key ``a``) each frame has its
own window δ(t), the smallest whose truncation error is bounded by ε (:func:`kdfaces.window.adaptive_windows`); the
status line shows the frame's δ and its bound.

Keys: ``space`` play/stop, ``m`` cycle kinematic → KD → IKD, ``i`` solve IKD, ``a`` adaptive / fixed window,
``w`` kinematic wireframe overlay, ``Left``/``Right`` step one frame. Every slider and key calls a plain method of
:class:`ShotViewer`, so tests drive the viewer programmatically; ``kdfaces view SHOT --screenshot FILE --frame F``
renders one frame off-screen.

Authoring (paper §6.6, Fig. 11-12; issue 26), with an authoring session (``session=``, what ``kdfaces view`` opens on
the shot file: :class:`kdfaces.shots.authoring.AuthoringSession`; the viewer only maps mouse and keys to its
methods): ``p`` picks the vertex under the mouse (:meth:`ShotViewer.pick`) and adds a point target there at the
current frame, its handle on the vertex's KD position (drag it: :meth:`ShotViewer.drag_target`; or type an offset:
:meth:`ShotViewer.set_offset_mm`); ``g`` cycles the named group, ``h`` holds it where the kinematic pose has it,
``v`` stops it (velocity 0), ``o`` sets a pose constraint at this frame (``k``: sliders for its shape weights and head
angles, :meth:`ShotViewer.set_pose_weight`, :meth:`ShotViewer.set_pose_head_deg`); ``i`` solves in a worker thread (warm
start; progress in the status line, ``Escape`` cancels, the window stays responsive); ``u`` or ``ctrl+z`` undoes, ``y``
redoes, ``s`` saves into the shot file, ``Up``/``Down`` select a row of the constraint panel (and jump to its frame),
``n`` enables/disables it, ``Delete`` (or ``x``) deletes it. A bad edit shows the session's message in the status line
and changes nothing.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path

import numpy as np

from .. import defaults
from ..errors import KDInputError
from ..io.atomic import atomic_path
from ..kd import simulate_kd, window_steps
from .figures import SKIN, check_focus, framing, rig_focus
from .markers import constraint_markers

__all__ = ["MODES", "ShotViewer", "PlotterWindow", "with_width", "check_window_size", "check_view_arguments",
           "check_screenshot_path", "panel_row_text"]

MODES = ("kinematic", "kd", "ikd")
_MODE_NAMES = {"kinematic": "kinematic", "kd": "KD", "ikd": "IKD"}


def with_width(constraint, width_s: float):
    """``constraint`` with its correction bell widened or narrowed to width ``width_s`` [s].

    An asymmetric bell keeps its ease-out / ease-in ratio.
    """
    b = constraint.basis
    if hasattr(b, "ease_out_s"):
        nb = dataclasses.replace(b, width_s=float(width_s), ease_out_s=float(width_s) * b.ease_out_s / b.width_s)
    else:
        nb = dataclasses.replace(b, width_s=float(width_s))
    return dataclasses.replace(constraint, basis=nb)


def _initial_width(constraints) -> float:
    for c in constraints:
        return float(c.basis.width_s)
    return defaults.WIDTH_S


class PlotterWindow:
    """What the scrubbing viewers (:class:`ShotViewer`, :class:`kdfem.viewer.HatViewer`) share around their
    ``plotter`` (pyvista), status ``_text`` actor, ``frame``/``times``/``set_frame`` and ``playing`` flag: frame
    steps, playback, the status redraw, a screenshot, the window loop."""

    def set_frame(self, value) -> None:
        """Timeline slider: show frame ``round(value)``, clamped to the frames."""
        self.frame = int(np.clip(round(float(value)), 0, len(self.times) - 1))
        self.update()

    def set_mode(self, mode: str) -> None:
        """Display ``"kinematic"``, ``"kd"`` or ``"ikd"`` (IKD shows KD until a solve exists)."""
        if mode not in MODES:
            raise KDInputError(f"mode: expected one of {MODES}, got {mode!r}")
        self.mode = mode
        self.update()

    def cycle_mode(self) -> None:
        """Key ``m``: kinematic → KD → IKD → kinematic."""
        self.set_mode(MODES[(MODES.index(self.mode) + 1) % len(MODES)])

    def step_frame(self, delta: int = 1) -> None:
        """Move ``delta`` frames, wrapping around."""
        self.set_frame((self.frame + int(delta)) % len(self.times))

    def set_playing(self, playing) -> None:
        """Play button / ``space``: start or stop playback (the timer calls :meth:`tick`)."""
        self.playing = bool(playing)
        self.update_text()

    def toggle_play(self) -> None:
        """Start or stop playback."""
        self.set_playing(not self.playing)

    def tick(self, *_) -> None:
        """Timer: advance one frame while playing."""
        if self.playing:
            self.step_frame(1)

    def update_text(self) -> None:
        """Redraw the status text (``status()``)."""
        self._text.SetText(2, self.status())
        self.plotter.render()

    def finish(self, summary: dict, screenshot=None) -> dict:
        """The end of a ``view`` command: write ``screenshot`` (its path goes into ``summary``) or open the window
        until it is closed; the viewer is closed either way. Returns ``summary``."""
        try:
            if screenshot is not None:
                summary["screenshot"] = str(self.screenshot(screenshot))
            else:
                self.show()
        finally:
            self.close()
        return summary

    def screenshot(self, path) -> Path:
        """Write the current view to ``path`` (PNG), atomically."""
        from PIL import Image

        self.raise_callback_error()
        self.plotter.render()
        img = np.asarray(self.plotter.screenshot(return_img=True))[..., :3]
        with atomic_path(path, ".png") as tmp:
            Image.fromarray(img).save(tmp, format="PNG")
        return Path(path)

    def _add_controls(self, center, position, sliders, *, widgets: bool, off_screen: bool) -> None:
        """The shared scene furniture: the camera looking from ``position`` at ``center`` (3,) [m], the status
        text, and — with ``widgets`` — the frame slider, one slider per ``(key, callback, (lo, hi), value, title)``
        of ``sliders`` (stacked on the right) and the play button; in a window, keys ``space`` (play) and
        ``Right``/``Left`` (frame steps)."""
        pl = self.plotter
        self.callback_error = None
        pl.camera.focal_point = center
        pl.camera.position = position
        pl.camera.up = (0.0, 1.0, 0.0)
        pl.camera.view_angle = 30.0
        pl.reset_camera_clipping_range()
        self._text = pl.add_text("", position="upper_left", font_size=10, color="black")
        self._sliders = {}
        if widgets:
            style = dict(title_height=0.02, fmt="%.2f", interaction_event="end", style="modern")
            self._sliders["frame"] = pl.add_slider_widget(self._guarded(self.set_frame), (0, len(self.times) - 1),
                                                          value=0,
                                                          title="frame", pointa=(0.25, 0.08), pointb=(0.95, 0.08),
                                                          interaction_event="always", fmt="%.0f", style="modern",
                                                          title_height=0.02)
            for i, (key, cb, rng, val, title) in enumerate(sliders):
                y = 0.86 - 0.13 * i
                self._sliders[key] = pl.add_slider_widget(self._guarded(cb), rng, value=float(np.clip(val, *rng)),
                                                          title=title,
                                                          pointa=(0.76, y), pointb=(0.98, y), **style)
            self._play_button = pl.add_checkbox_button_widget(self.set_playing, value=False, position=(10, 10),
                                                              size=36, color_on="#1a9850", color_off="grey")
        if not off_screen:
            pl.add_key_event("space", self.toggle_play)
            pl.add_key_event("Right", lambda: self.step_frame(1))
            pl.add_key_event("Left", lambda: self.step_frame(-1))
        self.raise_callback_error()  # a slider calls its callback once as it is made

    def _guarded(self, fn):
        """``fn`` as a widget callback: pyvista prints an exception raised in a callback as a warning with its
        traceback and goes on, so the error is kept instead (:attr:`callback_error`), shown in the status text, and
        raised by :meth:`raise_callback_error` (at once while the viewer is built, before a screenshot)."""

        def call(*args):
            try:
                return fn(*args)
            except Exception as e:  # noqa: BLE001  (kept and raised by raise_callback_error)
                self.callback_error = e
                if getattr(self, "_text", None) is not None:
                    self._text.SetText(2, f"error: {e}")

        return call

    def raise_callback_error(self) -> None:
        """Raise (and clear) the error a widget callback kept, if any (see :meth:`_guarded`)."""
        e, self.callback_error = getattr(self, "callback_error", None), None
        if e is not None:
            raise e

    def _open_window(self, fps: float, title: str) -> None:
        """Open the interactive window (blocks until it is closed), calling ``tick`` at ``fps`` frames per second."""
        self.plotter.add_timer_event(max_steps=2**31 - 1, duration=max(1, int(1000.0 / fps)), callback=self.tick)
        self.plotter.show(title=title)


class ShotViewer(PlotterWindow):
    """A pyvista window over one shot: timeline, play/stop, parameter sliders, display toggle, IKD solve.

    Args:
        shot: a :class:`~kdfaces.shots.shotfile.Shot`.
        off_screen: render without a window (screenshots, tests).
        size: window (width, height) in pixels.
        window_s: KD window δ [s], "auto" or "adaptive"; default the shot's ``window_s``.
        widgets: draw the sliders and the play button (they also appear in screenshots).
        threads: CPU threads per KD state (the face's vertices are split between them).
        focus: vertex indices (R,) the initial camera frames and pose-constraint markers are kept to; None: the
            rig's moving region (:func:`~kdfaces.viz.figures.rig_focus`, so a full-body avatar opens on its face).

    Attributes:
        frame: the displayed frame index into ``times``.
        times: frame times [s], shape (F,).
        mode: one of :data:`MODES`.
        points: the displayed vertex positions [m], shape (N, 3).
        last_ms: wall time of the last KD state computation [ms] (0 in kinematic mode).
        adaptive: whether each frame has its own window (:meth:`window_at`); ``window_s`` is then the automatic
            window, which the IKD solve keeps.
        ikd: the last :class:`~kdfaces.ikd.solver.IKDResult`, or None; ``ikd_stale`` is True when a parameter
            changed after it was solved (it is still shown, against the new dynamics, until solved again).
    """

    def __init__(self, shot, *, off_screen: bool = False, size=(960, 720), window_s: float | str | None = None,
                 widgets: bool = True, device: str = "cpu", threads: int = defaults.THREADS, focus=None,
                 session=None):
        self.shot = shot
        self.session = session
        self.selected = None  # the selected row of the constraint panel (index into the session's rows), or None
        self.group = _GROUPS[0]  # the named group ``h``/``v`` act on (``g`` cycles)
        self._pose_shapes = None  # the pose sliders' shapes (computed on first use)
        self._pose_sliders = {}  # name → slider widget of the pose editor (key ``k``, in a window with widgets)
        self.message = ""  # the last authoring message (a bad edit's, a save's), shown in the status line
        self._solve_thread = None
        self._cancel = threading.Event()
        self._solve_progress = ""
        self._solve_outcome = None
        self.focus = rig_focus(shot.rig) if focus is None else check_focus(focus, shot.rig.num_vertices)
        self.threads = int(threads)
        self.trajectory = shot.trajectory
        self.times = np.asarray(shot.animation.frame_times, dtype=np.float64)
        self.step_s = shot.step_s
        self.device = device
        base = shot.settle_time()
        self._settle_map = np.broadcast_to(np.asarray(base, dtype=np.float64), (shot.rig.num_vertices,))
        self.settle_time_s = float(self._settle_map.max())
        self.damping_ratio = float(shot.dynamics["damping_ratio"])
        self._constraints = shot.constraints()
        self.width_s = _initial_width(self._constraints)
        self._width_set = False  # until the slider moves, every constraint keeps the shot's own width
        self._rebuild_system()
        w = shot.dynamics["window_s"] if window_s is None else window_s
        self.adaptive = w == "adaptive"
        self._windows = {}  # trajectory version → the frames' adaptive windows (AdaptiveWindows)
        if w in ("auto", "adaptive"):
            from ..window import automatic_window

            w = automatic_window(self.system, self.trajectory, step_s=self.step_s).window_s
        if isinstance(w, str):
            raise KDInputError(f"window: expected seconds, 'auto' or 'adaptive', got {w!r}")
        self.window_s = float(max(float(w), self.step_s))
        if session is not None:
            self.window_s = float(session.window_s)  # the window the session solves with
        self.mode = "kd"
        self.frame = 0
        self.playing = False
        self.last_ms = 0.0
        self.ikd = None
        self.ikd_stale = False
        self.ikd_message = "IKD: not solved (press i)" if self._constraints else "IKD: the shot has no constraints"
        self._build_scene(off_screen, size, widgets)
        self.update()

    # --- dynamics ----------------------------------------------------------------------------------------------
    def _rebuild_system(self) -> None:
        from ..dynamics import FaceSystem

        scale = self.settle_time_s / float(self._settle_map.max())
        model = self.shot.model(settle_time_s=self._settle_map * scale, damping_ratio=self.damping_ratio)
        old = getattr(self, "system", None)
        if old is not None:
            old.close()  # its worker threads
        self.system = FaceSystem(model, device=self.device, threads=self.threads)
        self._windows = {}

    def constraints(self) -> list:
        """The shot's constraints (with a session: its enabled rows' constraints); once the width slider moved, all
        with the viewer's correction width σ."""
        if self.session is not None:
            try:
                return list(self.session.constraints())
            except KDInputError:  # a row that does not build says so in its status
                return []
        if not self._width_set:
            return list(self._constraints)
        return [with_width(c, self.width_s) for c in self._constraints]

    def state(self, frame: int | None = None, mode: str | None = None) -> np.ndarray:
        """Vertex positions (N, 3) [m] of ``frame`` in ``mode`` (default the displayed ones); sets ``last_ms``."""
        k = self.frame if frame is None else frame
        mode = self.mode if mode is None else mode
        t = self.times[k]
        if mode == "kinematic":
            self.last_ms = 0.0
            return self.trajectory.positions([t])[0]
        traj = self.ikd.trajectory if (mode == "ikd" and self.ikd is not None) else self.trajectory
        window = self.window_at(k, mode)
        t0 = time.perf_counter()
        x = simulate_kd(self.system, traj, [t], [window], step_s=self.step_s)[0]
        self.last_ms = 1e3 * (time.perf_counter() - t0)
        return x

    def adaptive_windows(self, mode: str | None = None):
        """The frames' adaptive windows (:class:`~kdfaces.window.AdaptiveWindows`) on the trajectory ``mode``
        shows (the IKD-corrected one in ``"ikd"`` mode once solved), computed once per trajectory and dynamics."""
        from ..window import adaptive_windows

        mode = self.mode if mode is None else mode
        traj = self.ikd.trajectory if (mode == "ikd" and self.ikd is not None) else self.trajectory
        key = getattr(traj, "version", id(traj))
        if key not in self._windows:
            self._windows[key] = adaptive_windows(self.system, traj, self.times, step_s=self.step_s)
        return self._windows[key]

    def window_at(self, frame: int | None = None, mode: str | None = None) -> float:
        """The KD window δ [s] of ``frame`` (default the displayed one): the fixed window, or the frame's adaptive
        window (a constraint's own frames on the IKD trajectory keep the solve's window, so they hold exactly)."""
        k = self.frame if frame is None else int(frame)
        mode = self.mode if mode is None else mode
        if not self.adaptive:
            return self.window_s
        if mode == "ikd" and self.ikd is not None:
            t = self.times[k]
            for c in self.ikd.constraints:
                if abs(c.time_s - t) <= 1e-9 or (c.needs_previous and abs(c.time_s - self.step_s - t) <= 1e-9):
                    return self.window_s
        return float(self.adaptive_windows(mode).window_s[k])

    # --- callbacks (sliders, keys, buttons) --------------------------------------------------------------------
    def set_settle_time(self, value) -> None:
        """Settle-time slider [s]: the loosest vertex's settle time; a per-vertex map is scaled with it."""
        v = float(value)
        if not v > 0:
            raise KDInputError(f"settle time: expected positive seconds, got {value}")
        self.settle_time_s = v
        self._parameters_changed(rebuild=True)

    def set_damping_ratio(self, value) -> None:
        """Damping-ratio slider (ζ, dimensionless)."""
        v = float(value)
        if not v > 0:
            raise KDInputError(f"damping ratio: expected a positive number, got {value}")
        self.damping_ratio = v
        self._parameters_changed(rebuild=True)

    def set_window(self, value) -> None:
        """Window slider: KD window δ [s] (rounded up to whole steps by ``simulate_kd``); a fixed window for every
        frame (adaptive windows off)."""
        window_steps(float(value), self.step_s)
        if self.adaptive and float(value) == self.window_s:
            return  # the slider reporting its own starting value (pyvista calls back on creation)
        self.window_s = float(value)
        self.adaptive = False
        self._parameters_changed(rebuild=False)

    def set_adaptive(self, on) -> None:
        """Key ``a``: adaptive per-frame windows on or off (off: the fixed window ``window_s``)."""
        self.adaptive = bool(on)
        self.update()

    def set_width(self, value) -> None:
        """Correction-width slider: σ [s] of every constraint's bell (takes effect at the next IKD solve).

        Until it is first set, each constraint keeps the width of its shot file (the slider starts at the first's).
        """
        v = float(value)
        if not v > 0:
            raise KDInputError(f"correction width: expected positive seconds, got {value}")
        if self.session is not None:  # the selected row's bell (every row at its time shares it)
            if self.selected is not None and abs(self.session.rows[self.selected].width_s - v) > 1e-12:
                self.set_field("width_s", v)
            return
        self.width_s = v
        self._width_set = True
        self._parameters_changed(rebuild=False)

    def _parameters_changed(self, *, rebuild: bool) -> None:
        if rebuild:
            self._rebuild_system()
        if self.session is not None and (rebuild or self.session.window_s != self.window_s):
            self._session_dynamics()
        if self.ikd is not None:
            self.ikd_stale = True
        self.update()

    def _session_dynamics(self) -> None:
        """The session solves with the viewer's dynamics and window: a system of its own (a solve runs beside the
        display's states) on the same model."""
        from ..dynamics import FaceSystem

        if self.session.busy:
            self.message = "dynamics changed during a solve: solve again once it ends"
            return
        old = self.session.system
        self.session.set_system(FaceSystem(self.system.model, device=self.device, threads=self.threads),
                                window_s=self.window_s)
        if old is not self.system and hasattr(old, "close"):
            old.close()
        self.message = str(self.session.status)

    def solve_ikd(self):
        """Key ``i``: solve IKD for the shot's constraints with the current parameters; show the IKD state.

        With a session, the session solves (warm start) and this waits for it: :meth:`solve_async` is what the key
        calls in a window."""
        from ..ikd.solver import solve_ikd

        if self.session is not None:
            self.solve_async()
            self.wait_solve()
            return self.ikd
        if not self._constraints:
            self.ikd_message = "IKD: the shot has no constraints"
            self.update()
            return None
        self.ikd = solve_ikd(self.system, self.trajectory, self.constraints(), window_s=self.window_s,
                             step_s=self.step_s, **self.shot.solver_options())
        self.ikd_stale = False
        r = self.ikd
        self.ikd_message = (f"IKD: {r.reason}, {r.iterations} sweeps, {r.wall_s:.2f} s, "
                            f"{_error_text(r)}")
        self.mode = "ikd"
        self.update()
        return r

    def show_kinematic(self, visible) -> None:
        """Key ``w``: the kinematic pose as a wireframe over the displayed state."""
        self._wire_actor.SetVisibility(bool(visible))
        self.update()

    # --- scene -------------------------------------------------------------------------------------------------
    def _build_scene(self, off_screen: bool, size, widgets: bool) -> None:
        import pyvista as pv

        rig = self.shot.rig
        f = np.asarray(rig.faces, dtype=np.int64)
        cells = np.hstack([np.full((len(f), 1), 3), f]).ravel()
        self.mesh = pv.PolyData(rig.neutral.astype(np.float64).copy(), cells)
        self.wire = pv.PolyData(rig.neutral.astype(np.float64).copy(), cells)
        self.plotter = pl = pv.Plotter(off_screen=off_screen, window_size=tuple(size), lighting="three lights")
        pl.set_background("white")
        self._mesh_actor = pl.add_mesh(self.mesh, color=SKIN, smooth_shading=True, specular=0.2)
        self._handle_sphere = pv.Sphere(radius=_HANDLE_RADIUS_M, center=(0.0, 0.0, 0.0))
        self._handle_rest = np.asarray(self._handle_sphere.points).copy()
        self._handle_actor = pl.add_mesh(self._handle_sphere, color=_HANDLE_COLOR, reset_camera=False)
        self._handle_actor.SetVisibility(False)
        self._handle_widget = None
        self._measured_actor = None
        self._off_screen = off_screen
        self._panel = pl.add_text("", position=(0.01, 0.2), viewport=True, font_size=8, color="black",
                                  font="courier")
        self._wire_actor = pl.add_mesh(self.wire, style="wireframe", color="#3b6fb6", opacity=0.25, line_width=1)
        self._wire_actor.SetVisibility(False)
        self._marker_actors = []
        center, position = framing(rig.neutral, self.focus, (0.35, 0.15, 1.0), distance=3.0)
        sliders = [("settle", self.set_settle_time, (0.05, 1.5), self.settle_time_s, "settle time [s]"),
                   ("zeta", self.set_damping_ratio, (0.05, 2.0), self.damping_ratio, "damping ratio"),
                   ("window", self.set_window, (self.step_s, max(2.0, self.window_s)), self.window_s, "window [s]"),
                   ("sigma", self.set_width, (0.05, 1.0), self.width_s, "correction width [s]")]
        self._add_controls(center, position, sliders, widgets=widgets, off_screen=off_screen)
        if not off_screen:
            pl.add_key_event("m", self.cycle_mode)
            pl.add_key_event("i", self._guarded(self.solve_async) if self.session is not None else self.solve_ikd)
            pl.add_key_event("a", lambda: self.set_adaptive(not self.adaptive))
            pl.add_key_event("w", lambda: self.show_kinematic(not self._wire_actor.GetVisibility()))
            if self.session is not None:
                self._authoring_keys(pl)

    def _constraint_markers(self, x: np.ndarray) -> list:
        """Markers of the constraints at the displayed frame (within half a step of its time); a pose constraint's
        on the focus vertices its target moves away from the kinematic pose at its time."""
        t = self.times[self.frame]
        out = []
        for c in self.constraints():
            if abs(c.time_s - t) <= 0.5 * self.step_s + 1e-9:
                xp = self.state(max(self.frame - 1, 0)) if c.kind == "velocity" else None
                rest = self.trajectory.positions([c.time_s])[0] if c.kind == "pose" else None
                out += constraint_markers(c, x, xp, step_s=self.step_s, focus=self.focus, moved_from=rest)
        return out

    def update(self) -> None:
        """Recompute the displayed state of the current frame and mode, and redraw."""
        x = self.state()
        ms = self.last_ms
        self.points = x
        self.mesh.points = x
        if self._wire_actor.GetVisibility():
            self.wire.points = self.trajectory.positions([self.times[self.frame]])[0]
        for a in self._marker_actors:
            self.plotter.remove_actor(a)
        self._marker_actors = [self.plotter.add_points(m.points, color=m.color, point_size=m.size_px,
                                                       render_points_as_spheres=True, reset_camera=False)
                               for m in self._constraint_markers(x)]
        self.last_ms = ms
        slider = self._sliders.get("frame")
        if slider is not None:
            slider.GetRepresentation().SetValue(self.frame)
        self._draw_handle()
        self._sync_pose_sliders()
        self._panel.SetInput(self.panel_text() or " ")
        self.update_text()

    def status(self) -> str:
        """The on-screen text: frame, time, mode, ms per KD state, window, IKD status."""
        n = len(self.times)
        shown = _MODE_NAMES[self.mode]
        if self.mode == "ikd" and self.ikd is None:
            shown = "IKD (not solved: showing KD)"
        window = self.window_at()
        steps = 0 if window == 0 else window_steps(window, self.step_s)
        how = ""
        if self.adaptive and window != self.window_s:
            aw = self.adaptive_windows()
            how = (f"  adaptive: bound {1e3 * aw.bound_m[self.frame]:.3f} mm <= eps {1e3 * aw.epsilon_m:.3f} mm"
                   f" (automatic {self.window_s:.2f} s)")
        elif self.adaptive:
            how = "  adaptive: the IKD solve's window at a constraint"
        lines = [f"{self.shot.name}   frame {self.frame}/{n - 1}   t = {self.times[self.frame]:.2f} s   {shown}"
                 + ("   [playing]" if self.playing else ""),
                 f"KD state: {self.last_ms:.1f} ms   window {window:.2f} s "
                 f"({steps} steps of {1e3 * self.step_s:.0f} ms){how}",
                 self.ikd_message + ("  [stale: press i]" if self.ikd_stale else "")]
        if self.session is not None:
            busy = self.solving
            lines.append(f"solving... {self._solve_progress} (Esc cancels)" if busy else
                         f"group: {self.group}   p point  h hold  v stop  o pose  k sliders  i solve  u undo  y redo"
                         "  s save")
            if self.message:
                lines.append(self.message)
        return "\n".join(lines)

    # --- output ------------------------------------------------------------------------------------------------
    def show(self) -> None:
        """Open the interactive window (blocks until it is closed); playback runs at the shot's frame rate."""
        self._open_window(float(getattr(self.shot.animation, "fps", 25.0)), f"kdfaces view: {self.shot.name}")

    def close(self) -> None:
        """Close the window and free the plotter (and the KD system's worker threads); a running solve is
        cancelled and waited for."""
        if self._solve_thread is not None:
            self._cancel.set()
            self._solve_thread.join()
        self.plotter.close()
        self.system.close()

    def tick(self, *_) -> None:
        """Timer: collect a finished solve (:meth:`poll_solve`), show its progress, advance one frame while
        playing."""
        if self.session is not None and (self._solve_thread is not None or self._solve_outcome is not None):
            if not self.poll_solve():
                self.update_text()
        super().tick()

    # --- authoring (a session's edits, at the current frame) ---------------------------------------------------
    @property
    def time_s(self) -> float:
        """The displayed frame's time [s]."""
        return float(self.times[self.frame])

    def _session(self):
        if self.session is None:
            raise KDInputError("authoring: this viewer has no authoring session (open it with kdfaces view SHOT)")
        return self.session

    def _edit(self, name: str, *args, select=None, **kwargs):
        """Call the session's edit ``name``; its message (a bad edit's, which changed nothing) goes to the status
        line, never a traceback. ``select``: the row to select after a successful edit ("new": the last row)."""
        s = self._session()
        try:
            out = getattr(s, name)(*args, **kwargs)
        except KDInputError as e:  # the session records its own messages; an error raised anyway is shown too
            self.message = f"{name}: {e}"
            self.update_text()
            return None
        self.message = _session_message(s, out)
        rows = len(s.rows)
        if select == "new" and out and getattr(out, "row", None) is not None:
            self.selected = int(out.row)
        elif self.selected is not None and self.selected >= rows:
            self.selected = rows - 1 if rows else None
        self._sync_result()
        self.update()
        return out

    def _sync_result(self) -> None:
        """Show the session's solution when it is the current rows' (an undo back to a solved set brings its
        solution back); else keep showing the last one, marked stale."""
        r = getattr(self.session, "result", None)
        if r is not None and not self.session.stale:
            if r is not self.ikd:
                self.ikd = r
                self.ikd_message = f"IKD: {r.reason}, {r.iterations} sweeps, {r.wall_s:.2f} s, {_error_text(r)}"
            self.ikd_stale = False
        elif self.ikd is not None:
            self.ikd_stale = True

    def vertex_at(self, screen_xy) -> int | None:
        """The face vertex under the display position ``screen_xy`` (x, y) [px, VTK's origin bottom left, as the
        interactor reports the mouse]: the nearest corner of the visible triangle hit there (VTK cell picking, so
        hidden vertices are never picked), or None when the face is not under it."""
        import vtk

        x, y = (float(v) for v in screen_xy)
        picker = vtk.vtkCellPicker()
        picker.SetTolerance(1e-4)
        picker.PickFromListOn()
        picker.AddPickList(self._mesh_actor)
        self.plotter.render()
        picker.Pick(x, y, 0.0, self.plotter.renderer)
        cell = picker.GetCellId()
        if cell < 0:
            return None
        tri = np.asarray(self.shot.rig.faces[cell], dtype=np.int64)
        hit = np.asarray(picker.GetPickPosition(), dtype=np.float64)
        return int(tri[np.argmin(np.linalg.norm(self.points[tri] - hit, axis=1))])

    def screen_position(self, vertex_id: int) -> tuple[float, float]:
        """The display position (x, y) [px, origin bottom left] of a vertex's displayed position (the inverse of
        :meth:`vertex_at` for a visible vertex)."""
        r = self.plotter.renderer
        r.SetWorldPoint(*self.points[int(vertex_id)], 1.0)
        r.WorldToDisplay()
        x, y, _ = r.GetDisplayPoint()
        return float(x), float(y)

    def pick(self, screen_xy) -> int | None:
        """Key ``p``: add a point target on the face vertex under ``screen_xy`` (:meth:`vertex_at`,
        :meth:`pick_vertex`). Returns the vertex id, or None (and a message) when the face is not under it."""
        v = self.vertex_at(screen_xy)
        if v is None:
            x, y = (float(c) for c in screen_xy)
            self.message = f"pick: no face vertex under ({x:.0f}, {y:.0f}) px"
            self.update_text()
            return None
        self.pick_vertex(v)
        return v

    def pick_vertex(self, vertex_id: int):
        """A point target (end effector, default falloff) on vertex ``vertex_id`` at the current frame; its handle
        appears at the vertex's KD position. Key ``p`` calls it through :meth:`pick`."""
        v = int(vertex_id)
        if not 0 <= v < self.shot.rig.num_vertices:
            self.message = f"pick: vertex {v} is not a vertex of the rig (0..{self.shot.rig.num_vertices - 1})"
            self.update_text()
            return None
        return self._edit("add_point", self.time_s, v, select="new")

    def set_group(self, name: str) -> None:
        """The named group (:data:`kdfaces.rig.groups.GROUP_SHAPES`) that ``h``, ``v`` act on."""
        if name not in _GROUPS:
            raise KDInputError(f"group: expected one of {', '.join(_GROUPS)}, got {name!r}")
        self.group = name
        self.update_text()

    def next_group(self) -> None:
        """Key ``g``: the next named group."""
        self.set_group(_GROUPS[(_GROUPS.index(self.group) + 1) % len(_GROUPS)])

    def hold_group(self):
        """Key ``h``: hold the named group where the kinematic pose has it at this frame (a subset constraint)."""
        return self._edit("add_group", self.time_s, self.group, select="new")

    def stop_group(self):
        """Key ``v``: stop the named group at this frame (a velocity constraint, target 0)."""
        return self._edit("add_velocity", self.time_s, self.group, select="new")

    def add_pose(self, weights: dict | None = None, head_deg=None):
        """Key ``o``: a pose constraint at this frame: shape ``weights`` (name → weight) and ``head_deg`` (3,)
        [deg] (None: the kinematic pose's)."""
        return self._edit("add_pose", self.time_s, weights=weights, head_deg=head_deg, select="new")

    # --- the pose editor: sliders for shape weights and head angles at this frame (a pose constraint) ----------
    @property
    def pose_shapes(self) -> list[str]:
        """The shapes the pose editor sets: the rig's shapes the shot animates (a weight that changes over its
        frames), at most :data:`POSE_SLIDER_SHAPES`, the largest weight range (max − min over the frames) first."""
        if self._pose_shapes is None:
            w = self.trajectory.weights(self.times, 0)[0]  # (F, K)
            span = w.max(axis=0) - w.min(axis=0)
            order = [int(k) for k in np.argsort(-span, kind="stable") if span[k] > 0][:POSE_SLIDER_SHAPES]
            self._pose_shapes = [self.shot.rig.shape_names[k] for k in order]
        return list(self._pose_shapes)

    def pose_row(self) -> int | None:
        """The session's enabled pose constraint at the displayed frame (its row index), or None."""
        for i, r in enumerate(self._session().rows):
            if r.enabled and r.kind == "pose" and abs(r.time_s - self.time_s) <= 0.5 * self.step_s:
                return i
        return None

    def pose_values(self) -> tuple[dict, np.ndarray]:
        """What the pose sliders show at this frame: ({shape: weight} of :attr:`pose_shapes`, head (yaw, pitch,
        roll) [deg] added to the animation's): the pose constraint's target here, else the animation's weights and
        no head offset."""
        rig = self.shot.rig
        w = self.trajectory.weights([self.time_s], 0)[0][0].copy()
        head = np.zeros(3)
        i = self.pose_row()
        target = self.session.rows[i].target if i is not None else None
        if isinstance(target, dict):
            for name, v in (target.get("weights") or {}).items():
                w[rig.shape_indices([name])[0]] = float(v)
            if target.get("head_deg") is not None:
                head = np.asarray(target["head_deg"], dtype=np.float64)
        return {n: float(w[rig.shape_indices([n])[0]]) for n in self.pose_shapes}, head

    def _pose_edit(self, what: str, key: str, value):
        """Set ``key`` of the pose target at this frame: the pose row's target updated (undoable), or a new pose
        constraint when the frame has none."""
        i = self.pose_row()
        if i is None:
            return self._edit("add_pose", self.time_s, select="new", **{key: value})
        target = self.session.rows[i].target
        target = dict(target) if isinstance(target, dict) else {}
        if target.get("obj") is not None:
            self.message = f"refused: {what}: row {i}'s pose is an OBJ file ({target['obj']}); nothing changed"
            self.update_text()
            return None
        if key == "weights":
            rig = self.shot.rig
            k = rig.shape_indices(list(value))[0]
            old = {n: v for n, v in (target.get("weights") or {}).items() if rig.shape_indices([n])[0] != k}
            value = {**old, **value}
        target[key] = value
        self.selected = i
        return self._edit("set_field", i, "target", target)

    def set_pose_weight(self, name: str, value):
        """Pose slider: shape ``name``'s weight at this frame is ``value`` (a pose constraint here, made or
        updated through the session, undoable). A bad name or value gives a message and changes nothing."""
        try:
            self.shot.rig.shape_indices([name], where="pose slider")
            v = float(value)
        except (KDInputError, TypeError, ValueError) as e:
            self.message = f"refused: set_pose_weight: {e}; nothing changed"
            self.update_text()
            return None
        return self._pose_edit(f"set_pose_weight({name!r})", "weights", {str(name): v})

    def set_pose_head_deg(self, yaw_deg: float, pitch_deg: float, roll_deg: float):
        """Head sliders: the head turned by (yaw, pitch, roll) [deg] from the animation's at this frame (a pose
        constraint here, made or updated through the session, undoable)."""
        try:
            head = [float(v) for v in (yaw_deg, pitch_deg, roll_deg)]
        except (TypeError, ValueError) as e:
            self.message = f"refused: set_pose_head_deg: {e}; nothing changed"
            self.update_text()
            return None
        return self._pose_edit("set_pose_head_deg", "head_deg", head)

    def toggle_pose_sliders(self) -> bool:
        """Key ``k``: show or hide the pose sliders (one per :attr:`pose_shapes` and yaw, pitch, roll) in place of
        the dynamics sliders; each release calls :meth:`set_pose_weight` / :meth:`set_pose_head_deg`. Only in a
        window with widgets (off-screen, call the methods). Returns whether they are shown."""
        self._session()
        if self._off_screen or "frame" not in self._sliders:
            self.message = "pose sliders: only in a window with widgets (call set_pose_weight, set_pose_head_deg)"
            self.update_text()
            return False
        return self._show_pose_sliders(not any(w.GetEnabled() for w in self._pose_sliders.values()))

    def _show_pose_sliders(self, on: bool) -> bool:
        if on and not self._pose_sliders:
            style = dict(title_height=0.015, interaction_event="end", style="modern")
            weights, head = self.pose_values()
            rows = [(n, (min(0.0, v), max(1.0, v)), v, "%.2f", n) for n, v in weights.items()]
            rows += [(f"head_{a}", (-30.0, 30.0), float(head[j]), "%.0f", f"head {a} [deg]")
                     for j, a in enumerate(("yaw", "pitch", "roll"))]
            for i, (key, rng, val, fmt, title) in enumerate(rows):
                y = 0.90 - 0.07 * i
                self._pose_sliders[key] = self.plotter.add_slider_widget(
                    self._guarded(lambda v, key=key: self._pose_slider(key, v)), rng, value=float(np.clip(val, *rng)),
                    title=title, pointa=(0.76, y), pointb=(0.98, y), fmt=fmt, **style)
                rep = self._pose_sliders[key].GetRepresentation()
                rep.SetLabelHeight(0.015)  # eleven sliders in the column: smaller value labels, thinner tubes
                rep.SetTubeWidth(0.004)
                rep.SetSliderWidth(0.015)
            self.raise_callback_error()
        for w in self._pose_sliders.values():
            w.On() if on else w.Off()
        for key, w in self._sliders.items():
            if key != "frame":
                w.Off() if on else w.On()
        self.update()
        return on

    def _pose_slider(self, key: str, value) -> None:
        """A pose slider's release: an edit when its value differs from the pose shown (a slider calls back with
        its own value as it is made)."""
        weights, head = self.pose_values()
        if key.startswith("head_"):
            new = head.copy()
            new[("head_yaw", "head_pitch", "head_roll").index(key)] = float(value)
            if np.abs(new - head).max() > 1e-9:
                self.set_pose_head_deg(*new)
        elif abs(weights[key] - float(value)) > 1e-9:
            self.set_pose_weight(key, value)

    def _sync_pose_sliders(self) -> None:
        """The pose sliders show the pose at the displayed frame (setting a slider's value does not call it)."""
        if not self._pose_sliders or self.session is None:
            return
        weights, head = self.pose_values()
        values = {**weights, "head_yaw": head[0], "head_pitch": head[1], "head_roll": head[2]}
        for key, w in self._pose_sliders.items():
            w.GetRepresentation().SetValue(float(values[key]))

    def drag_target(self, point_m, row: int | None = None):
        """Dragging the handle: the point target of ``row`` (default the selected one) to ``point_m`` (3,) [m]."""
        return self._edit("drag", self._row(row), np.asarray(point_m, dtype=np.float64))

    def set_offset_mm(self, row, dx_mm: float, dy_mm: float, dz_mm: float):
        """Typed offset: ``row``'s target (None: the selected row) at its kinematic position plus (dx, dy, dz)
        [mm]."""
        return self._edit("set_offset_mm", self._row(row), (dx_mm, dy_mm, dz_mm))

    def set_field(self, name: str, value, row: int | None = None):
        """Edit field ``name`` (time_s, width_s, curve, falloff_m, enabled, label, target) of ``row`` (default the
        selected one)."""
        return self._edit("set_field", self._row(row), name, value)

    def toggle_enabled(self, row: int | None = None):
        """Key ``n``: enable or disable ``row`` (default the selected one)."""
        r = self._row(row)
        if r is None:
            return None
        if not 0 <= r < len(self.session.rows):
            return self._edit("set_enabled", r, True)  # the session refuses it with its message
        return self._edit("set_enabled", r, not self.session.rows[r].enabled)

    def delete(self, row: int | None = None):
        """Key ``Delete`` / ``x``: delete ``row`` (default the selected one)."""
        return self._edit("delete", self._row(row))

    def undo(self):
        """Key ``u`` / ``ctrl+z``: undo the last edit."""
        return self._edit("undo")

    def redo(self):
        """Key ``y``: redo the last undone edit."""
        return self._edit("redo")

    def save(self, path=None):
        """Key ``s``: write the constraints back into the shot file (or ``path``); the session's message (written,
        or why not) goes to the status line."""
        return self._edit("save", path) if path is not None else self._edit("save")

    def select_row(self, row) -> None:
        """Select a row of the constraint panel and jump to its frame (the frame nearest its time)."""
        rows = self._session().rows
        if not rows:
            self.selected = None
            self.update()
            return
        self.selected = int(np.clip(int(row), 0, len(rows) - 1))
        t = float(_get(rows[self.selected], "time_s"))
        self.frame = int(np.argmin(np.abs(self.times - t)))
        self.update()

    def step_row(self, delta: int) -> None:
        """Keys ``Down``/``Up``: select the next/previous row."""
        rows = self._session().rows
        if rows:
            self.select_row(0 if self.selected is None else (self.selected + int(delta)) % len(rows))

    def _row(self, row):
        r = self.selected if row is None else int(row)
        return -1 if r is None else r  # the session refuses a missing row with its message

    # --- solving in a worker thread ----------------------------------------------------------------------------
    @property
    def solving(self) -> bool:
        """Whether a solve is running in the worker thread."""
        return self._solve_thread is not None and self._solve_thread.is_alive()

    def solve_async(self) -> bool:
        """Key ``i``: start the session's solve (warm start) in a worker thread; the window stays responsive, the
        status line shows its progress, ``Escape`` cancels (:meth:`cancel_solve`) and the timer collects the result
        (:meth:`poll_solve`). Returns False (with a message) when one is already running."""
        s = self._session()
        if self.solving:
            self.message = "solve: already running (Esc cancels)"
            self.update_text()
            return False
        self._cancel.clear()
        self._solve_progress, self._solve_outcome = "", None

        def progress(*args):
            self._solve_progress = _progress_text(args)

        def work():
            try:
                self._solve_outcome = ("done", s.solve(progress=progress, cancel=self._cancel.is_set))
            except Exception as e:  # noqa: BLE001  (shown in the status line by poll_solve)
                self._solve_outcome = ("error", e)

        self._solve_thread = threading.Thread(target=work, name="kdfaces-view-solve", daemon=True)
        self._solve_thread.start()
        self.update_text()
        return True

    def cancel_solve(self) -> None:
        """Key ``Escape``: ask a running solve to stop after its current sweep."""
        if self.solving:
            self._cancel.set()
            self.message = "solve: cancelling..."
            self.update_text()

    def wait_solve(self, timeout_s: float | None = None) -> bool:
        """Wait for the running solve (at most ``timeout_s`` [s]) and collect it; True when it finished."""
        if self._solve_thread is not None:
            self._solve_thread.join(timeout_s)
        return self.poll_solve()

    def poll_solve(self) -> bool:
        """Collect a finished solve: show the IKD state of the session's result and its rows' errors; a failed or
        cancelled one only says so. Returns True when a solve was collected."""
        if self._solve_thread is None or self._solve_thread.is_alive() or self._solve_outcome is None:
            return False
        how, out = self._solve_outcome
        self._solve_thread, self._solve_outcome = None, None
        if how == "error":
            self.message = f"solve: {out}"
        else:
            self.message = str(self.session.status)
            self._sync_result()
            if out is not None and self.ikd is out:
                self.mode = "ikd"
        self.update()
        return True

    # --- the constraint panel and the handle -------------------------------------------------------------------
    def panel_text(self) -> str:
        """The constraint list: one row per session row (:func:`panel_row_text`), ``>`` at the selected one."""
        if self.session is None:
            return ""
        rows = self.session.rows
        head = f"  {'time':>7s}  {'kind':12s}  {'label':14s} {'before':>7s} {'after':>7s}  grad  on  (mm, mm/s)"
        lines = [head] + [(">" if i == self.selected else " ") + " " + panel_row_text(r) for i, r in enumerate(rows)]
        return "\n".join(lines) if rows else head + "\n  (no constraints: p, h, v or o adds one)"

    def handle_point(self) -> np.ndarray | None:
        """Where the selected point target's handle is drawn (3,) [m]: its target, when the row is a point
        constraint at the displayed frame; else None."""
        if self.session is None or self.selected is None or self.selected >= len(self.session.rows):
            return None
        row = self.session.rows[self.selected]
        if abs(row.time_s - self.time_s) > 0.5 * self.step_s:
            return None
        return self.session.handle(self.selected)

    def _draw_handle(self) -> None:
        p = self.handle_point()
        self._handle_actor.SetVisibility(p is not None)
        if self._measured_actor is not None:
            self.plotter.remove_actor(self._measured_actor)
            self._measured_actor = None
        if p is not None:
            self._handle_sphere.points = self._handle_rest + p
            which = "ikd" if (self.mode == "ikd" and not self.ikd_stale) else "kd"
            q = self.session.measured(self.selected, which) if self.mode != "kinematic" else None
            if q is not None:  # where the displayed KD state has the constrained point
                self._measured_actor = self.plotter.add_points(np.asarray(q)[None], color="#f28e2b",
                                                               point_size=10, render_points_as_spheres=True,
                                                               reset_camera=False)
        if self._off_screen:
            return
        if p is not None:
            if self._handle_widget is None:
                self._handle_widget = self.plotter.add_sphere_widget(self._guarded(self._on_drag), center=p,
                                                                     radius=1.3 * _HANDLE_RADIUS_M,
                                                                     color=_HANDLE_COLOR)
            else:
                self._handle_widget.SetCenter(*p)
            self._handle_widget.On()
        elif self._handle_widget is not None:
            self._handle_widget.Off()

    def _on_drag(self, center) -> None:
        p = self.handle_point()
        if p is None or not np.allclose(center, p, atol=1e-9):
            self.drag_target(center)

    def _authoring_keys(self, pl) -> None:
        """The authoring keys of an interactive window (each calls one method above)."""
        g = self._guarded
        pl.add_key_event("p", g(lambda: self.pick(pl.iren.get_event_position())))
        pl.add_key_event("g", g(self.next_group))
        pl.add_key_event("h", g(self.hold_group))
        pl.add_key_event("v", g(self.stop_group))
        pl.add_key_event("o", g(self.add_pose))
        pl.add_key_event("u", g(self.undo))
        pl.add_key_event("z", g(lambda: self.undo() if pl.iren.interactor.GetControlKey() else None))
        pl.add_key_event("y", g(self.redo))
        pl.add_key_event("s", g(self.save))
        pl.add_key_event("n", g(self.toggle_enabled))
        pl.add_key_event("Delete", g(self.delete))
        pl.add_key_event("x", g(self.delete))
        pl.add_key_event("Up", g(lambda: self.step_row(-1)))
        pl.add_key_event("Down", g(lambda: self.step_row(1)))
        pl.add_key_event("Escape", g(self.cancel_solve))
        pl.add_key_event("k", g(self.toggle_pose_sliders))


def check_screenshot_path(path, *, where: str = "--screenshot") -> Path:
    """``path`` as a screenshot file, checked before anything runs: a ``.png`` name (the viewer writes PNG bytes,
    so another suffix would mislabel them), not a folder, in a folder that exists. Raises :class:`KDInputError`
    naming ``where`` and the path."""
    p = Path(path)
    if p.suffix.lower() != ".png":
        got = f"a {p.suffix!r} name" if p.suffix else "a name without a suffix"
        raise KDInputError(f"{where} {p}: expected a .png file name (screenshots are PNG images), got {got}")
    if p.is_dir():
        raise KDInputError(f"{where} {p}: is a folder; expected a .png file name")
    if not p.parent.is_dir():
        raise KDInputError(f"{where} {p}: folder {p.parent} not found; expected a .png file in an existing folder")
    return p


#: Window or screenshot sides a viewer accepts [px] (VTK aborts the process on a size it cannot allocate).
WINDOW_SIDE_PX = (16, 8192)


def check_view_arguments(args) -> None:
    """The checks a ``view`` verb makes before loading anything: ``--frame`` only with ``--screenshot``, and a
    screenshot path that can take a PNG (:func:`check_screenshot_path`)."""
    if args.screenshot is None and args.frame != 0:
        raise KDInputError("--frame: only meaningful with --screenshot FILE")
    if args.screenshot is not None:
        check_screenshot_path(args.screenshot)


def check_window_size(size, *, where: str = "--width, --height") -> tuple[int, int]:
    """``size`` (width, height) [px] as two ints when each is a whole number in :data:`WINDOW_SIDE_PX`, else
    :class:`KDInputError` naming ``where``: checked before a render window exists."""
    lo, hi = WINDOW_SIDE_PX
    try:
        w, h = size
        ok = all(float(v).is_integer() and lo <= int(v) <= hi for v in (w, h))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise KDInputError(f"{where}: expected a window of whole pixels from {lo} to {hi} on each side, got {size!r}")
    return int(w), int(h)


def _error_text(result) -> str:
    """Largest remaining error per unit: positions in mm, velocities in mm/s (never mixed)."""
    parts = []
    for unit, scale, label in (("m", 1e3, "mm"), ("m/s", 1e3, "mm/s")):
        errs = [e for c, e in zip(result.constraints, result.errors_after) if c.unit == unit]
        if errs:
            parts.append(f"max error {scale * max(errs):.4f} {label}")
    return ", ".join(parts)


#: Shapes the pose editor gives sliders at most (:attr:`ShotViewer.pose_shapes`).
POSE_SLIDER_SHAPES = 8
#: Named groups the ``g`` key cycles (``h`` holds, ``v`` stops the current one).
_GROUPS = ("jaw", "lips", "mouth", "brows", "cheeks", "eyelids", "nose", "cheek_left", "cheek_right")
_HANDLE_COLOR = "#1a9850"
_HANDLE_RADIUS_M = 0.004


def _get(row, name: str, default=None):
    """Field ``name`` of a session row (an object with attributes or a mapping)."""
    if isinstance(row, dict):
        return row.get(name, default)
    return getattr(row, name, default)


def _mm_text(v) -> str:
    return "    -" if v is None or not np.isfinite(v) else f"{float(v):7.3f}"


def panel_row_text(row) -> str:
    """One row of the constraint panel (a :class:`kdfaces.shots.authoring.Row`): time [s], kind, label, error
    before/after [mm] (mm/s for velocity), gradient ratio, enabled, and its status unless it is met (not solved,
    out of reach, conflicting with another row at the same time, ...)."""
    grad = _get(row, "gradient_ratio")
    why = _get(row, "status") or ""
    on = "on " if _get(row, "enabled", True) else "off"
    label = str(_get(row, "label", "") or "")[:14]
    text = (f"{float(_get(row, 'time_s')):5.2f} s  {str(_get(row, 'kind')):12s}  {label:14s} "
            f"{_mm_text(_get(row, 'error_before_mm'))} {_mm_text(_get(row, 'error_after_mm'))}  "
            f"{'  -' if grad is None else f'{float(grad):4.2f}'}  {on}")
    return text + (f"  {why}" if why and why not in ("met", "not solved") else "")


def _session_message(session, out) -> str:
    """The message of the session's last edit (its :class:`~kdfaces.shots.authoring.Outcome`'s, else its status)."""
    return str(getattr(out, "message", None) or getattr(session, "status", "") or "")


def _progress_text(args) -> str:
    """A solve's ``progress(sweep, max_sweeps, errors)`` as status text."""
    if len(args) >= 3:
        it, most, err = args[0], args[1], np.asarray(args[2], dtype=np.float64)
        return f"sweep {it}/{most}" + (f", largest error {1e3 * float(err.max()):.3f} mm" if err.size else "")
    return " ".join(str(a) for a in args)
