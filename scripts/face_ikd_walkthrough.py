"""What a technical animator does with kdfaces, step by step, in plain Python.

rig → animate (keys) → KD (secondary motion) → IKD (hit a pose exactly) → render → export a point cache.

    python scripts/face_ikd_walkthrough.py [--out kd-out/walkthrough] [--duration 2.0] [--export usd]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from kdfaces import FaceAnimation, JointDrive, KeyframeCurve, KinematicTrajectory, ShapeTrack, load_default_rig
from kdfaces.dynamics import FaceModel, FaceSystem, soft_tissue_settle_map
from kdfaces.ikd import GaussianBasis, pose_constraint, solve_ikd
from kdfaces.io.export import export_trajectory
from kdfaces.kd import simulate_kd
from kdfaces.motion.joints import SkeletonAnimation
from kdfaces.rig.poses import kinematic_pose
from kdfaces.viz.figures import filmstrip
from kdfaces.window import automatic_window


def ease(times, values):
    v = np.asarray(values, dtype=float)
    return KeyframeCurve.create(times, v, interpolation="hermite", tangents=np.zeros_like(v))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("kd-out/walkthrough"))
    ap.add_argument("--duration", type=float, default=2.0, help="shot length [s]")
    ap.add_argument("--export", action="append", default=[], choices=["usd", "usda", "pc2"])
    args = ap.parse_args(argv)
    d = args.duration

    # 1. the rig: the CC0 MakeHuman head with 52 ARKit shapes (metres, y up)
    rig = load_default_rig()

    # 2. animate: a quick smile and a head turn that stops sharply
    smile = ShapeTrack(("mouthSmileLeft", "mouthSmileRight"), ease([0, 0.3 * d, 0.45 * d, d], [[0, 0], [0, 0],
                                                                                             [1, 1], [1, 1]]))
    turn = JointDrive(ease([0, 0.2 * d, 0.35 * d, d], [[0, 0, 0], [0, 0, 0], [0.5, 0.0, 0.0], [0.5, 0.0, 0.0]]))
    anim = FaceAnimation(tracks=(smile,), skeleton=SkeletonAnimation((turn,)), end_s=d, fps=25, name="walkthrough")
    traj = KinematicTrajectory(rig, anim)

    # 3. KD: loose cheeks and lips, stiff forehead; the window comes from the gains and the sharpest acceleration
    settle = soft_tissue_settle_map(rig, stiff_s=0.12, loose_s=0.35)
    model = FaceModel.from_rig(rig, settle_time_s=settle, damping_ratio=0.3, shape_matching_alpha=0.2)
    system = FaceSystem(model, threads=2)
    h = 1.0 / anim.fps
    window = max(automatic_window(model, traj, step_s=h).window_s, h)
    times = anim.frame_times
    kd = simulate_kd(system, traj, times, window, step_s=h)

    # 4. IKD: at 60 % of the shot, the face must be exactly the animated pose with the head tilted 8 degrees
    tc = round(0.6 * d * anim.fps) / anim.fps
    target = kinematic_pose(traj, tc, head_deg=[0.0, 0.0, 8.0])
    pose = pose_constraint(tc, target, GaussianBasis(tc, 0.25), num_vertices=rig.num_vertices)
    result = solve_ikd(system, traj, [pose], window_s=window, step_s=h,
                       update="secant")
    ikd = simulate_kd(system, result.trajectory, times, window, step_s=h)

    # 5. look at it, and hand it to other tools
    pick = np.unique(np.round(np.linspace(0, len(times) - 1, 5)).astype(int).tolist() + [int(round(tc * 25))])
    outputs = [filmstrip(args.out / "walkthrough.png", rig.faces, {"kinematic": traj.positions(times[pick]),
                         "KD": kd[pick], "IKD": ikd[pick]}, times[pick], title="walkthrough")]
    for kind in args.export:
        outputs.append(export_trajectory(args.out, ikd, times, kind=kind, faces=rig.faces, fps=anim.fps,
                                         name="walkthrough"))
    summary = {
        "window_s": window,
        "max_secondary_motion_m": float(np.linalg.norm(kd - traj.positions(times), axis=-1).max()),
        "ikd_converged": result.converged,
        "ikd_iterations": result.iterations,
        "ikd_error_after_m": float(result.errors_after[0]),
        "outputs": [str(p) for p in outputs],
    }
    print(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    main()
