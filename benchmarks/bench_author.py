"""Authoring latency (issue 26, paper §6.6): edit an IKD target and solve again, on the 27k-vertex production rig
(``scripts/build_production_rig.py --target-vertices 27000``, centimetres, no skeleton) with a keyed animation (the
jaw opens and closes, a smile, the brows rise and drop, each stopping sharply) and four constraints (a chin end
effector, a smile pose, the lips held, the brows' velocity).

Rows ``author_resolve`` (one per operation, ``size`` says which), all through
:class:`~kdfaces.shots.AuthoringSession` on two threads:

- ``move``: drag the chin target 1 mm (alternately up and down from a solved state, so every repeat is a new
  target) and solve, until the new KD state at the constraint's time is available (warm start, every lift
  factorisation, LU and secant model reused);
- ``add``: add a point constraint on a new vertex at the chin's time, 2 mm below its KD position, and solve
  (its lift's geodesic distances and factorisation included), then undo;
- ``cold``: today's cold solve of the four constraints (:func:`~kdfaces.ikd.solve_ikd` with a new surface:
  every factorisation, f = 0).

Targets: ``move`` ≤ 1.0 s, ``add`` ≤ 3 s (median, two cores). ``rate`` is the sweeps of the median repeat.
"""

from __future__ import annotations

import importlib.util
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHOT = """name = "author"
[rig]
source = "{rig}"
units = "cm"

[animation]
source = "keys"
end_s = 6.0
fps = 25
[[animation.tracks]]
shapes = ["jawOpen"]
times_s = [0.0, 0.6, 0.9, 2.0, 2.3]
values = [[0.0], [0.0], [0.8], [0.8], [0.0]]
interpolation = "linear"
[[animation.tracks]]
shapes = ["mouthSmileLeft", "mouthSmileRight"]
times_s = [0.0, 1.8, 2.3, 3.0, 3.3]
values = [[0.0, 0.0], [0.0, 0.0], [1.0, 1.0], [1.0, 1.0], [0.0, 0.0]]
interpolation = "linear"
[[animation.tracks]]
shapes = ["browInnerUp_L", "browInnerUp_R"]
times_s = [0.0, 4.5, 4.9, 5.3, 6.0]
values = [[0.0, 0.0], [0.0, 0.0], [1.0, 1.0], [0.2, 0.2], [0.0, 0.0]]
interpolation = "linear"

[dynamics]
settle_time_s = {{ stiff_s = 0.25, loose_s = 0.6 }}
damping_ratio = 0.3
window_s = "auto"
step_s = 0.04

[[constraints]]
time_s = 1.0
kind = "end_effector"
group = "jaw"
target = {{ offset_m = [0.0, -0.003, 0.0] }}
width_s = 0.25
falloff_m = 0.05
label = "chin"

[[constraints]]
time_s = 2.48
kind = "pose"
target = {{ weights = {{ mouthSmileLeft = 1.0, mouthSmileRight = 1.0 }} }}
width_s = 0.3
label = "smile"

[[constraints]]
time_s = 3.4
kind = "subset"
group = "lips"
width_s = 0.3
label = "lips"

[[constraints]]
time_s = 5.2
kind = "velocity"
group = "brows"
width_s = 0.25
label = "brows velocity"

[solver]
max_iterations = 10
"""


def _builder():
    spec = importlib.util.spec_from_file_location("build_production_rig", ROOT / "scripts" / "build_production_rig.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.build_production_rig


def author_session(folder: Path, target_vertices: int = 27_000):
    """An :class:`~kdfaces.shots.AuthoringSession` on the production rig built into ``folder``."""
    from kdfaces.shots import AuthoringSession

    _builder()(folder / "rig", target_vertices=target_vertices)
    shot = folder / "author.toml"
    shot.write_text(SHOT.format(rig=(folder / "rig").as_posix()))
    return AuthoringSession(shot)


def bench_author_resolve(repeats: int):
    from kdfaces.ikd.solver import solve_ikd
    from kdfaces.resources import single_threaded_blas

    repeats = max(int(repeats), 3)
    with tempfile.TemporaryDirectory() as tmp:
        s = author_session(Path(tmp))
        n = s.shot.rig.num_vertices
        t0 = time.perf_counter()
        first = s.solve()
        first_s = time.perf_counter() - t0
        assert first is not None and first.converged, s.status
        # cold: today's solve from scratch (new surface: every factorisation; f = 0)
        cold, cold_sweeps = [], []
        for _ in range(min(repeats, 2)):
            t0 = time.perf_counter()
            with single_threaded_blas():
                r = solve_ikd(s.system, s.trajectory, s.constraints(), window_s=s.window_s, step_s=s.step_s,
                              **s.options)
            cold.append(time.perf_counter() - t0)
            cold_sweeps.append(r.iterations)
        # move the chin target 1 mm and re-solve until the KD state at its time is there
        chin = 0
        home = s.handle(chin)
        move, move_sweeps, move_err = [], [], []
        for k in range(repeats):
            t0 = time.perf_counter()
            s.drag(chin, home + np.array([0.0, 0.001 if k % 2 == 0 else -0.001, 0.0]) * (1 + k // 2 * 1e-3))
            r = s.solve()
            s.state(s.rows[chin].time_s)
            move.append(time.perf_counter() - t0)
            assert r is not None, s.status
            move_sweeps.append(r.iterations)
            move_err.append(float(r.errors_after.max()))
        # add a point on a new vertex (its lift factorised in the solve), then undo
        x = s.state(1.0)
        jaw = s.vertices(chin)
        front = jaw[np.argsort(-x[jaw, 2])[: max(repeats, 3) * 7: 7]]
        add, add_sweeps = [], []
        for k in range(repeats):
            v = int(front[k % len(front)])
            t0 = time.perf_counter()
            o = s.add_point(1.0, v)
            s.drag(o.row, s.handle(o.row) + np.array([0.0, -0.002, 0.0]))
            r = s.solve()
            s.state(1.0)
            add.append(time.perf_counter() - t0)
            assert r is not None, s.status
            add_sweeps.append(r.iterations)
            s.undo()
            s.undo()
    size = f"{n / 1e3:.0f}k vertices, 4 constraints, 2 threads"
    rows = []
    for what, walls, sweeps in (("move", move, move_sweeps), ("add", add, add_sweeps), ("cold", cold, cold_sweeps)):
        med = statistics.median(walls)
        rows.append({"name": "author_resolve", "size": f"{what}: {size}", "median_s": med,
                     "rate": float(sweeps[int(np.argsort(walls)[len(walls) // 2])]), "unit": "sweeps"})
    rows[0]["size"] += f" (first solve {first_s:.1f} s, largest error after {max(move_err) * 1e3:.3f} mm/mm/s)"
    return rows


BENCHMARKS = [("author_resolve", bench_author_resolve)]


if __name__ == "__main__":
    for row in bench_author_resolve(3):
        print(row)
