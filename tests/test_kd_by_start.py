"""kdfem.scenes.braid.kd_states_by_start: KD states of windows that share a start, one simulation per start.

On the linear PD particles of tests/ikd_systems.py (numpy, implicit Euler): the states equal simulate_kd's, window
by window, to float64 round-off. The only difference between the two computations is the step grid's times
(start + k·h against t − (n − k)·h, a few ulps of t), which x_K(t) turns into ~1e-16 m differences; 1e-12 m bounds
that with room while a wrong start or step count moves the states by millimetres (checked below).
"""

import numpy as np
import pytest
from ikd_systems import LinearPDSystem, PointTrajectory

from kdfaces.errors import KDInputError
from kdfaces.kd import simulate_kd
from kdfaces.motion.curves import KeyframeCurve
from kdfem.scenes.braid import kd_states_by_start

H = 0.01


def _scene():
    t = np.linspace(0.0, 2.0, 9)
    vals = np.stack([0.02 * np.sin(3 * t), 0.01 * np.cos(5 * t), 0.005 * t], axis=1)
    traj = PointTrajectory(np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]), KeyframeCurve.create(t, vals,
                                                                                             interpolation="catmull-rom"))
    return LinearPDSystem([6.0, 9.0], [0.1, 0.2], edges=[[0, 1]], coupling=20.0), traj


def test_shared_starts_equal_simulate_kd_window_by_window():
    system, traj = _scene()
    times = np.round(np.arange(0, 51) * 0.04, 12)
    windows = np.where(times > 0.3, times - 0.3, 0.0)  # every frame after 0.3 s starts at 0.3 s: one simulation
    windows[-5:] = 0.5  # and a few windows of their own
    windows[3] = 0.0
    x = kd_states_by_start(system, traj, times, windows, step_s=H)
    ref = np.stack([simulate_kd(system, traj, times[i:i + 1], windows[i:i + 1], step_s=H)[0]
                    for i in range(len(times))])
    assert np.abs(x - ref).max() <= 1e-12
    assert np.abs(x - traj.positions(times)).max() > 1e-4  # the dynamics are there (else this could not fail)
    moved = kd_states_by_start(system, traj, times, np.where(windows > 0, windows + H, 0.0), step_s=H)
    assert np.abs(moved - ref).max() > 1e-6  # one step more in each window: visibly other states


def test_one_window_per_time():
    system, traj = _scene()
    with pytest.raises(KDInputError, match="one window per time"):
        kd_states_by_start(system, traj, [0.1, 0.2], [0.1], step_s=H)
