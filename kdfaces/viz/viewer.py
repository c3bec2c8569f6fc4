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
"""

from __future__ import annotations

import dataclasses
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
           "check_screenshot_path"]

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
                 widgets: bool = True, device: str = "cpu", threads: int = defaults.THREADS, focus=None):
        self.shot = shot
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
        """The shot's constraints; once the width slider moved, all with the viewer's correction width σ."""
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
    def set_frame(self, value) -> None:
        """Timeline slider: show frame ``round(value)`` (clamped to the shot)."""
        self.frame = int(np.clip(round(float(value)), 0, len(self.times) - 1))
        self.update()

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
        self.width_s = v
        self._width_set = True
        self._parameters_changed(rebuild=False)

    def _parameters_changed(self, *, rebuild: bool) -> None:
        if rebuild:
            self._rebuild_system()
        if self.ikd is not None:
            self.ikd_stale = True
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

    def solve_ikd(self):
        """Key ``i``: solve IKD for the shot's constraints with the current parameters; show the IKD state."""
        from ..ikd.solver import solve_ikd

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
        pl.add_mesh(self.mesh, color=SKIN, smooth_shading=True, specular=0.2)
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
            pl.add_key_event("i", self.solve_ikd)
            pl.add_key_event("a", lambda: self.set_adaptive(not self.adaptive))
            pl.add_key_event("w", lambda: self.show_kinematic(not self._wire_actor.GetVisibility()))

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
        return "\n".join(lines)

    # --- output ------------------------------------------------------------------------------------------------
    def show(self) -> None:
        """Open the interactive window (blocks until it is closed); playback runs at the shot's frame rate."""
        self._open_window(float(getattr(self.shot.animation, "fps", 25.0)), f"kdfaces view: {self.shot.name}")

    def close(self) -> None:
        """Close the window and free the plotter (and the KD system's worker threads)."""
        self.plotter.close()
        self.system.close()


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
