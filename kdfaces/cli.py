"""The ``kdfaces`` command."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .errors import KDError

__all__ = ["main", "build_parser", "configure_output"]


def configure_output(*, verbose: bool = False) -> None:
    """The command-line tools' process settings (a library call never changes them): Warp's start-up banner, its
    kernel-cache messages and its native "no CUDA driver" warning only with ``verbose``."""
    import os

    import warp as wp

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


def _demo(args) -> dict:
    from .shots.demo import run_demo

    return run_demo(args.out, rig=args.rig, threads=args.threads, exports=args.export,
                    offset_grid=args.offset_grid > 0, offset_grid_size=max(args.offset_grid, 1))


def build_parser() -> argparse.ArgumentParser:
    from .io.export import add_export_option, add_export_rig_parser
    from .shots.render import add_render_parser
    from .shots.run import add_run_parser
    from .viz.viewer import add_view_parser

    ap = argparse.ArgumentParser(prog="kdfaces", description="Kinodynamics for blend-shape face rigs.")
    ap.add_argument("-v", "--verbose", action="store_true", help="show Warp's and VTK's own messages")
    sub = ap.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the built-in demo shot on the default rig")
    demo.add_argument("--out", default="kd-out/demo", help="output folder (default kd-out/demo)")
    demo.add_argument("--rig", default="default", help="rig: 'default', an .npz, or an OBJ folder")
    demo.add_argument("--json", action="store_true", help="print summary.json to stdout")
    demo.add_argument("--threads", type=int, default=2, help="threads stepping the KD batch (default 2)")
    demo.add_argument("--offset-grid", type=int, default=3, metavar="N",
                      help="N x N hat-tip targets of the Fig. 9 analog (default 3, about 30 s; 0 skips it)")
    add_export_option(demo)
    demo.set_defaults(func=_demo)
    add_run_parser(sub)
    add_render_parser(sub)
    add_view_parser(sub)
    add_export_rig_parser(sub)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure_output(verbose=args.verbose)
    try:
        summary = args.func(args)
    except KDError as e:
        print(f"kdfaces: error: {e}", file=sys.stderr)
        return 2
    if getattr(args, "json", False):
        print(json.dumps(summary, indent=2))
    elif getattr(args, "out", None):
        print(f"kdfaces {args.command}: wrote {Path(args.out) / 'summary.json'}")
    elif isinstance(summary, dict) and summary.get("screenshot"):
        print(f"kdfaces {args.command}: wrote {summary['screenshot']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
