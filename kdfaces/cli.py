"""The ``kdfaces`` command, and what every command of the toolkit shares (:func:`execute`).

Every run ends in one line: what was written, the wall time and the peak memory; or, for bad input, one line naming
the file and field (exit status 2); or, for Ctrl-C or SIGTERM, one line saying nothing was written (exit status 130).
Outputs go to a hidden sibling folder that is renamed into place only when the whole run succeeded, and that folder
is created and checked before any computation.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

from . import defaults
from .errors import KDError

__all__ = ["main", "build_parser", "configure_output", "execute", "command", "finish", "peak_memory_bytes"]


def configure_output(*, verbose: bool = False) -> None:
    """The command-line tools' process settings (a library call never changes them): Warp's start-up banner, its
    kernel-cache messages, its native "no CUDA driver" warning and VTK's display warnings only with ``verbose``;
    Python warnings as one line each."""
    import os

    import warp as wp

    def one_line(message, category, filename, lineno, line=None):
        return f"warning: {message}\n"

    warnings.formatwarning = one_line
    if verbose:
        wp.init()
        return
    wp.config.log_level = wp.LOG_WARNING
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)  # the native library writes its warning straight to file descriptor 2
            wp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _load_native(args, *, renders: bool, verbose: bool) -> None:
    """Set up the process (:func:`configure_output`: Warp) and import the native libraries the command will use —
    VTK when it ``renders``, USD when it exports USD — with SIGINT and SIGTERM held back: an interrupt must never
    land inside such an import or initialisation (half-registered native state turns into an ImportError, or a crash
    at exit). It is only recorded meanwhile, and raised right after."""
    held = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, _record_signal) for s in held}
    mask = _hold_signals(held)
    try:
        configure_output(verbose=verbose)
        if renders:
            import pyvista.plotting  # noqa: F401  (pyvista loads its VTK rendering modules lazily, on first use)
            from vtkmodules.vtkCommonCore import vtkLogger

            if not verbose:
                vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)  # "bad X server connection" off-screen
        if any(str(kind).startswith("usd") for kind in (getattr(args, "export", None) or ())):
            from pxr import Sdf, Tf, Usd, UsdGeom, Vt  # noqa: F401
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a held signal arrives now, and is recorded
        for s, h in previous.items():
            signal.signal(s, h)
    if _INTERRUPTED.is_set():
        raise KeyboardInterrupt


def peak_memory_bytes() -> int:
    """Peak resident memory of this process so far [bytes] (see :func:`kdfaces.resources.peak_rss_bytes`)."""
    from .resources import peak_rss_bytes

    return peak_rss_bytes()


_INTERRUPTED = threading.Event()
_HANDLING = threading.Event()


#: While the main thread is importing a module, an interrupt is re-sent after this many seconds instead of raised.
REDELIVER_S = 0.02
_IMPORT_MACHINERY = ("<frozen importlib._bootstrap>", "<frozen importlib._bootstrap_external>")
#: Python code that VTK's pipeline calls back into (a filter written in Python): VTK catches an exception raised
#: there, prints it as a multi-line error and carries on, so an interrupt is deferred out of it too.
_VTK_CALLBACKS = ("vtkmodules/util/vtkAlgorithm.py", "pyvista/plotting/utilities/algorithms.py")


def _on_signal(signum, frame):
    """SIGINT/SIGTERM while a command runs: KeyboardInterrupt, except inside an import.

    A KeyboardInterrupt raised in the middle of an import can land in the Python half of a native module's
    initialisation (VTK's modules import their dependencies through a Python loader while their C initialiser
    runs), which does not expect an exception there and crashes the interpreter. So while any frame of the main
    thread is in the import machinery, the interrupt is only recorded, and the signal is sent again shortly; it is
    raised once the import has finished (imports end, so the retries are bounded). The same holds inside a Python
    filter that VTK's pipeline calls (VTK would print the interrupt as a page of pipeline errors)."""
    _INTERRUPTED.set()
    if _importing(frame):
        timer = threading.Timer(REDELIVER_S, _resend, (signum,))
        timer.daemon = True
        timer.start()
        return
    raise KeyboardInterrupt


def _importing(frame) -> bool:
    """True when ``frame`` or a caller of it runs in Python's import machinery (a module is being imported), or in
    a Python filter called from VTK's pipeline."""
    while frame is not None:
        name = frame.f_code.co_filename
        if name in _IMPORT_MACHINERY or name.replace("\\", "/").endswith(_VTK_CALLBACKS):
            return True
        frame = frame.f_back
    return False


def _resend(signum) -> None:
    import os

    if _HANDLING.is_set():  # the command is still running under _on_signal
        os.kill(os.getpid(), signum)


def _record_signal(signum, frame):
    _INTERRUPTED.set()


def _hold_signals(held):
    """Block ``held`` for this thread until the returned previous mask is restored: a signal stays pending instead
    of interrupting a system call inside a native library's initialisation (a library that does not retry on
    EINTR can crash there); threads started meanwhile (BLAS, TBB, VTK) inherit the block and never take one."""
    return signal.pthread_sigmask(signal.SIG_BLOCK, held)


def command(prog: str, build, argv, *, renders) -> int:
    """Parse ``argv`` with ``build()`` and :func:`execute` it, with Ctrl-C and SIGTERM taken over from the first
    moment (before any heavy library is imported, so none can swallow the interrupt unnoticed). While the parser
    imports the libraries, an interrupt is only recorded (raised inside an import it can leave a half-imported module
    or a library's own state behind) and acted on right after."""
    previous = {s: signal.signal(s, _record_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    _INTERRUPTED.clear()
    try:
        mask = _hold_signals((signal.SIGINT, signal.SIGTERM))
        try:
            args = build().parse_args(argv)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a held signal arrives now, and is recorded
        if _INTERRUPTED.is_set():
            print(f"{prog}: interrupted; nothing was written", file=sys.stderr)
            return 130
        if getattr(args, "out", "") is None and getattr(args, "shot", None):
            args.out = str(Path("kd-out") / Path(args.shot).stem)
        return execute(prog, args, renders=renders(args))
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def execute(prog: str, args, *, renders: bool = False) -> int:
    """Run ``args.func(args)`` as a command: output folder first and all-or-nothing, one line per outcome, exit
    status 0 (done), 2 (bad input or a failed computation) or 130 (interrupted)."""
    from .io.atomic import OutputFolder
    from .resources import format_bytes

    interrupted = _INTERRUPTED
    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    _HANDLING.set()
    folder = None
    t0 = time.perf_counter()
    try:
        _load_native(args, renders=renders, verbose=getattr(args, "verbose", False))
        final = getattr(args, "out", None)
        args.final_out = final  # where the folder will appear (args.out is its temporary sibling meanwhile)
        if final is not None:
            folder = OutputFolder(final)
            args.out = str(folder.__enter__())
        summary = args.func(args)
        if interrupted.is_set():  # an interrupt that a library swallowed (e.g. inside a C callback)
            raise KeyboardInterrupt
        if folder is not None:
            args.out = str(folder.publish())
    except KeyboardInterrupt:
        if folder is not None:
            folder.abandon()
        print(f"{prog}: interrupted; nothing was written", file=sys.stderr)
        return 130
    except KDError as e:
        if folder is not None:
            folder.abandon()
        if interrupted.is_set():  # e.g. a solver stopped early by the interrupt and reported that as its error
            print(f"{prog}: interrupted; nothing was written", file=sys.stderr)
            return 130
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a full disk, a folder made read-only meanwhile: the OS's reason, in one line
        if folder is not None:
            folder.abandon()
        if interrupted.is_set():
            print(f"{prog}: interrupted; nothing was written", file=sys.stderr)
            return 130
        where = e.filename or getattr(args, "final_out", None) or "output"
        print(f"{prog}: error: {where}: {e.strerror or e}; nothing was written", file=sys.stderr)
        return 2
    except MemoryError:
        if folder is not None:
            folder.abandon()
        hint = ("a smaller --chunk-frames or --max-memory, or fewer --workers" if getattr(args, "command", "") ==
                "bake" else "a smaller budget with --max-memory or a shorter window")
        print(f"{prog}: error: out of memory (peak {format_bytes(peak_memory_bytes())}); give {hint}",
              file=sys.stderr)
        return 2
    except BaseException:
        if folder is not None:
            folder.abandon()
        if interrupted.is_set():  # a library turned our KeyboardInterrupt into its own error (e.g. an ImportError
            # from a lazy VTK import it landed in): it is still the interrupt
            print(f"{prog}: interrupted; nothing was written", file=sys.stderr)
            return 130
        raise
    finally:
        _HANDLING.clear()
        for s, h in previous.items():
            signal.signal(s, h)
    wall = time.perf_counter() - t0
    if getattr(args, "json", False):
        print(json.dumps(summary, indent=2))
    outputs = summary.get("outputs", []) if isinstance(summary, dict) else []
    where = summary.get("screenshot") if isinstance(summary, dict) and summary.get("screenshot") else args.out
    done = f"wrote {where}" if where is not None else "done (nothing written)"  # e.g. an interactive viewer
    line = (f"{prog} {args.command}: {done}" + (f" ({len(outputs)} outputs)" if outputs else "")
            + f" in {wall:.1f} s, peak memory {format_bytes(peak_memory_bytes())}")
    print(line, file=sys.stderr if getattr(args, "json", False) else sys.stdout)
    return 0


def _demo(args) -> dict:
    from .defaults import user_cache_dir
    from .errors import check_count
    from .io.rigfiles import load_rig
    from .shots.demo import OFFSET_GRID_MOVED, run_demo

    if args.offset_grid is not None:  # deprecated: one release of a note, then the flag goes
        check_count(args.offset_grid, "--offset-grid", minimum=0)
        print(f"kdfaces demo: --offset-grid is deprecated and ignored: {OFFSET_GRID_MOVED}", file=sys.stderr)
    rig = load_rig(args.rig, units=args.rig_units, cache_dir=user_cache_dir())
    return run_demo(args.out, rig=rig, threads=args.threads, exports=args.export,
                    export_unit_m=rig.source_unit_m if args.export_unit == "rig" else 1.0, progress=True,
                    max_steps=args.max_steps)


def add_rig_units_option(parser) -> None:
    """Add ``--rig-units {m,dm,cm,mm}``: the unit of the ``--rig`` file's numbers (default: the file's own)."""
    from .io.rigfiles import UNITS

    parser.add_argument("--rig-units", choices=sorted(UNITS), default=None,
                        help="unit of the rig file's numbers (default: metres; MakeHuman folders decimetres)")


def _export_rig_command(args) -> dict:
    from .defaults import user_cache_dir
    from .io.export import export_rig
    from .io.rigfiles import load_rig
    from .io.summary import write_summary

    rig = load_rig(args.rig, units=args.rig_units, cache_dir=user_cache_dir())
    out = Path(args.out)
    animation = None
    if args.animation is not None:
        from .shots.shotfile import load_shot

        shot = load_shot(args.animation, rig=rig)
        animation = shot.animation
    unit = rig.source_unit_m if args.unit == "rig" else 1.0
    written = export_rig(rig, out, formats=args.format or ["obj", "gltf"], animation=animation, unit_m=unit)
    summary = {
        "rig": {"name": rig.name, "vertices": rig.num_vertices, "shapes": rig.num_shapes,
                "diameter_m": rig.diameter, "max_delta_m": float(abs(rig.deltas).max())},
        "outputs": [str(p.relative_to(out)) for p in written],
    }
    write_summary(out, summary)
    return summary


def add_export_rig_parser(subparsers) -> None:
    """Add ``kdfaces export-rig [--rig R] [--out DIR] [--format obj|gltf|glb ...] [--json]``."""
    ap = subparsers.add_parser("export-rig", help="write a rig as an OBJ folder and/or glTF for other tools")
    ap.add_argument("--rig", default="default", help="rig: 'default', an .npz, an OBJ folder or a .gltf/.glb")
    ap.add_argument("--rig-units", choices=("m", "dm", "cm", "mm"), default=None,
                    help="unit of the rig file's numbers (default: metres)")
    ap.add_argument("--unit", choices=("m", "rig"), default="m",
                    help="write metres (default) or the rig file's own unit (OBJ)")
    ap.add_argument("--animation", metavar="SHOT.toml", default=None,
                    help="also write this shot's animation as glTF morph-weight animation")
    ap.add_argument("--out", default="kd-out/rig", help="output folder (default kd-out/rig)")
    ap.add_argument("--format", action="append", choices=("obj", "gltf", "glb"),
                    help="obj, gltf or glb (repeatable; default obj and gltf)")
    ap.add_argument("--json", action="store_true", help="print summary.json to stdout")
    ap.set_defaults(func=_export_rig_command)


def build_parser() -> argparse.ArgumentParser:
    from .bake.bake import add_bake_parser
    from .io.export import add_export_option
    from .shots.render import add_render_parser
    from .shots.run import add_run_parser
    from .shots.view import add_view_parser

    ap = argparse.ArgumentParser(prog="kdfaces", description="Kinodynamics for blend-shape face rigs.")
    ap.add_argument("-v", "--verbose", action="store_true", help="show Warp's and VTK's own messages")
    sub = ap.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the built-in demo shot on the default rig")
    demo.add_argument("--out", default="kd-out/demo", help="output folder (default kd-out/demo)")
    demo.add_argument("--rig", default="default", help="rig: 'default', an .npz, or an OBJ folder")
    add_rig_units_option(demo)
    demo.add_argument("--json", action="store_true", help="print summary.json to stdout")
    demo.add_argument("--threads", type=int, default=defaults.THREADS,
                      help=f"threads stepping the KD batch (default {defaults.THREADS})")
    demo.add_argument("--offset-grid", type=int, default=None, metavar="N",
                      help="deprecated and ignored: the Fig. 9 analog moved to `kdfem demo --offset-grid N`")
    add_export_option(demo)
    from .shots.run import add_max_steps_option

    add_max_steps_option(demo)
    demo.set_defaults(func=_demo)
    add_run_parser(sub)
    add_bake_parser(sub)
    add_render_parser(sub)
    add_view_parser(sub)
    add_export_rig_parser(sub)
    punch = sub.add_parser("punch", help="skeletal KD on MuJoCo: the relaxed punch, its IKD, On the Beat timing")
    punch.add_argument("--out", default="kd-out/punch", help="output folder (default kd-out/punch)")
    punch.add_argument("--no-movie", dest="movie", action="store_false", help="skip movie.mp4")
    punch.add_argument("--coupling", choices=("paper", "exact"), default="paper",
                       help="On the Beat's parent-torque coupling: paper (eq. 8-9 as printed, default) or exact "
                            "(the joint-space inertia's in-board entries); the timing reports both")
    punch.add_argument("--json", action="store_true", help="print summary.json to stdout")
    punch.add_argument("--export", action="append", default=[], choices=("pc2", "usd", "usda"),
                       help="also write point caches of the arm's KD and IKD points (punch_kd.*, punch_ikd.*; "
                            "repeatable)")
    from .viz.punch_viewer import add_view_options

    add_view_options(punch)
    punch.set_defaults(func=_punch)
    return ap


def _punch(args) -> dict:
    if args.view or args.screenshot is not None:
        from .viz.punch_viewer import punch_view_command

        return punch_view_command(args)
    from .articulated.punch import run_punch

    return run_punch(args.out, movie=args.movie, coupling=args.coupling, exports=args.export)


def finish(status: int, argv) -> int:
    """The exit status of a command-line entry point called with ``argv`` (None: the process's own arguments).

    After an interrupt (130) the process entry point leaves at once (``os._exit``), its message printed and its
    output folder already abandoned: the interpreter's finalization would run native destructors (VTK render
    windows, USD stages, Warp modules) whose work the interrupt may have cut short, and one of those crashing would
    turn a clean exit 130 into a SIGSEGV. A call with an explicit ``argv`` (scripts, tests) just returns."""
    if status == 130 and argv is None:
        import os

        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    return status


def main(argv=None) -> int:
    """``kdfaces …``: parse ``argv`` and run the command (see :func:`execute`); returns the exit status."""
    return finish(command("kdfaces", build_parser, argv,
                          renders=lambda args: args.command in ("demo", "run", "render", "view")
                          or getattr(args, "view", False) is True), argv)


if __name__ == "__main__":
    sys.exit(main())
