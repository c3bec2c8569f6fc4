"""A Live Link Face capture (Apple ARKit via Epic's app) → secondary motion on the default face.

    python scripts/livelink_to_kd.py [--csv TAKE.csv] [--start 10] [--end 14] [--out kd-out/livelink]
        [--export pc2]

The default take is ../shared/data/livelinkface/alex_rom_3.csv when it is present (used in place).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from kdfaces import KinematicTrajectory, livelinkface_animation, load_default_rig
from kdfaces.dynamics import FaceModel, FaceSystem, soft_tissue_settle_map
from kdfaces.io.export import export_trajectory
from kdfaces.kd import simulate_kd
from kdfaces.viz.figures import filmstrip
from kdfaces.window import automatic_window

DEFAULT_TAKE = Path(__file__).resolve().parents[2] / "shared" / "data" / "livelinkface" / "alex_rom_3.csv"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--csv", type=Path, default=DEFAULT_TAKE)
    ap.add_argument("--start", type=float, default=74.0, help="crop start [s] from the take's first sample")
    ap.add_argument("--end", type=float, default=80.0, help="crop end [s] (default: jaw open, brows up)")
    ap.add_argument("--fps", type=float, default=None, help="output frame rate (default: the capture's)")
    ap.add_argument("--out", type=Path, default=Path("kd-out/livelink"))
    ap.add_argument("--export", action="append", default=[], choices=["usd", "usda", "pc2"])
    args = ap.parse_args(argv)

    rig = load_default_rig()
    anim = livelinkface_animation(args.csv, start_s=args.start, end_s=args.end, fps=args.fps)
    traj = KinematicTrajectory(rig, anim)
    model = FaceModel.from_rig(rig, settle_time_s=soft_tissue_settle_map(rig, stiff_s=0.1, loose_s=0.3),
                               damping_ratio=0.4, shape_matching_alpha=0.2)
    system = FaceSystem(model, threads=2)
    h = 1.0 / anim.fps
    window = max(automatic_window(model, traj, step_s=h).window_s, h)
    times = anim.frame_times
    kd = simulate_kd(system, traj, times, window, step_s=h)
    x = traj.positions(times)
    dev = np.linalg.norm(kd - x, axis=-1).max(axis=1)
    pick = np.unique(np.r_[np.round(np.linspace(0, len(times) - 1, 4)).astype(int), int(np.argmax(dev))])
    outputs = [filmstrip(args.out / "livelink.png", rig.faces, {"capture": x[pick], "KD": kd[pick]}, times[pick],
                         title=f"{args.csv.name} [{args.start:g}, {args.end:g}] s")]
    for kind in args.export:
        outputs.append(export_trajectory(args.out, kd, times, kind=kind, faces=rig.faces, fps=anim.fps,
                                         name="livelink"))
    summary = {"take": str(args.csv), "frames": len(times), "fps": anim.fps, "window_s": window,
               "max_secondary_motion_m": float(dev.max()), "outputs": [str(p) for p in outputs]}
    print(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    main()
