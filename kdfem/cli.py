"""The ``kdfem`` command: ``kdfem demo`` (the floppy hat), ``kdfem window [MESH]`` (the modal window report) and
``kdfem door`` (the floppy hat under the door: IKD on posture), ``kdfem braid`` (a braid flips over the shoulder:
KD with contact), ``kdfem follow`` (a head that follows through) and
``kdfem view`` (the hat's scrubbing viewer)."""

from __future__ import annotations

import argparse
import sys

from kdfaces import defaults
from kdfaces.cli import command, finish

__all__ = ["main", "build_parser"]


def _demo(args) -> dict:
    from kdfaces.defaults import user_cache_dir
    from kdfaces.errors import check_count

    from .demo import run_hat_demo

    check_count(args.offset_grid, "--offset-grid", minimum=0)
    return run_hat_demo(args.out, rig=args.rig, window_s=args.window, step_s=args.step,
                        edge_length_fac=args.edge_length_fac, frame_stride=args.frame_stride, threads=args.threads,
                        offset_grid=args.offset_grid, cache_dir=user_cache_dir() / "tets",
                        with_colliders=args.with_colliders, export=args.export, export_unit=args.export_unit)


def _add_scene_options(parser) -> None:
    """``--no-colliders`` and ``--export`` (:func:`kdfaces.io.export.add_export_option`) of the hat's scenes (their
    KD and IKD trajectories: ``kdfem demo`` hat_kd and face, ``door`` hat_kd, hat_ikd, head and head_ikd,
    ``follow`` hat_kd and face_kd)."""
    from kdfaces.io.export import add_export_option

    parser.add_argument("--no-colliders", dest="with_colliders", action="store_false",
                        default=defaults.HAT_COLLIDERS,
                        help="simulate the hat without colliders (default: the head is one, and the door's lintel)")
    add_export_option(parser)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="kdfem", description="FEM secondary motion attached to an animated head.")
    ap.add_argument("-v", "--verbose", action="store_true", help="show Warp's and VTK's own messages")
    sub = ap.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="the default head nods and turns wearing a floppy hat: rigid | KD | full")
    demo.add_argument("--out", default="kd-out/hat", help="output folder (default kd-out/hat)")
    demo.add_argument("--rig", default="default", help="rig: 'default' or an .npz rig with a head joint")
    demo.add_argument("--window", type=defaults.window_argument, default=defaults.HAT_WINDOW_S,
                      help=f"KD window δ [s], or 'adaptive': one per frame (default {defaults.HAT_WINDOW_S})")
    demo.add_argument("--step", "--h", dest="step", type=float, default=defaults.HAT_STEP_S,
                      help=f"simulation step [s] (default {defaults.HAT_STEP_S})")
    demo.add_argument("--edge-length-fac", type=float, default=defaults.TET_EDGE_LENGTH_FAC,
                      help=f"pytetwild edge length / bbox diagonal (default {defaults.TET_EDGE_LENGTH_FAC}, ~1k tets)")
    demo.add_argument("--frame-stride", type=int, default=2,
                      help="evaluate every n-th frame of the shot (default 2; summary fps is the evaluated rate)")
    demo.add_argument("--threads", type=int, default=defaults.THREADS,
                      help=f"threads running the KD batch's windows (default {defaults.THREADS})")
    demo.add_argument("--offset-grid", type=int, default=3, metavar="N",
                      help="N x N hat-tip targets of the Fig. 9 analog, IKD through the head posture "
                           "(default 3, about 40 s; 0 skips it)")
    demo.add_argument("--json", action="store_true", help="print summary.json to stdout")
    _add_scene_options(demo)
    demo.set_defaults(func=_demo)
    _add_window_parser(sub)
    door = sub.add_parser("door", help="the floppy hat under the door: IK on the neck chain, IKD on posture, clearance")
    door.add_argument("shot", nargs="?", default=None, metavar="DOOR_SHOT",
                      help="a door shot file (.toml; default: the built-in scene kdfem/scenes/door.toml)")
    door.add_argument("--out", default="kd-out/door", help="output folder (default kd-out/door)")
    door.add_argument("--no-movie", dest="movie", action="store_false", default=None, help="skip movie.mp4")
    door.add_argument("--json", action="store_true", help="print summary.json to stdout")
    _add_scene_options(door)
    door.set_defaults(func=_door)
    follow = sub.add_parser("follow", help="a sharp head turn on the skeletal KD neck (MuJoCo); face and hat ride it")
    follow.add_argument("--out", default="kd-out/follow", help="output folder (default kd-out/follow)")
    follow.add_argument("--frame-stride", type=int, default=1,
                        help="export every n-th frame of the shot (default 1)")
    follow.add_argument("--json", action="store_true", help="print summary.json to stdout")
    _add_scene_options(follow)
    follow.set_defaults(func=_follow)
    braid = sub.add_parser("braid", help="a braid flips over the shoulder with a head turn: KD with contact (§6.3)")
    braid.add_argument("--out", default="kd-out/braid", help="output folder (default kd-out/braid)")
    braid.add_argument("--frame-stride", type=int, default=1,
                       help="evaluate every n-th frame of the shot (default 1; summary fps is the evaluated rate)")
    braid.add_argument("--no-movie", dest="movie", action="store_false", default=True, help="skip movie.mp4")
    braid.add_argument("--json", action="store_true", help="print summary.json to stdout")
    braid.set_defaults(func=_braid)
    from .viewer import add_view_parser

    add_view_parser(sub)
    return ap


def _follow(args) -> dict:
    from .scenes.follow import run_follow

    return run_follow(args.out, with_colliders=args.with_colliders, export=args.export,
                      export_unit=args.export_unit, export_stride=args.frame_stride)


def _braid(args) -> dict:
    from .scenes.braid import run_braid

    return run_braid(args.out, frame_stride=args.frame_stride, movie=args.movie, progress=not args.json)


def _door(args) -> dict:
    from .scenes.door import run_door

    return run_door(args.out, shot=args.shot, movie=args.movie, progress=not args.json,
                    with_colliders=args.with_colliders, export=args.export, export_unit=args.export_unit)


def _window(args) -> dict:
    """The ``kdfem window`` handler: runs :func:`~kdfem.modal.window.window_report`; returns the window.json dict."""
    from kdfaces.defaults import user_cache_dir

    from .modal.window import window_report

    run = window_report(args.surface, out=args.out, omega_max_radps=args.omega_max, v_max_mps=args.v_max,
                        rayleigh_alpha=args.alpha, rayleigh_beta=args.beta, edge_length_fac=args.edge_length_fac,
                        scale=args.scale, attach_distance_m=args.attach_distance, attach_below_m=args.attach_below,
                        modes=args.modes, nonlinear=args.nonlinear, sweep=args.sweep, sweep_stride=args.sweep_stride,
                        progress=True, cache_dir=user_cache_dir() / "tets")
    return run.result


def _add_window_parser(subparsers):
    """Add the ``window`` verb to an argparse ``subparsers``; its ``func`` returns the window.json dict."""
    p = subparsers.add_parser("window", help="modal KD window of an attached object (§5.3) with a verified report")
    p.add_argument("surface", nargs="?", default=None, metavar="SURFACE_MESH",
                   help="closed surface .obj/.ply/.stl/.off in metres (default: the procedural hat)")
    p.add_argument("--omega-max", type=float, default=defaults.OMEGA_MAX_RADPS,
                   help=f"largest bone angular speed jump [rad/s] ({defaults.OMEGA_MAX_RADPS:g})")
    p.add_argument("--v-max", type=float, default=defaults.V_MAX_MPS,
                   help=f"largest bone linear speed jump [m/s] ({defaults.V_MAX_MPS:g})")
    p.add_argument("--alpha", type=float, default=defaults.RAYLEIGH_ALPHA,
                   help=f"Rayleigh mass damping α [1/s] ({defaults.RAYLEIGH_ALPHA:g})")
    p.add_argument("--beta", type=float, default=defaults.RAYLEIGH_BETA,
                   help=f"Rayleigh stiffness damping β [s] ({defaults.RAYLEIGH_BETA:g})")
    p.add_argument("--out", default="kd-out/window", help="output folder (default kd-out/window)")
    p.add_argument("--json", action="store_true", help="print window.json to stdout")
    p.add_argument("--edge-length-fac", type=float, default=defaults.TET_EDGE_LENGTH_FAC,
                   help=f"tet edge / bbox diagonal ({defaults.TET_EDGE_LENGTH_FAC:g})")
    p.add_argument("--scale", type=float, default=1.0, help="file units → metres (1)")
    p.add_argument("--attach-distance", type=float, default=defaults.ATTACH_DISTANCE_M,
                   help=f"attach nodes within this distance of the head surface [m] ({defaults.ATTACH_DISTANCE_M:g})")
    p.add_argument("--attach-below", type=float, default=None, metavar="Y",
                   help="attach the nodes with y ≤ Y [m] instead (a mesh not on the head; no Fig. 10 sweep)")
    p.add_argument("--modes", type=int, default=6, help="modes computed and reported (6)")
    p.add_argument("--nonlinear", action=argparse.BooleanOptionalAction, default=True,
                   help="also verify with the nonlinear FEM (default on)")
    p.add_argument("--sweep", action=argparse.BooleanOptionalAction, default=True,
                   help="KD-vs-full error over the demo animation, Fig. 10 (default on)")
    p.add_argument("--sweep-stride", type=int, default=10, help="every n-th demo frame in the sweep (10)")
    p.set_defaults(func=_window)
    return p


def main(argv=None) -> int:
    """``kdfem …``: parse ``argv`` and run the command (see :func:`kdfaces.cli.execute`); returns the exit status."""
    return finish(command("kdfem", build_parser, argv, renders=lambda args: True), argv)


if __name__ == "__main__":
    sys.exit(main())
