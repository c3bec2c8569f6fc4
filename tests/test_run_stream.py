"""``kdfaces run`` streams a take: chunks of frames through simulate_kd, caches written chunk by chunk, statistics
gathered on the way. Chunked equals one batch bit for bit (KD states are history-free); the PC2 of ``run`` is
``bake``'s byte for byte; a 4× longer take does not take more memory."""

from __future__ import annotations

import importlib.util
import json
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest

from kdfaces.cli import main as kdfaces_main
from kdfaces.io.pointcache import read_pc2, read_usd
from kdfaces.kd import simulate_kd
from kdfaces.shots.builtin import DEMO_SHOT
from kdfaces.shots.run import run_shot, run_summary

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "kdfaces" / "shots" / "demo.toml"
BENCH = ROOT / "benchmarks" / "bench_run_long.py"


@pytest.fixture(scope="module")
def demo():
    """The demo shot (KD and IKD) streamed in chunks of 7 frames (which do not divide its 151), kept whole too."""
    seen = []
    run = run_shot(DEMO_SHOT, chunk_frames=7, keep_states=True, sinks=[lambda lo, hi, x: seen.append((lo, hi, x))])
    return run, seen


def test_chunked_run_equals_one_batch_bit_for_bit(demo):
    run, seen = demo
    t, h = run.times, run.step_s
    one_kd = simulate_kd(run.system, run.shot.trajectory, t, run.window_s, step_s=h)
    one_ikd = simulate_kd(run.system, run.ikd_result.trajectory, t, run.window_s, step_s=h)
    assert np.array_equal(run.kd, one_kd)
    # IKD: float32 (what the caches and the bake store hold) to the bit, and float64 to the bit on every simulated
    # vertex; the rigid ones (teeth, eyes) are x_K + f evaluated in float64 by FaceSystem.observe in groups of
    # members, and a blend of other times skips other all-zero weight columns: the last bit may differ there
    assert np.array_equal(run.ikd.astype(np.float32), one_ikd.astype(np.float32))
    rigid = run.system.model.rigid_mask
    assert np.array_equal(run.ikd[:, ~rigid], one_ikd[:, ~rigid])
    assert np.abs(run.ikd[:, rigid] - one_ikd[:, rigid]).max() <= 4 * np.finfo(float).eps
    # x_K itself is a float64 blend whose skipped all-zero weight columns depend on which times are evaluated
    # together (BlendshapeRig.blend_offsets): to the last bit
    assert np.abs(run.kinematic - run.shot.trajectory.positions(t)).max() <= 4 * np.finfo(float).eps
    # the sinks got the final (IKD) trajectory, every frame once, in order, in chunks of 7
    assert [(lo, hi) for lo, hi, _ in seen] == [(lo, min(lo + 7, len(t))) for lo in range(0, len(t), 7)]
    assert np.array_equal(np.concatenate([x for _, _, x in seen]), run.ikd)
    # any frame range later, simulated again on its own, and the statistics of the whole arrays
    assert np.array_equal(run.states("final", 42, 49), run.ikd[42:49])  # the same chunk: the same bits
    assert np.array_equal(run.states("final", 40, 61).astype(np.float32), one_ikd[40:61].astype(np.float32))
    assert np.array_equal(run.states("kd", 150, 151), one_kd[150:])
    dev = np.linalg.norm(one_kd - run.kinematic, axis=-1)
    assert np.array_equal(run.deviation_m, dev.max(axis=0)) and np.array_equal(run.frame_deviation_m, dev.max(axis=1))
    ikd_dev = np.linalg.norm(run.ikd - run.kinematic, axis=-1)
    assert np.array_equal(run.ikd_deviation_m, ikd_dev.max(axis=0))
    s = run_summary(run, Path("."), [])
    assert s["kd"]["max_deviation_from_kinematic_m"] == float(dev.max()) > 1e-3


def test_a_run_that_keeps_nothing_gives_the_same_frames_on_demand(demo):
    kept, _ = demo
    run = run_shot(DEMO_SHOT, solve=False)  # default chunks (32), nothing kept
    assert run.kept == {} and run.ikd is None
    assert np.array_equal(run.deviation_m, kept.deviation_m)  # the solve does not touch the KD pass
    lo_hi = [(lo, hi) for lo, hi, _ in run.iter_states("kd", chunk_frames=50)]
    assert lo_hi == [(0, 50), (50, 100), (100, 150), (150, 151)]
    assert np.array_equal(run.final, kept.kd)  # computed on first use, then held
    assert run.final is run.kd


def _bytes(folder: Path, suffix: str) -> bytes:
    (f,) = folder.glob(f"*{suffix}")
    return f.read_bytes()


def test_run_and_bake_write_the_same_pc2_bytes(tmp_path):
    # with constraints: the bake ships the client's IKD correction to its workers
    shot = tmp_path / "demo.toml"
    shot.write_text(DEMO.read_text())
    run_out, bake_out = tmp_path / "run", tmp_path / "bake"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert kdfaces_main(["run", str(shot), "--out", str(run_out), "--export", "pc2", "--export", "usd"]) == 0
        assert kdfaces_main(["bake", str(shot), "--out", str(bake_out), "--workers", "1", "--chunk-frames", "20",
                             "--export", "pc2"]) == 0
    assert _bytes(run_out, ".pc2") == _bytes(bake_out, ".pc2")
    s = json.loads((run_out / "summary.json").read_text())
    assert sorted(s["outputs"]) == ["demo.pc2", "demo.usdc", "filmstrip.png", "ikd_convergence.png"]
    pc2, usd = read_pc2(run_out / "demo.pc2", fps=s["fps"]), read_usd(run_out / "demo.usdc")
    assert pc2.positions.shape == (s["frames"], s["rig"]["vertices"], 3)
    assert np.array_equal(usd.positions, pc2.positions)  # both float32 of the same streamed chunks


def _peak_bytes(shot: Path, **kwargs) -> tuple[int, int]:
    """(peak numpy memory of run_shot streaming ``shot`` into a sink [bytes], frames)."""
    sizes = []
    tracemalloc.start()
    try:
        run = run_shot(shot, solve=False, sinks=[lambda lo, hi, x: sizes.append(x.shape[0])], **kwargs)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert sum(sizes) == len(run.times)
    return peak, len(run.times)


def _take_writer():
    spec = importlib.util.spec_from_file_location("bench_run_long", BENCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.write_livelink_take


TAKE_SHOT = """name = "take"
[animation]
source = "{take}"
fps = 30
[dynamics]
window_s = 0.2
"""


def test_peak_memory_does_not_grow_with_the_take(tmp_path):
    # a generated Live Link Face take on the default head, 4 s and 16 s; numpy's allocations are traced (chunks,
    # the trajectory's samples, the face system's host copy of its trajectory bake); 0.2 s windows keep it fast
    write = _take_writer()
    peaks = {}
    for length_s in (4.0, 4.0, 16.0):  # the first run warms up what a process sets up once (Warp, the rig)
        shot = tmp_path / f"take{length_s:g}.toml"
        shot.write_text(TAKE_SHOT.format(take=write(tmp_path / f"take{length_s:g}.csv", length_s)))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            peaks[length_s] = _peak_bytes(shot, chunk_frames=16)
    (short, f_short), (long, f_long) = peaks[4.0], peaks[16.0]
    assert f_long == 4 * (f_short - 1) + 1
    held = (f_long - f_short) * 4774 * 3 * 8  # what holding the KD of the extra frames (float64) would add
    # the longer take peaks where the shorter one does (same chunks, same bounded caches; the take's own curves
    # grow, about 1 kB a frame): within 2 % of the short take's peak and 5 % of what holding its extra frames adds
    assert long - short <= min(0.02 * short, 0.05 * held), (short, long, held)
