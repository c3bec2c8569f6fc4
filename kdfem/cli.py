"""The ``kdfem`` command: ``kdfem demo [--out DIR] [--json]``."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from kdfaces.errors import KDInputError, SimulationBlowUpError

from .default import DEFAULT_EDGE_LENGTH_FAC

__all__ = ["main"]

SWEEP_WINDOWS_S = (0.08, 0.16, 0.32, 0.568)


def _peaks(times: np.ndarray, dev: np.ndarray, *, count: int = 5, gap: float = 0.15) -> np.ndarray:
    """Indices of up to ``count`` frames of largest ``dev``, at least ``gap`` [s] apart, in time order."""
    picked: list[int] = []
    for i in np.argsort(dev)[::-1]:
        if all(abs(times[i] - times[j]) >= gap for j in picked):
            picked.append(int(i))
        if len(picked) == count:
            break
    return np.sort(np.array(picked, dtype=np.int64))


def _demo(args) -> dict:
    from kdfaces.demo import demo_animation
    from kdfaces.io.rigfiles import load_rig
    from kdfaces.kd import simulate_full, simulate_kd
    from kdfaces.summary import write_summary
    from kdfaces.trajectory import KinematicTrajectory

    from .default import default_hat_system
    from .render import error_plot, hat_filmstrip
    from .tetmesh import tet_quality

    if args.frame_stride < 1 or args.threads < 1:
        raise KDInputError("--frame-stride and --threads: expected positive integers")
    out = Path(args.out)
    rig = load_rig(args.rig)
    anim = demo_animation()
    traj = KinematicTrajectory(rig, anim)
    system, surf, _ = default_hat_system(rig, edge_length_fac=args.edge_length_fac, cache_dir=out / ".cache",
                                         threads=args.threads)
    mesh = system.model.mesh
    h = args.h
    times = anim.frame_times[:: args.frame_stride]  # every frame_stride-th frame: "fps" below is their rate
    full = simulate_full(system, traj, times, h=h)
    rigid = system.rigid(traj, times)
    t0 = time.perf_counter()
    kd = simulate_kd(system, traj, times, args.window, h=h)
    ms_per_state = 1e3 * (time.perf_counter() - t0) / len(times)
    sweep, errors = [], {}
    for w in sorted({*SWEEP_WINDOWS_S, args.window}):
        x = kd if abs(w - args.window) < 1e-12 else simulate_kd(system, traj, times, w, h=h)
        errors[w] = np.linalg.norm(x - full, axis=2).max(axis=1)
        sweep.append({"window_s": w, "max_error_vs_full_m": float(errors[w].max())})
    dev = np.linalg.norm(full - rigid, axis=2).max(axis=1)
    strip_idx = _peaks(times, dev)
    rows = {"kinematic (rigid)": rigid[strip_idx], f"KD δ={args.window:g}s": kd[strip_idx],
            "full simulation": full[strip_idx]}
    outputs = [
        hat_filmstrip(out / "filmstrip_hat.png", rig, traj, system, surf.faces, rows, times[strip_idx]),
        error_plot(out / "kd_error_vs_full.png", times, errors, dev),
    ]
    q = tet_quality(mesh)
    summary = {
        "hat": {"nodes": mesh.num_nodes, "tets": mesh.num_tets, "min_tet_volume_m3": q["min_tet_volume_m3"],
                "min_dihedral_deg": q["min_dihedral_deg"]},
        "fps": anim.fps / args.frame_stride,
        "frames": len(times),
        "kd": {"window_s": args.window, "ms_per_state": ms_per_state, "sweep": sweep,
               "max_deviation_from_rigid_m": float(dev.max())},
        "outputs": [str(p.relative_to(out)) for p in outputs],
    }
    write_summary(out, summary)
    return summary


def build_parser() -> argparse.ArgumentParser:
    from .window_cli import add_window_parser

    ap = argparse.ArgumentParser(prog="kdfem", description="FEM secondary motion attached to an animated head.")
    sub = ap.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="the default head nods and turns wearing a floppy hat: rigid | KD | full")
    demo.add_argument("--out", default="kd-out/hat", help="output folder (default kd-out/hat)")
    demo.add_argument("--rig", default="default", help="rig: 'default' or an .npz rig with a head joint")
    demo.add_argument("--window", type=float, default=0.568, help="KD window δ [s] (default 0.568)")
    demo.add_argument("--h", type=float, default=0.01, help="simulation step [s] (default 0.01)")
    demo.add_argument("--edge-length-fac", type=float, default=DEFAULT_EDGE_LENGTH_FAC,
                      help=f"pytetwild edge length / bbox diagonal (default {DEFAULT_EDGE_LENGTH_FAC}, ~1k tets)")
    demo.add_argument("--frame-stride", type=int, default=2,
                      help="evaluate every n-th frame of the shot (default 2; summary fps is the evaluated rate)")
    demo.add_argument("--threads", type=int, default=2, help="threads stepping the KD batch (default 2)")
    demo.add_argument("--json", action="store_true", help="print summary.json to stdout")
    demo.set_defaults(func=_demo)
    add_window_parser(sub)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        summary = args.func(args)
    except (KDInputError, SimulationBlowUpError) as e:
        print(f"kdfem: error: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        name = "window.json" if args.command == "window" else "summary.json"
        print(f"kdfem {args.command}: wrote {Path(args.out) / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
