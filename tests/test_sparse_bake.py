"""A bake of a few windows far apart (issue 26: IKD re-bakes x_K + f at every sweep, for a handful of constraint
windows spread over the shot) evaluates only the rows the windows read, each window start its own rows on the
shared grid (``TrajectoryBake.member_grid``), and the kernels read the same x_K bits as from the dense bake of the
whole span j_lo..j_hi: the same grid times origin + j·h, evaluated the same way.

The trajectory is x_K + f of the default head and the demo (a correction with slots at the constraint times, as IKD
has), its base counting every time it evaluates.
"""

from __future__ import annotations

import numpy as np
import pytest

from kdfaces import KinematicTrajectory
from kdfaces.dynamics import FaceModel, FaceSystem
from kdfaces.dynamics.system import TrajectoryBake
from kdfaces.ikd import CorrectedTrajectory, Correction, GaussianBasis, Slot
from kdfaces.kd import simulate_kd, window_steps
from kdfaces.shots.builtin import demo_animation

SETTLE = dict(settle_time_s=0.3, damping_ratio=0.3)
WINDOW_S = 0.2
FRAMES = [8, 30, 55]  # three constraint frames far apart: 3·(steps + 1) rows against a span of ~53


class CountingTrajectory(KinematicTrajectory):
    """A kinematic trajectory that records the times of every evaluation it does."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.evaluated: list[np.ndarray] = []

    def _evaluate_chunk(self, t, order=2, rows=None):
        self.evaluated.append(np.array(t, dtype=np.float64))
        return super()._evaluate_chunk(t, order, rows)


@pytest.fixture(scope="module")
def short_demo():
    a = demo_animation()
    return type(a)(tracks=a.tracks, skeleton=a.skeleton, start_s=0.0, end_s=2.4, fps=a.fps, name="demo-2.4s")


@pytest.fixture(scope="module")
def model(default_rig):
    return FaceModel.from_rig(default_rig, **SETTLE)


@pytest.fixture(scope="module")
def correction(default_rig, short_demo):
    """f with a position slot at each constraint frame and a velocity slot at the middle one, random values [m]."""
    times = [float(t) for t in KinematicTrajectory(default_rig, short_demo).frame_times[FRAMES]]
    slots = [Slot(s, "position", GaussianBasis(s, 0.15)) for s in times]
    slots.append(Slot(times[1], "velocity", GaussianBasis(times[1], 0.15)))
    corr = Correction(slots, (default_rig.num_vertices, 3))
    corr.values[:] = 1e-3 * np.random.default_rng(26).standard_normal(corr.values.shape)
    corr.update()
    return corr


def corrected(rig, anim, corr):
    return CorrectedTrajectory(CountingTrajectory(rig, anim), corr)


def test_a_sparse_prepare_evaluates_the_windows_rows_only_with_the_dense_bakes_bits(default_rig, short_demo, model,
                                                                                     correction):
    traj = corrected(default_rig, short_demo, correction)
    h = 1.0 / short_demo.fps
    steps = window_steps(WINDOW_S, h)
    t0 = traj.frame_times[FRAMES]
    system = FaceSystem(model, threads=1)
    system.prepare(traj, t0, steps, h)
    state = system.initial_state(traj, t0)
    bake, rows = state.bake, state.rows
    assert bake.member_grid is not None and bake.stride == len(FRAMES)
    assert bake.num_rows == len(FRAMES) * (steps + 1)
    # the base evaluated each window's grid times once, and nothing between the windows
    origin = TrajectoryBake.grid_origin(traj, t0, h)
    j = TrajectoryBake.grid_index(traj, t0, h, origin)
    grid = origin + (j[:, None] + np.arange(steps + 1)) * h  # the shared grid's arithmetic
    done = np.concatenate(traj.base.evaluated)
    np.testing.assert_array_equal(np.sort(done), np.sort(grid.ravel()))
    # member b at step k reads rows[b] + k·stride: its own grid time, the very float64 the dense bake has there
    k = np.arange(steps + 1)
    read = rows[:, None] + k * bake.stride
    np.testing.assert_array_equal(bake.times(read), grid)
    # the dense bake of the span, on a fresh trajectory (its own sample cache): the same x_K and ẋ_K bits
    fresh = corrected(default_rig, short_demo, correction)
    dense = TrajectoryBake(fresh, h, "cpu", j_lo=int(j.min()), origin=origin, vertices=model.region)
    dense.ensure(np.zeros(1, np.int32), int(j.max() - j.min()) + steps)
    assert len(np.concatenate(fresh.base.evaluated)) == dense.num_rows > 2 * bake.num_rows
    at = j[:, None] - j.min() + k
    np.testing.assert_array_equal(bake.xk_np[read], dense.xk_np[at])
    np.testing.assert_array_equal(bake.vk_np[read], dense.vk_np[at])


def test_sparse_windows_give_the_dense_batchs_kd_states_bit_for_bit(default_rig, short_demo, model, correction):
    traj = corrected(default_rig, short_demo, correction)
    t = traj.frame_times
    sparse_system = FaceSystem(model, threads=2)
    x = simulate_kd(sparse_system, traj, t[FRAMES], WINDOW_S)
    assert sparse_system._sparse is not None and sparse_system._bake is None
    # every frame from the first to the last in one batch: a dense shared bake (too many windows for own rows)
    dense_system = FaceSystem(model, threads=2)
    span = np.arange(FRAMES[0], FRAMES[-1] + 1)
    xd = simulate_kd(dense_system, corrected(default_rig, short_demo, correction), t[span], WINDOW_S)
    assert dense_system._bake is not None and dense_system._bake.member_grid is None
    np.testing.assert_array_equal(x, xd[np.asarray(FRAMES) - FRAMES[0]])


def test_a_sparse_bake_is_reused_for_the_same_content_and_rebuilt_for_a_new_f(default_rig, short_demo, model,
                                                                               correction):
    corr = correction.copy()
    traj = corrected(default_rig, short_demo, corr)
    h = 1.0 / short_demo.fps
    steps = window_steps(WINDOW_S, h)
    t0 = traj.frame_times[FRAMES]
    system = FaceSystem(model, threads=1)
    system.prepare(traj, t0, steps, h)
    first = system._sparse
    calls = len(traj.base.evaluated)
    system.prepare(traj, t0[[0, 2]], steps, h)  # a subset of the starts, same content: nothing evaluated
    state = system.initial_state(traj, t0[[0, 2]])
    assert state.bake is first and len(traj.base.evaluated) == calls
    np.testing.assert_array_equal(state.rows, [0, 2])
    corr.values *= 0.5  # a new f (IKD's next sweep): a new bake of the windows' rows
    corr.update()
    system.prepare(traj, t0, steps, h)
    assert system._sparse is not first and system._sparse.version == traj.version


def test_unprepared_sparse_windows_bake_as_they_step_and_match_the_prepared_run(default_rig, short_demo, model,
                                                                                  correction):
    # the protocol without prepare: the bake is made at the first step (no step count known) and grows per step
    traj = corrected(default_rig, short_demo, correction)
    h = 1.0 / short_demo.fps
    steps = window_steps(WINDOW_S, h)
    times = traj.frame_times[FRAMES]
    t0 = times - steps * h  # the windows ending at the frames, as simulate_kd starts them
    system = FaceSystem(model, threads=1)
    state = system.initial_state(traj, t0)
    for k in range(steps):
        system.step(state, traj, t0 + k * h, h)
    assert state.bake.member_grid is not None and state.bake.num_rows == len(FRAMES) * (steps + 1)
    prepared = simulate_kd(FaceSystem(model, threads=1), corrected(default_rig, short_demo, correction), times,
                           WINDOW_S)
    np.testing.assert_array_equal(system.observe(state), prepared)
