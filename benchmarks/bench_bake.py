"""The Dask bake (``kdfaces bake``): throughput with 1 and 2 local worker processes against the single-process KD,
the per-task overhead, and each worker's peak memory for two lengths of a take.

The take is a 60 s stretch of the real Live Link Face capture (30 Hz) on the default head, without constraints (the
client's IKD solve is the same as ``kdfaces run``'s; it is not what the workers scale); when the capture is absent,
the demo animation. Every bake is checked bit for bit (float32) against the single-process KD of the same shot, so a
row exists only for an equal bake.

Rows: ``bake_single_process`` (``run_shot``'s one KD batch, 2 threads), ``bake_fps`` per worker count (frames per
second of the task phase: first submission to last result, cluster start and the client's window estimate
excluded; ``median_s`` is the whole call), ``bake_overhead`` (the share of the workers' wall time outside tasks:
scheduling, transfers, result round trips, and the idle tail of the last chunks; and the median gap between two
tasks on one worker), ``bake_worker_peak_rss`` (max over the workers of a worker process's peak resident memory,
for two take lengths).
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TAKE = Path(os.environ.get("KDFACES_SHARED_DATA", ROOT.parent / "shared" / "data")) / "livelinkface" / "alex_rom_3.csv"
CAPTURE = """name = "bake-bench"
[animation]
source = "{take}"
start_s = {start}
end_s = {end}
fps = 30
[dynamics]
settle_time_s = {{ stiff_s = 0.2, loose_s = 0.45 }}
damping_ratio = 0.3
"""
DEMO = (ROOT / "kdfaces" / "shots" / "demo.toml").read_text().split("[[constraints]]")[0]
START_S = 10.0


def _shot(folder: Path, length_s: float) -> tuple[Path, str]:
    p = folder / f"take{length_s:g}.toml"
    if TAKE.exists():
        p.write_text(CAPTURE.format(take=TAKE, start=START_S, end=START_S + length_s))
        return p, f"{length_s:g} s of alex_rom_3 @30 Hz"
    p.write_text(DEMO)
    return p, "demo animation (capture absent)"


def _load() -> str:
    try:
        return f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    except OSError:
        return ""


def bench_bake_throughput(repeats: int):
    from kdfaces.bake import BakeStore, bake_shot
    from kdfaces.shots import run_shot

    out = []
    with tempfile.TemporaryDirectory() as tmp:
        shot, what = _shot(Path(tmp), 60.0)
        t0 = time.perf_counter()
        run = run_shot(shot, solve=False)
        single = time.perf_counter() - t0
        reference = run.final.astype(np.float32)
        frames, n = reference.shape[:2]
        kd_s = run.ms_per_state * frames / 1e3
        size = f"{what}: {frames} frames × {n / 1e3:.1f}k vertices, δ = {run.window_s:.3f} s"
        out.append({"name": "bake_single_process", "size": size + f", 2 threads, {_load()}", "median_s": single,
                    "rate": frames / kd_s, "unit": "frames/s (KD batch only)"})
        runs: dict[int, list] = {1: [], 2: []}
        for k, workers in enumerate([1, 2] * max(1, min(repeats, 3))):  # interleaved: the machine's load drifts
            store = Path(tmp) / f"store{k}.zarr"
            r = bake_shot(shot, store, workers=workers)
            if not np.array_equal(BakeStore.open(store).read(), reference):
                raise AssertionError(f"bake with {workers} workers differs from the single-process KD")
            runs[workers].append((r, os.getloadavg()[0]))
        for workers, rs in runs.items():
            best = sorted((r for r, _ in rs), key=lambda r: r.tasks_wall_s)[len(rs) // 2]
            loads = "/".join(f"{load:.1f}" for _, load in rs)
            per_core = sum(r.frames for r, _ in rs) / sum(sum(t["kd_s"] for t in r.tasks) for r, _ in rs)
            label = (f"{size}, {workers} worker(s), {best.chunks} chunks of {best.chunk_frames}, {len(rs)} runs "
                     f"(load {loads} on {os.cpu_count()} cores), in-task KD {per_core:.1f} frames/s per worker")
            out.append({"name": "bake_fps", "size": label + ", equal to single-process: yes",
                        "median_s": statistics.median(r.wall_s for r, _ in rs),
                        "rate": statistics.median(r.frames_per_s for r, _ in rs), "unit": "frames/s (task phase)"})
            out.append({"name": "bake_overhead", "size": label, "median_s": best.tasks_wall_s,
                        "rate": 100 * statistics.median(r.overhead_share for r, _ in rs),
                        "unit": f"% of worker time outside tasks (median gap {1e3 * (best.task_gap_s or 0):.1f} "
                                f"ms/task, setup {best.summary()['setup_s']:.2f} s)"})
    return out


def bench_bake_memory(repeats: int):
    from kdfaces.bake import bake_shot

    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for length in (15.0, 60.0):
            shot, what = _shot(Path(tmp), length)
            r = bake_shot(shot, Path(tmp) / f"mem{length:g}.zarr", workers=2)
            peak = r.summary()["max_worker_peak_rss_bytes"]
            out.append({"name": "bake_worker_peak_rss", "size": f"{what}, {r.frames} frames, 2 workers",
                        "median_s": r.wall_s, "rate": peak / 2**20, "unit": "MiB peak RSS per worker (max)"})
    return out


BENCHMARKS = [("bake_throughput", bench_bake_throughput), ("bake_worker_peak_rss", bench_bake_memory)]
