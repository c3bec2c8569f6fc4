"""The skeletal KD scenes (issue 16): ``kdfaces punch`` (the relaxed punch and its IKD, On the Beat's timing claim)
and ``kdfem follow`` (a head that follows through a sharp turn; the face and the hat ride on it)."""

from __future__ import annotations

import json

import pytest


@pytest.fixture(scope="module")
def punch(tmp_path_factory):
    from kdfaces.articulated.punch import run_punch

    out = tmp_path_factory.mktemp("punch")
    return run_punch(out, movie=False, exports=("pc2", "usd")), out


def test_punch_summary_keys_and_ikd(punch):
    s, out = punch
    assert set(s["skeleton"]) >= {"engine", "joints", "dofs"} and s["skeleton"]["engine"] == "mujoco"
    assert s["skeleton"]["joints"] == ["clavicle", "upperarm", "forearm", "hand"] and s["skeleton"]["dofs"] == 12
    assert set(s["kd"]) >= {"window_s", "ms_per_state"} and s["kd"]["window_s"] == 0.3
    ikd = s["ikd"]
    assert set(ikd) >= {"converged", "iterations", "error_after_6_m", "error_after_m", "wall_s"}
    assert s["kd"]["miss_before_ikd_m"] > 0.05  # relaxed: the KD fist misses by centimetres
    assert ikd["converged"] and ikd["iterations"] < 50
    assert ikd["error_after_6_m"] <= 1e-4  # the paper's §6.3: under 0.1 mm after 6 iterations
    assert ikd["velocity"]["converged"] and ikd["velocity"]["error_after_mps"] <= 1e-3
    assert json.loads((out / "summary.json").read_text())["ikd"]["iterations"] == ikd["iterations"]
    for name in ("filmstrip_punch.png", "convergence.png", "timing.png"):
        assert (out / name).stat().st_size > 10_000


def test_punch_exports_its_kd_and_ikd_points(punch):
    """``kdfaces punch --export pc2 --export usd``: the arm's simulated points at every frame (100 fps), KD and
    IKD, frame k at scene frame FRAME_START + k; USD holds them as UsdGeom.Points, the same float32 values."""
    import numpy as np

    from kdfaces.cli import build_parser
    from kdfaces.defaults import FRAME_START
    from kdfaces.io import read_pc2, read_usd

    s, out = punch
    assert {"punch_kd.pc2", "punch_ikd.pc2", "punch_kd.usdc", "punch_ikd.usdc"} <= set(s["outputs"])
    kd, ikd = (read_pc2(out / f"punch_{k}.pc2", fps=s["fps"]) for k in ("kd", "ikd"))
    usd = read_usd(out / "punch_ikd.usdc")
    assert s["fps"] == 100.0 and kd.positions.shape[0] == s["frames"] == s["kd"]["batch"]
    assert np.array_equal(usd.positions, ikd.positions) and usd.faces is None and usd.frame_start == FRAME_START
    np.testing.assert_allclose(usd.times, np.arange(s["frames"]) / 100.0, rtol=0, atol=1e-9)
    # the IKD edit moves the fist by about the KD miss (centimetres): two different trajectories
    assert np.abs(ikd.positions - kd.positions).max() > 0.5 * s["kd"]["miss_before_ikd_m"]
    assert build_parser().parse_args(["punch", "--export", "pc2"]).export == ["pc2"]


def test_composite_gains_keep_time_better_than_local_gains(punch):
    """On the Beat Fig. 8 by the paper's own definition of reaching a keyframe (§4.1: each hinge has removed 90 % of
    its error at t̂), over every hinge each of the twelve conductor keyframes animates (9 hinges: the clavicle is not
    animated): composite-inertia gains keep time better than local ones, and neither does better than decoupled
    critically damped joints started from the same states (the error eq. 4 makes by itself on a chained sequence).

    The issue's "5× smaller" is not asserted: this metric gives 2.0× (162 ms against 322 ms) on this arm, see
    :func:`kdfaces.articulated.punch.timing_experiment` and the README."""
    s, _ = punch
    t = s["timing"]
    err = t["keyframe_time_error_s"]
    assert set(err) == {"composite", "local", "decoupled"} and t["counted"] == 12 * 9
    assert err["local"] > err["composite"] > err["decoupled"] > 0, t
    assert t["ratio_local_over_composite"] == err["local"] / err["composite"]


def test_the_decoupled_reference_reaches_ninety_percent_at_the_settle_time():
    """The timing metric's closed form: a critically damped joint from rest (n of ``timing="critical"``) has
    removed 90 % of its error exactly at t̂; starting towards the target it is early, away from it late."""
    import numpy as np

    from kdfaces.articulated import time_constants
    from kdfaces.articulated.punch import _critical_error, _time_to_fraction

    t_hat, h = 0.3, 1e-5
    times = h * (np.arange(int(1.0 / h)) + 1)
    e0 = np.array([0.4, -0.2, 0.4, 0.4])
    rate0 = np.array([0.0, 0.0, -1.0, 1.0])  # ė(0) = −θ̇(0): moving towards the target, then away from it
    t90 = _time_to_fraction(_critical_error(e0, rate0, t_hat / time_constants(0.9, "critical"), times), e0, times, 0.9)
    assert np.abs(t90[:2] - t_hat).max() <= h
    assert t90[2] < t_hat - 0.01 and t90[3] > t_hat + 0.01


def test_the_kd_head_follows_through_and_settles(tmp_path):
    from kdfem.scenes.follow import run_follow

    s = run_follow(tmp_path)
    f = s["follow_through"]
    assert f["overshoot_deg"] >= 2.0
    assert f["full_sim_residual_at_stop_plus_window_deg"] <= 0.5  # settled within the window
    assert f["kd_vs_full_max_m"] <= 0.005
    assert (tmp_path / "filmstrip_follow.png").stat().st_size > 10_000
