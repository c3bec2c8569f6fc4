"""A long take through ``kdfaces run``: a 2-minute, 30 Hz Live Link Face take on the 27k-vertex production rig
(``scripts/build_production_rig.py --target-vertices 27000``, centimetres, no skeleton), exported as PC2, in a fresh
child process whose wall time and peak resident memory (``ru_maxrss`` of that child, from ``os.wait4``) are the row.
The same shot then goes through ``kdfaces bake --workers 2 --export pc2`` and the two PC2 files must be the same
bytes (no row otherwise).

The take is generated (:func:`write_livelink_take`): 52 ARKit channels of smooth, seeded motion with expression
onsets and stops every few seconds, and small head angles (which the skeleton-less rig ignores), so the benchmark
needs no capture file. Row ``run_long_take``: ``median_s`` the whole command (interpreter start included),
``rate`` its peak RSS in GiB; the size names frames, window and the per-KD-state time.
"""

from __future__ import annotations

import filecmp
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHOT = """name = "long"
[rig]
source = "{rig}"
units = "cm"
[animation]
source = "{take}"
fps = 30
[dynamics]
settle_time_s = {{ stiff_s = 0.2, loose_s = 0.45 }}
damping_ratio = 0.3
"""
DURATION_S = 120.0


def write_livelink_take(path, duration_s: float, fps: int = 30, *, seed: int = 0) -> Path:
    """Write a Live Link Face CSV of ``duration_s`` seconds at ``fps`` (timecodes ``HH:MM:SS:FF.000`` counted at
    ``fps``): 52 ARKit weights in [0, 1], each a sum of two slow sines gated by expression bursts that switch on
    and off sharply (so the soft tissue overshoots), and yaw/pitch/roll of a few degrees [rad]."""
    from kdfaces.rig.names import ARKIT_NAMES

    rng = np.random.default_rng(seed)
    n = int(round(duration_s * fps)) + 1
    t = np.arange(n) / fps
    freq = rng.uniform(0.1, 0.8, (2, len(ARKIT_NAMES)))
    phase = rng.uniform(0, 2 * np.pi, (2, len(ARKIT_NAMES)))
    base = 0.5 + 0.25 * (np.sin(2 * np.pi * freq[0] * t[:, None] + phase[0])
                         + np.sin(2 * np.pi * freq[1] * t[:, None] + phase[1]))
    period = rng.uniform(2.0, 5.0, len(ARKIT_NAMES))
    gate = (np.floor(t[:, None] / period + rng.uniform(0, 1, len(ARKIT_NAMES))) % 2).astype(float)
    w = np.clip(base * gate, 0.0, 1.0)
    head = 0.05 * np.sin(2 * np.pi * np.array([0.13, 0.21, 0.17]) * t[:, None])
    names = [n[0].upper() + n[1:] for n in ARKIT_NAMES]
    lines = [",".join(["Timecode", "BlendShapeCount", *names, "HeadYaw", "HeadPitch", "HeadRoll"])]
    start = 10 * 3600.0  # 10:00:00:00
    for i in range(n):
        s, ff = divmod(i, fps)
        total = int(start) + s
        code = f"{total // 3600:02d}:{total // 60 % 60:02d}:{total % 60:02d}:{ff:02d}.000"
        lines.append(",".join([code, str(len(names))] + [f"{x:.6f}" for x in w[i]] + [f"{x:.6f}" for x in head[i]]))
    p = Path(path)
    p.write_text("\n".join(lines) + "\n")
    return p


def _builder():
    spec = importlib.util.spec_from_file_location("build_production_rig", ROOT / "scripts" / "build_production_rig.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.build_production_rig


def measure_command(argv: list[str], env: dict) -> dict:
    """Run ``python -m kdfaces.cli ARGV`` as a child: exit status, wall time [s], the child's peak RSS [bytes]."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c",
                                 "import sys; from kdfaces.cli import main; sys.exit(main())", *argv],
                                stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)  # this child's own rusage (ru_maxrss: its peak RSS)
        wall = time.perf_counter() - t0
        proc.returncode = code = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read().decode(), err.read().decode()
    if code != 0:
        raise RuntimeError(f"{' '.join(argv[:2])}: exit {code}: {stderr[-1500:]}")
    return {"wall_s": wall, "peak_bytes": usage.ru_maxrss * 1024, "stdout": stdout}


def bench_run_long_take(repeats: int, *, duration_s: float = DURATION_S, target_vertices: int | None = 27_000,
                        bake: bool = True):
    """The ``run_long_take`` row (see the module docstring)."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        info = _builder()(tmp / "rig", target_vertices=target_vertices)
        take = write_livelink_take(tmp / "take.csv", duration_s)
        shot = tmp / "long.toml"
        shot.write_text(SHOT.format(rig=tmp / "rig", take=take))
        env = {**os.environ, "KDFACES_CACHE": str(tmp / "cache"), "KDFACES_PROGRESS_DELAY_S": "1000",
               "PYTHONWARNINGS": "ignore"}
        # parse the rig into the cache once, so each measured run reads it as a studio's second run would
        subprocess.run([sys.executable, "-c", "import sys; from kdfaces.shots.shotfile import load_shot; "
                        "from kdfaces.defaults import user_cache_dir; load_shot(sys.argv[1], "
                        "cache_dir=user_cache_dir())", str(shot)], env=env, check=True, capture_output=True)
        runs = []
        for k in range(max(1, min(repeats, 2))):  # each run takes a minute or more; the peak hardly varies
            out = tmp / f"run{k}"
            runs.append(measure_command(["run", str(shot), "--out", str(out), "--export", "pc2", "--json"], env))
            runs[-1]["summary"] = json.loads((out / "summary.json").read_text())
        s = runs[0]["summary"]
        equal = None
        if bake:
            b = measure_command(["bake", str(shot), "--out", str(tmp / "bake"), "--workers", "2", "--export", "pc2"],
                                env)
            equal = filecmp.cmp(tmp / "run0" / "long.pc2", tmp / "bake" / "long.pc2", shallow=False)
            if not equal:
                raise RuntimeError("run_long_take: kdfaces run and kdfaces bake wrote different PC2 files")
    walls = sorted(r["wall_s"] for r in runs)
    peak = max(r["peak_bytes"] for r in runs)
    size = (f"{info['vertices'] / 1e3:.1f}k vertices, {s['frames']} frames ({duration_s:g} s at 30 Hz), "
            f"δ = {s['kd']['window_s']:.3f} s, {s['kd']['ms_per_state']:.1f} ms/KD state"
            + (f", PC2 = bake's (bake {b['wall_s']:.0f} s)" if equal else "") + f", {_load()}")
    return [{"name": "run_long_take", "size": size, "median_s": walls[len(walls) // 2], "rate": peak / 2**30,
             "unit": "GiB peak RSS (kdfaces run process)"}]


def _load() -> str:
    try:
        return f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    except OSError:
        return ""


def main() -> None:  # python benchmarks/bench_run_long.py [SECONDS [VERTICES]]: one measurement, printed
    duration = float(sys.argv[1]) if len(sys.argv) > 1 else DURATION_S
    target = int(sys.argv[2]) if len(sys.argv) > 2 else 27_000
    print(json.dumps(bench_run_long_take(1, duration_s=duration, target_vertices=target), indent=1))


BENCHMARKS = [("run_long_take", bench_run_long_take)]

if __name__ == "__main__":
    main()
