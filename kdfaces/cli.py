"""The ``kdfaces`` command."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from .errors import KDInputError, SimulationBlowUpError

__all__ = ["main"]


def _demo(args) -> dict:
    from .demo import demo_animation, demo_kd
    from .io.rigfiles import load_rig
    from .kd_report import write_kd_report
    from .render import filmstrip
    from .summary import write_summary
    from .trajectory import KinematicTrajectory

    out = Path(args.out)
    rig = load_rig(args.rig)
    anim = demo_animation()
    traj = KinematicTrajectory(rig, anim)
    times = anim.frame_times
    kd, report, kd_summary = demo_kd(rig, traj, threads=args.threads)
    strip = np.array([0, 20, 28, 65, 103, 125])  # frames: rest, after the head turn, blink, smile, brow, nod
    strip_times = times[strip]
    rows = {"kinematic": traj.positions(strip_times), f"KD (δ = {kd_summary['window_s']:.2f} s)": kd[strip]}
    outputs = [filmstrip(out / "filmstrip_kinematic_kd.png", rig.faces, rows, strip_times,
                         title=f"{rig.name}: kinematic | KD demo"),
               *write_kd_report(out, report)]
    summary = {
        "rig": {"name": rig.name, "vertices": rig.num_vertices, "shapes": rig.num_shapes},
        "fps": anim.fps,
        "frames": len(times),
        "duration_s": anim.duration,
        "outputs": [str(p.relative_to(out)) for p in outputs],
        "kd": kd_summary,
    }
    write_summary(out, summary)
    return summary


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="kdfaces", description="Kinodynamics for blend-shape face rigs.")
    sub = ap.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the built-in demo shot on the default rig")
    demo.add_argument("--out", default="kd-out/demo", help="output folder (default kd-out/demo)")
    demo.add_argument("--rig", default="default", help="rig: 'default', an .npz, or an OBJ folder")
    demo.add_argument("--json", action="store_true", help="print summary.json to stdout")
    demo.add_argument("--threads", type=int, default=2, help="threads stepping the KD batch (default 2)")
    demo.set_defaults(func=_demo)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        summary = args.func(args)
    except (KDInputError, SimulationBlowUpError) as e:
        print(f"kdfaces: error: {e}", file=sys.stderr)
        return 2
    if getattr(args, "json", False):
        print(json.dumps(summary, indent=2))
    else:
        print(f"kdfaces {args.command}: wrote {Path(args.out) / 'summary.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
