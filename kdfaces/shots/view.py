"""``kdfaces view``: the shot viewer opened on a shot file (:func:`view_shot`) and its command-line verb. The
viewer itself (:class:`~kdfaces.viz.viewer.ShotViewer`) takes a parsed shot; loading the file is the shots layer's
part, so the viz layer never imports shots."""

from __future__ import annotations

from .. import defaults
from ..errors import KDInputError
from ..viz.viewer import MODES, ShotViewer, check_screenshot_path, check_view_arguments, check_window_size

__all__ = ["view_shot", "add_view_parser"]


def view_shot(path, *, screenshot=None, frame: int = 0, mode: str = "kd", size=(960, 720), window_s=None,
              threads: int = defaults.THREADS, max_steps: float | None = defaults.MAX_STEPS,
              authoring: bool | None = None) -> dict:
    """Open the viewer on a shot file, or with ``screenshot`` render ``frame`` in ``mode`` off-screen to a PNG.

    ``authoring`` (default: in the window, not for a screenshot) opens an
    :class:`~kdfaces.shots.authoring.AuthoringSession` on the file: targets are picked, dragged, solved and saved
    back into it from the viewer (keys in :mod:`kdfaces.viz.viewer`).

    In ``"ikd"`` mode the screenshot solves IKD first. Returns a small summary (frame, time, ms per KD state).
    ``max_steps``: the shot's work estimate is checked against it as it is loaded (see
    :func:`~kdfaces.shots.shotfile.estimate_work`). ``screenshot`` must be a ``.png`` path
    (:func:`check_screenshot_path`, checked before the shot is read).
    """
    from .shotfile import load_shot

    size = check_window_size(size)
    if screenshot is not None:
        check_screenshot_path(screenshot)
    shot = load_shot(path, max_steps=max_steps)
    n = len(shot.animation.frame_times)
    if not 0 <= int(frame) < n:
        raise KDInputError(f"--frame: {frame} is outside the shot's frames 0..{n - 1}")
    if mode not in MODES:
        raise KDInputError(f"--mode: expected one of {MODES}, got {mode!r}")
    session = None
    if (screenshot is None) if authoring is None else authoring:
        from .authoring import AuthoringSession

        session = AuthoringSession(path, window_s=window_s, threads=threads)
        shot = session.shot
    viewer = ShotViewer(shot, off_screen=screenshot is not None, size=size, window_s=window_s, threads=threads,
                        session=session)
    try:
        if mode == "ikd":
            viewer.solve_ikd()
        viewer.set_mode(mode)
        viewer.set_frame(int(frame))
        summary = {"shot": shot.name, "frame": viewer.frame, "time_s": float(viewer.times[viewer.frame]),
                   "mode": viewer.mode, "window_s": viewer.window_at(), "adaptive": viewer.adaptive,
                   "kd_state_ms": viewer.last_ms, "authoring": session is not None}
    except BaseException:
        viewer.close()
        raise
    return viewer.finish(summary, screenshot)


def _view_command(args) -> dict:
    check_view_arguments(args)
    return view_shot(args.shot, screenshot=args.screenshot, frame=args.frame, mode=args.mode,
                     size=(args.width, args.height), window_s=args.window, threads=args.threads,
                     max_steps=args.max_steps)


def add_view_parser(subparsers) -> None:
    """Add ``kdfaces view SHOT.toml [--screenshot FILE --frame F] [--mode kinematic|kd|ikd] [--window S]``."""
    ap = subparsers.add_parser("view", help="scrub a shot's KD states interactively (or screenshot one frame)")
    ap.add_argument("shot", help="the shot file (TOML)")
    ap.add_argument("--screenshot", metavar="FILE", help="render one frame off-screen to this PNG and exit")
    ap.add_argument("--frame", type=int, default=0, help="frame index for --screenshot (default 0)")
    ap.add_argument("--mode", default="kd", choices=MODES, help="what to display (default kd)")
    ap.add_argument("--window", type=defaults.window_argument,
                    help="KD window δ [s], 'auto' or 'adaptive' (default: the shot's)")
    ap.add_argument("--width", type=int, default=960, help="window width [px]")
    ap.add_argument("--height", type=int, default=720, help="window height [px]")
    ap.add_argument("--threads", type=int, default=defaults.THREADS,
                    help=f"CPU threads per KD state (default {defaults.THREADS})")
    ap.add_argument("--json", action="store_true", help="print the summary to stdout")
    from .run import add_max_steps_option

    add_max_steps_option(ap)
    ap.set_defaults(func=_view_command)
