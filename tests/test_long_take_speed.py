"""Long takes stream through simulate_kd chunk by chunk (issue 25): the face system's trajectory bake slides along
the take in one buffer (chunk k + 1's windows share rows with chunk k's, which are kept, not evaluated again), never
while a state still reads it, and the results are the same bits as one batch of every frame; the sample cache
computes only the derivative orders asked for, the same bits as when all are computed."""

from __future__ import annotations

import numpy as np
import pytest

from kdfaces import KinematicTrajectory
from kdfaces.dynamics import FaceModel, FaceSystem
from kdfaces.kd import simulate_kd, window_steps
from kdfaces.shots.builtin import demo_animation

SETTLE = dict(settle_time_s=0.3, damping_ratio=0.3)
WINDOW_S = 0.2
CHUNK = 8


@pytest.fixture(scope="module")
def setup(default_rig):
    a = demo_animation()
    anim = type(a)(tracks=a.tracks, skeleton=a.skeleton, start_s=0.0, end_s=2.0, fps=a.fps, name="demo-2s")
    return default_rig, anim, FaceModel.from_rig(default_rig, **SETTLE)


def _system(model, steps):
    system = FaceSystem(model, threads=1)
    # a bake of about two chunks' windows, as kdfaces run keeps: it restarts (slides) every other chunk or so
    system.max_bake_bytes = 2 * (CHUNK + steps + 1) * 48 * system.num_simulated
    return system


def test_streamed_chunks_slide_one_bake_and_match_one_batch(setup):
    rig, anim, model = setup
    traj = KinematicTrajectory(rig, anim)
    h = 1.0 / anim.fps
    steps = window_steps(WINDOW_S, h)
    times = traj.frame_times
    whole = simulate_kd(FaceSystem(model, threads=1), traj, times, WINDOW_S, step_s=h)
    system = _system(model, steps)
    parts, bakes, buffers, starts = [], set(), set(), set()
    for lo in range(0, len(times), CHUNK):
        parts.append(simulate_kd(system, traj, times[lo:lo + CHUNK], WINDOW_S, step_s=h))
        bakes.add(id(system._bake))
        buffers.add(id(system._bake._x))
        starts.add(system._bake.j_lo)
    np.testing.assert_array_equal(np.concatenate(parts), whole)  # bit for bit
    assert len(bakes) == 1 and len(buffers) == 1  # one bake, never reallocated...
    assert len(starts) > 2  # ...that slid along the take
    assert system._bake.nbytes <= 2 * system.max_bake_bytes  # host and device copies of the budget's rows


def test_a_bake_a_live_state_reads_does_not_slide(setup):
    rig, anim, model = setup
    traj = KinematicTrajectory(rig, anim)
    h = 1.0 / anim.fps
    steps = window_steps(WINDOW_S, h)
    times = traj.frame_times
    system = _system(model, steps)
    simulate_kd(system, traj, times[:CHUNK], WINDOW_S, step_s=h)
    held = system.initial_state(traj, times[:1] - WINDOW_S)  # reads the current bake
    bake = held.bake
    if bake is None:  # not prepared: it bakes at its first step
        system.step(held, traj, times[:1] - WINDOW_S, h)
        bake = held.bake
    simulate_kd(system, traj, times[CHUNK:2 * CHUNK], WINDOW_S, step_s=h)  # the same bake, grown
    assert system._bake is bake
    rows = (bake.j_lo, bake.xk_np.copy())
    later = slice(2 * CHUNK, 3 * CHUNK)  # its windows share rows with the bake, whose span would pass the budget
    x = simulate_kd(system, traj, times[later], WINDOW_S, step_s=h)
    assert system._bake is not bake  # a new bake: the held state's rows stay where they are
    assert bake.j_lo == rows[0]
    np.testing.assert_array_equal(bake.xk_np[:len(rows[1])], rows[1])
    np.testing.assert_array_equal(x, simulate_kd(FaceSystem(model, threads=1), traj, times[later], WINDOW_S,
                                                 step_s=h))
    del held


def test_the_sample_cache_computes_the_orders_asked_for_with_the_same_bits(setup):
    rig, anim, _ = setup
    t = np.linspace(0.1, 1.7, 23)
    ref = KinematicTrajectory(rig, anim).evaluate(t, 2)
    traj = KinematicTrajectory(rig, anim)
    calls = []
    chunk = traj._evaluate_chunk
    traj._evaluate_chunk = lambda tt, order=2, rows=None: calls.append(order) or chunk(tt, order, rows)
    x0 = traj.evaluate(t, 0)
    assert len(x0) == 1 and set(calls) == {0}
    x1 = traj.evaluate(t[::-1], 1)  # a sample cached with order 0 only is computed again for order 1
    assert set(calls) == {0, 1}
    n = len(calls)
    x2 = traj.evaluate(t, 2)
    assert len(calls) > n and calls[-1] == 2
    again = traj.evaluate(t[5:9], 1)  # cached with every order: no call
    assert len(calls) == n + -(-len(t) // traj.chunk)
    np.testing.assert_array_equal(x0[0], ref[0])
    for o in range(2):
        np.testing.assert_array_equal(x1[o], ref[o][::-1])
        np.testing.assert_array_equal(again[o], ref[o][5:9])
    for o in range(3):
        np.testing.assert_array_equal(x2[o], ref[o])


class _RegionOrder(FaceSystem):
    """A FaceSystem that keeps the region's vertex order in memory (a subclass overriding observe does)."""

    def observe(self, state):
        return FaceSystem.observe(self, state)


@pytest.mark.parametrize("threads, kernels", [(1, "fused"), (2, "fused"), (1, "parallel")])
def test_the_locality_order_gives_the_same_bits(setup, threads, kernels):
    """The state and the bake in a bandwidth-reducing order (clusters' members close in memory) compute the same
    arithmetic in the same sequence as the region's order: the same KD states bit for bit, for a batch and for a
    single state split by vertices between two threads, on both kernel paths; the bake reads back in region order."""
    rig, anim, model = setup
    traj = KinematicTrajectory(rig, anim)
    h = 1.0 / anim.fps
    ordered = FaceSystem(model, threads=threads, kernels=kernels)
    plain = _RegionOrder(model, threads=threads, kernels=kernels)
    assert plain._order is None and ordered._order is not None
    order = ordered._order
    assert sorted(order.tolist()) == list(range(model.num_simulated)) and (order != np.arange(len(order))).any()
    c0, c1 = plain._clusters, ordered._clusters  # the clusters' members lie closer together in memory
    span = [np.median([np.ptp(c.members[a:b]) for a, b in zip(c.offsets[:-1], c.offsets[1:]) if b > a])
            for c in (c0, c1)]
    assert span[1] < span[0]
    times = traj.frame_times[5:25]
    for t in (times, times[7:8]):
        a = simulate_kd(ordered, traj, t, WINDOW_S, step_s=h)
        b = simulate_kd(plain, traj, t, WINDOW_S, step_s=h)
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ordered._bake.xk_np, plain._bake.xk_np)
    np.testing.assert_array_equal(ordered._bake.vk_np, plain._bake.vk_np)
    ordered.close()
    plain.close()
