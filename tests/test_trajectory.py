"""Kinematic trajectories: LBS identity at rest, exact derivatives, rigid head motion, demo shot, bad input."""

import numpy as np
import pytest

from kdfaces import FaceAnimation, JointDrive, KDInputError, KeyframeCurve, KinematicTrajectory, ShapeTrack
from kdfaces.motion.joints import SkeletonAnimation
from kdfaces.rig.skeleton import joint_transforms
from kdfaces.shots.builtin import demo_animation


def head_turn(shares=None):
    c = KeyframeCurve.create([0.0, 0.4, 1.0], [[0, 0, 0], [0.5, -0.2, 0.1], [0.1, 0.3, 0.0]])
    return SkeletonAnimation((JointDrive(c) if shares is None else JointDrive(c, shares),))


def test_lbs_is_identity_at_rest_pose(default_rig):
    anim = FaceAnimation(skeleton=SkeletonAnimation((JointDrive(KeyframeCurve.create([0, 1], np.zeros((2, 3)))),)))
    x, v, a = KinematicTrajectory(default_rig, anim).evaluate([0.0, 0.5])
    np.testing.assert_allclose(x, np.broadcast_to(default_rig.neutral, x.shape), atol=1e-15)
    assert not v.any() and not a.any()


def test_trajectory_derivatives_match_finite_differences(default_rig):
    smile = ShapeTrack(("mouthSmileLeft", "jawOpen"), KeyframeCurve.create([0, 0.5, 1.0], [[0, 0], [1, 0.6], [0.2, 0]]))
    traj = KinematicTrajectory(default_rig, FaceAnimation(tracks=(smile,), skeleton=head_turn()))
    t = np.array([0.17, 0.33, 0.71])
    e = 1e-5
    x, v, a = traj.evaluate(t)
    xp, vp, _ = traj.evaluate(t + e)
    xm, vm, _ = traj.evaluate(t - e)
    # central differences: truncation O(e²·|x'''|) ~ 1e-10 m/s, round-off ~1e-16·|x|/e ~ 1e-11 m/s
    np.testing.assert_allclose(v, (xp - xm) / (2 * e), atol=1e-8)
    np.testing.assert_allclose(a, (vp - vm) / (2 * e), atol=1e-6)
    assert np.abs(v).max() > 0.05  # the head really moves


def test_head_only_rotation_is_rigid_for_fully_head_weighted_vertices(default_rig):
    skel = default_rig.skeleton
    traj = KinematicTrajectory(default_rig, FaceAnimation(skeleton=head_turn({"head": 1.0})))
    x = traj.positions([0.4])[0]
    full = np.flatnonzero(skel.weights[:, skel.index("head")] + skel.weights[:, skel.index("jaw")] > 1 - 1e-6)
    assert len(full) > 1000
    sel = full[:: max(1, len(full) // 300)]
    d0 = np.linalg.norm(default_rig.neutral[sel, None] - default_rig.neutral[None, sel], axis=-1)
    d1 = np.linalg.norm(x[sel, None] - x[None, sel], axis=-1)
    np.testing.assert_allclose(d1, d0, atol=1e-12)
    # the head pivot does not move under a head-only rotation
    G = joint_transforms(skel, SkeletonAnimation((head_turn({"head": 1.0}).drives[0],)).joint_angles(skel, [0.4]))[0]
    p = skel.positions[skel.index("head")]
    np.testing.assert_allclose(G[0, skel.index("head"), :3, :3] @ p + G[0, skel.index("head"), :3, 3], p, atol=1e-14)


def test_demo_shot_has_expressions_and_sharp_head_motion(default_rig):
    anim = demo_animation()
    assert anim.fps == 25 and abs(anim.duration - 6.0) < 1e-12 and len(anim.frame_times) == 151
    traj = KinematicTrajectory(default_rig, anim)
    x, v, a = traj.evaluate(anim.frame_times)
    assert np.isfinite(x).all() and np.isfinite(a).all()
    assert np.linalg.norm(a, axis=-1).max() > 5.0  # m/s²: sharp starts and stops
    w = traj.weights(anim.frame_times, 0)[0]
    for name in ("jawOpen", "mouthSmileLeft", "browInnerUp", "eyeBlinkLeft"):
        assert w[:, default_rig.shape_names.index(name)].max() > 0.6


def test_unknown_shape_in_animation(default_rig):
    bad = ShapeTrack(("smileLeft",), KeyframeCurve.create([0, 1], [0, 1]))
    with pytest.raises(KDInputError, match="animation 'animation': unknown shape name 'smileLeft'"):
        KinematicTrajectory(default_rig, FaceAnimation(tracks=(bad,)))


def test_unknown_joint(default_rig):
    anim = FaceAnimation(skeleton=head_turn({"skull": 1.0}))
    with pytest.raises(KDInputError, match="unknown joint 'skull'"):
        KinematicTrajectory(default_rig, anim).evaluate([0.1])


def test_sample_cache_returns_the_same_values(default_rig):
    anim = demo_animation()
    cached = KinematicTrajectory(default_rig, anim)
    tiny = KinematicTrajectory(default_rig, anim, cache_bytes=1)  # holds one sample: evaluates directly
    t = np.array([0.6, 0.64, 0.6, 5.0])
    first = cached.evaluate(t)
    again = cached.evaluate(t[::-1])
    for a, b, c in zip(first, again, tiny.evaluate(t)):
        np.testing.assert_array_equal(a, b[::-1])
        np.testing.assert_allclose(a, c, rtol=1e-13, atol=1e-15)  # BLAS blocking differs with the batch


def test_one_off_passes_leave_the_sample_cache_alone(default_rig):
    # the window estimate scans the whole shot: it may not fill the trajectory's sample cache (on a 19k-vertex rig
    # that was 256 MiB of samples nobody read again)
    from kdfaces.dynamics import FaceModel, FaceSystem
    from kdfaces.window import automatic_window

    traj = KinematicTrajectory(default_rig, demo_animation())
    automatic_window(FaceSystem(FaceModel.from_rig(default_rig)), traj)
    assert len(traj._cache) == 0
    t = traj.frame_times[:5]
    for a, b in zip(traj.scan(t), traj.evaluate(t)):  # the scan is the same evaluation
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-15)
    assert len(traj._cache) == 5


def test_a_scan_of_a_corrected_trajectory_keeps_the_correction(default_rig):
    # CorrectedTrajectory forwards unknown attributes to its base; a scan must not fall through to the base's and
    # silently drop f (IKD then never moves)
    from kdfaces.ikd import CorrectedTrajectory, Correction, Slot, make_basis
    from kdfaces.motion import scan_trajectory

    traj = KinematicTrajectory(default_rig, demo_animation())
    corr = Correction([Slot(2.0, "position", make_basis("gaussian", 2.0, width_s=0.3))], traj.state_shape)
    corr.values[0] = 0.01
    corr.update()
    fixed = CorrectedTrajectory(traj, corr)
    t = np.array([1.9, 2.0, 2.1])
    for a, b in zip(scan_trajectory(fixed, t, 1), fixed.evaluate(t, 1)):
        np.testing.assert_array_equal(a, b)
    assert np.abs(scan_trajectory(fixed, t, 0)[0] - traj.evaluate(t, 0)[0]).max() > 0.005


def test_scans_of_lower_orders_skip_the_derivatives_but_not_a_bit_of_the_rest(default_rig):
    # positions alone (FaceSystem.observe's rigid parts) and positions + velocities (bakes, adaptive windows) come
    # from the same arithmetic as the full evaluation: bit for bit, with the head skinned
    smile = ShapeTrack(("mouthSmileLeft",), KeyframeCurve.create([0, 0.5, 1.0], [[0], [1], [0.2]]))
    traj = KinematicTrajectory(default_rig, FaceAnimation(tracks=(smile,), skeleton=head_turn()))
    t = np.array([0.13, 0.5, 0.77])
    full = traj.scan(t, 2)
    for order in (0, 1):
        part = traj.scan(t, order)
        assert len(part) == order + 1
        for a, b in zip(part, full):
            np.testing.assert_array_equal(a, b)
