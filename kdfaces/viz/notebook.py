"""The shot viewer in a web page: Jupyter, or any browser, through pyvista's trame backend (issue 26).

:class:`ViewerApp` serves one :class:`~kdfaces.viz.viewer.ShotViewer` (with its authoring session) as a trame web app
on a localhost port: the 3D view is trame-pyvista's view of the viewer's plotter (server rendering: the images are
rendered off-screen by VTK and streamed, so neither the kernel nor the browser needs a GPU or a display), beside it
the constraint list (:meth:`~kdfaces.viz.viewer.ShotViewer.panel_text`) and the status line, with a frame slider, a
display switch, a vertex field with "add point", and buttons for solve, cancel, undo, redo and save: each calls the
same plain method of the viewer as the desktop window's key.

In a notebook the app shows itself as an ``<iframe>`` on that port (its ``_repr_html_``), and every public method of
the viewer is a method of the app (``app.set_frame(25)``, ``app.pick_vertex(725)``, ``app.set_offset_mm(...)``,
``app.undo()``, ``app.save()``): the call runs on the server's thread (VTK is used from one thread only) and the page
updates after it. :meth:`ViewerApp.solve` solves in the viewer's worker thread while the page shows the progress.

:func:`notebook_viewer` serves the viewer of an authoring session
(:class:`~kdfaces.shots.authoring.AuthoringSession` on a shot file); :func:`serve_viewer` serves a viewer made
elsewhere. Nothing is written unless the viewer's ``save`` is called.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import html
import itertools
import threading
import time

from ..errors import KDInputError

__all__ = ["ViewerApp", "notebook_viewer", "serve_viewer", "PANEL_ID", "STATUS_ID", "VIEW_ID"]

#: HTML ids of the page's constraint list, status line and 3D view (for tests and scripts driving a browser).
PANEL_ID, STATUS_ID, VIEW_ID = "kd-panel", "kd-status", "kd-view"
#: How often the page shows a running solve's progress [s].
_POLL_S = 0.2
#: How long stopping the server may take [s].
_STOP_S = 10.0
_NAMES = itertools.count()


class ViewerApp:
    """A :class:`~kdfaces.viz.viewer.ShotViewer` served as a trame web app (see the module docstring).

    Args:
        viewer: the viewer to serve; its plotter must be off-screen (``ShotViewer(..., off_screen=True)``) and should
            have no VTK widgets (``widgets=False``: the page has its own frame slider). After :meth:`start`, call
            its methods through the app (on the server's thread), not directly.
        mode: the trame-pyvista view mode: ``"server"`` (rendered in the kernel, streamed as images; works in a
            headless browser) or ``"trame"`` (switchable to client-side WebGL rendering in the page).

    Attributes:
        viewer: the served viewer; url: the page's address once started (None before).
    """

    def __init__(self, viewer, *, mode: str = "server"):
        if mode not in ("server", "trame", "client"):
            raise KDInputError(f"mode: expected 'server', 'trame' or 'client', got {mode!r}")
        self.viewer = viewer
        self.mode = mode
        self.url = None
        self.server = None
        self._loop = None
        self._thread = None
        self._poll_task = None
        self._view = None

    # --- the server ------------------------------------------------------------------------------------------------
    def start(self, *, port: int = 0, host: str = "127.0.0.1", timeout_s: float = 30.0) -> str:
        """Serve the page on ``host``:``port`` (0: a free port) from a background thread; returns its URL.

        Raises :class:`KDInputError` when the server does not come up within ``timeout_s`` [s]."""
        if self.url is not None:
            return self.url
        ready = concurrent.futures.Future()
        self._loop = asyncio.new_event_loop()

        def run():
            asyncio.set_event_loop(self._loop)
            try:
                self._build()
                self.server.controller.on_server_ready.add(lambda **_: ready.set_result(self.server.port))
                self.server.start(port=int(port), host=host, thread=True, exec_mode="task", open_browser=False,
                                  show_connection_info=False, disable_logging=True, timeout=0)
            except BaseException as e:  # noqa: BLE001  (reported by start)
                ready.set_exception(e)
                return
            self._loop.run_forever()

        self._thread = threading.Thread(target=run, name="kdfaces-viewer-app", daemon=True)
        self._thread.start()
        try:
            bound = ready.result(timeout_s)
        except concurrent.futures.TimeoutError:
            raise KDInputError(f"viewer app: the trame server did not start on {host}:{port} within "
                               f"{timeout_s:g} s") from None
        self.url = f"http://{host}:{bound}/index.html"
        return self.url

    def stop(self) -> None:
        """Stop the server and its thread (the viewer stays open: close it with ``viewer.close()``)."""
        if self._loop is None:
            return
        loop, self._loop = self._loop, None
        if self.server is not None and self.url is not None:
            asyncio.run_coroutine_threadsafe(self.server.stop(), loop).result(_STOP_S)
        loop.call_soon_threadsafe(loop.stop)
        self._thread.join(_STOP_S)
        self.url = None

    def close(self) -> None:
        """Stop the server, then close the viewer (and its plotter and KD system)."""
        self.stop()
        self.viewer.close()

    def call(self, fn, *args, **kwargs):
        """``fn(*args, **kwargs)`` on the server's thread (where the page renders), then the page updates; returns
        its result (or raises its error). Before :meth:`start` (or after :meth:`stop`) it runs on the caller's
        thread."""

        def work():
            try:
                return fn(*args, **kwargs)
            finally:
                self.refresh()

        return self._on_server(work)

    def _on_server(self, fn):
        """``fn()`` on the server's thread; its result, or its error raised here."""
        if self._loop is None or threading.current_thread() is self._thread:
            return fn()
        done = concurrent.futures.Future()

        def work():
            try:
                done.set_result(fn())
            except BaseException as e:  # noqa: BLE001  (re-raised in the caller's thread)
                done.set_exception(e)

        self._loop.call_soon_threadsafe(work)
        return done.result()

    def __getattr__(self, name: str):
        """The viewer's public methods, called through :meth:`call`; its other attributes as they are."""
        if name.startswith("_") or "viewer" not in self.__dict__:
            raise AttributeError(name)
        value = getattr(self.viewer, name)
        if not callable(value):
            return value
        return lambda *args, **kwargs: self.call(value, *args, **kwargs)

    def __dir__(self):
        return sorted(set(super().__dir__()) | {n for n in dir(self.viewer) if not n.startswith("_")})

    def solve(self, *, wait: bool = True, timeout_s: float | None = None):
        """Start the session's solve (the viewer's worker thread: warm start, the page shows its progress and stays
        responsive) and, with ``wait``, wait for it (at most ``timeout_s`` [s]). Returns the session's
        :class:`~kdfaces.ikd.IKDResult` once collected (None while running or when nothing was solved)."""
        if not self.call(self._start_solve):
            return None
        if not wait:
            return None
        t0 = time.perf_counter()
        while self._on_server(lambda: self.viewer.solving or self._poll_task is not None):
            if timeout_s is not None and time.perf_counter() - t0 > timeout_s:
                return None
            time.sleep(_POLL_S / 2)
        return self.viewer.ikd if not self.viewer.ikd_stale else None

    # --- the page ---------------------------------------------------------------------------------------------------
    def refresh(self) -> None:
        """Push the viewer's constraint list, status, frame and image to the page (on the server's thread)."""
        if self.server is None:
            return
        v = self.viewer
        state = self.server.state
        with state:
            state.kd_panel = v.panel_text()
            state.kd_status = v.status()
            state.kd_frame = int(v.frame)
            state.kd_mode = v.mode
            state.kd_rows = len(v.session.rows) if v.session is not None else 0
        if getattr(self, "_view", None) is not None:
            self._view.update()

    def _build(self) -> None:
        from trame.ui.vuetify3 import SinglePageLayout
        from trame.widgets import html as h
        from trame.widgets import vuetify3 as vu
        from trame_pyvista.ui import plotter_ui
        from trame_pyvista.widgets import get_server

        from .viewer import MODES

        v = self.viewer
        self.server = server = get_server(f"kdfaces-viewer-{next(_NAMES)}", client_type="vue3")
        state, ctrl = server.state, server.controller
        state.trame__title = f"kdfaces view: {v.shot.name}"
        state.kd_vertex = ""
        last = len(v.times) - 1

        def on_frame(kd_frame, **_):
            if kd_frame is not None and int(kd_frame) != v.frame:
                v.set_frame(int(kd_frame))
                self.refresh()

        def on_mode(kd_mode, **_):
            if kd_mode in MODES and kd_mode != v.mode:
                v.set_mode(kd_mode)
                self.refresh()

        state.change("kd_frame")(on_frame)
        state.change("kd_mode")(on_mode)

        def act(fn):
            def run(*_args):
                fn()
                self.refresh()
            return run

        def add_point():
            text = str(state.kd_vertex or "").strip()
            if not text.lstrip("-").isdigit():
                v.message = f"point: expected a vertex id (a whole number), got {text!r}"
                return
            v.pick_vertex(int(text))

        ctrl.kd_point = act(add_point)
        ctrl.kd_solve = act(self._start_solve)
        ctrl.kd_cancel = act(v.cancel_solve)
        ctrl.kd_undo = act(v.undo)
        ctrl.kd_redo = act(v.redo)
        ctrl.kd_save = act(v.save)
        self._view = None
        width, height = (int(s) for s in v.plotter.window_size)
        for name in ("_text", "_panel"):  # the page shows the status line and the constraint list as text
            actor = getattr(v, name, None)
            if actor is not None:
                actor.SetVisibility(False)
        with SinglePageLayout(server, full_height=True) as layout:
            layout.icon.hide()
            layout.footer.hide()
            layout.title.set_text(f"kdfaces view: {html.escape(v.shot.name)}")
            with layout.toolbar:
                vu.VSpacer()
                for name, label in (("kd_solve", "solve"), ("kd_cancel", "cancel"), ("kd_undo", "undo"),
                                    ("kd_redo", "redo"), ("kd_save", "save")):
                    vu.VBtn(label, click=getattr(ctrl, name), id=f"kd-{label}", variant="text")
            with layout.content, h.Div(style="display: flex; flex-wrap: wrap; gap: 12px; padding: 8px"):
                with h.Div(id=VIEW_ID, style=f"width: {width}px; height: {height}px; position: relative"):
                    self._view = plotter_ui(v.plotter, mode=self.mode, add_menu=False, server=server)
                with h.Div(style="flex: 1; min-width: 420px"):
                    vu.VSlider(v_model=("kd_frame", int(v.frame)), min=0, max=last, step=1, label="frame",
                               hide_details=True, thumb_label=True, id="kd-frame")
                    with h.Div(style="display: flex; gap: 8px; align-items: center"):
                        vu.VSelect(v_model=("kd_mode", v.mode), items=("kd_modes", list(MODES)), label="display",
                                   density="compact", hide_details=True, style="max-width: 160px")
                        vu.VTextField(v_model=("kd_vertex", ""), label="vertex id", density="compact",
                                      hide_details=True, style="max-width: 140px", id="kd-vertex")
                        vu.VBtn("add point", click=ctrl.kd_point, id="kd-point", variant="tonal")
                    h.Pre("{{ kd_status }}", id=STATUS_ID, style="font-size: 12px; white-space: pre-wrap")
                    h.Pre("{{ kd_panel }}", id=PANEL_ID, style="font-size: 12px")
        self.refresh()

    def _start_solve(self) -> bool:
        """Start the viewer's solve; served, a task on the server's loop collects it and shows its progress."""
        started = self.viewer.solve_async()
        if self._loop is None:  # not served: wait here
            self.viewer.wait_solve()
        elif started and self._poll_task is None:
            self._poll_task = self._loop.create_task(self._poll())
        return started

    async def _poll(self) -> None:
        """Every ``_POLL_S``: show the running solve's progress; collect it once it ended."""
        try:
            while True:
                await asyncio.sleep(_POLL_S)
                running = self.viewer.solving
                self.viewer.poll_solve()
                self.refresh()
                if not running:
                    return
        finally:
            self._poll_task = None

    def image(self):
        """The 3D view as the page shows it: an RGB image (H, W, 3) uint8, rendered on the server's thread."""
        import numpy as np

        def grab():
            self.viewer.plotter.render()
            return np.asarray(self.viewer.plotter.screenshot(return_img=True))[..., :3].copy()

        return self.call(grab)

    def _repr_html_(self) -> str:
        if self.url is None:
            return "<pre>" + html.escape(self.viewer.panel_text()) + "</pre>"
        w, h = (int(s) for s in self.viewer.plotter.window_size)
        return (f'<iframe src="{html.escape(self.url)}" width="{w + 560}" height="{h + 140}" '
                'style="border: 1px solid #ddd"></iframe>')


def serve_viewer(viewer, *, port: int = 0, host: str = "127.0.0.1", mode: str = "server") -> ViewerApp:
    """Serve ``viewer`` (an off-screen :class:`~kdfaces.viz.viewer.ShotViewer`) as a web page
    (:class:`ViewerApp`) on ``host``:``port`` (0: a free port); returns the started app (its ``url``)."""
    app = ViewerApp(viewer, mode=mode)
    app.start(port=port, host=host)
    return app


def notebook_viewer(session, *, size=(640, 480), port: int = 0, host: str = "127.0.0.1", mode: str = "server",
                    **viewer_options) -> ViewerApp:
    """Serve the viewer of an authoring ``session`` (a :class:`~kdfaces.shots.authoring.AuthoringSession` on a shot
    file) as a web page: an off-screen :class:`~kdfaces.viz.viewer.ShotViewer` of ``size`` (width, height) [px]
    (``viewer_options`` go to it) in a started :class:`ViewerApp`. The last expression of a notebook cell shows it.
    Saving writes into the session's shot file (work on a copy to keep the original)."""
    from .viewer import ShotViewer, check_window_size

    size = check_window_size(size, where="size")
    if not hasattr(session, "shot") or not hasattr(session, "rows"):
        raise KDInputError("session: expected a kdfaces.shots.authoring.AuthoringSession, got "
                           f"{type(session).__name__}")
    viewer = ShotViewer(session.shot, off_screen=True, size=size, widgets=False, session=session, **viewer_options)
    try:
        return serve_viewer(viewer, port=port, host=host, mode=mode)
    except BaseException:
        viewer.close()
        raise
