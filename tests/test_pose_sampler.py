"""The dense pose in one Warp kernel (kdfaces.motion.pose.PoseSampler, issue #29) against the trajectory's own
evaluation: blend shapes, in-betweens, LBS, root motion and IKD's corrections.

The kernel sums the same float64 products as the trajectory (float32 deltas widen exactly) in another order, so the
two agree to float64 round-off: positions of order 1 m, a few dozen terms each, ~1e-15 m; 1e-12 m leaves room."""

from __future__ import annotations

import numpy as np
import pytest

from kdfaces import FaceAnimation, KinematicTrajectory
from kdfaces.motion.curves import KeyframeCurve
from kdfaces.motion.joints import SkeletonAnimation
from kdfaces.motion.pose import PoseSampler

ROUND_OFF_M = 1e-12


@pytest.fixture(scope="module")
def demo_traj(default_rig):
    from kdfaces.shots.builtin import demo_animation

    return KinematicTrajectory(default_rig, demo_animation())


def test_the_pose_is_the_trajectorys_blend_and_skin(demo_traj):
    rig = demo_traj.rig
    assert rig.skeleton is not None and demo_traj.animation.skeleton.drives  # LBS is exercised
    sampler = PoseSampler(rig)
    t = demo_traj.frame_times[[0, 37, 80, 150]]
    x = sampler.positions(demo_traj, t)
    ref = demo_traj.scan(t, 0)[0]
    assert np.abs(ref - rig.neutral).max() > 1e-2  # the shapes and the head turn move the face centimetres
    np.testing.assert_allclose(x, ref, rtol=0, atol=ROUND_OFF_M)
    # split over vertex ranges (threads): every vertex's arithmetic is the same, so the same bits
    out = np.empty_like(x)
    runs = sampler.launch(demo_traj, t, out, parts=3)
    assert len(runs) == 3
    for run in runs[::-1]:
        run()
    np.testing.assert_array_equal(out, x)
    # one time at a time: the same bits as the batch
    np.testing.assert_array_equal(sampler.positions(demo_traj, t[1:2])[0], x[1])


def test_root_motion_and_in_betweens(default_rig, demo_traj):
    from kdfaces.rig import BlendshapeRig

    rig = default_rig
    k = list(rig.shape_names).index("jawOpen")
    half = 0.3 * rig.deltas[k]  # an in-between target reached at weight 0.5, not the half of jawOpen
    inb = BlendshapeRig.create(rig.neutral, np.concatenate([rig.deltas, half[None].astype(np.float32)]), rig.faces,
                               [*rig.shape_names, "jawOpen_50"], skeleton=rig.skeleton, name="inb",
                               inbetweens=((k, (rig.num_shapes, k), (0.5, 1.0)),))
    times = np.linspace(0.0, 2.0, 9)
    root = KeyframeCurve.create(times, np.stack([0.1 * times, 0.02 * np.sin(3 * times), -0.05 * times], axis=1))
    skel = demo_traj.animation.skeleton
    anim = FaceAnimation(tracks=demo_traj.animation.tracks, skeleton=SkeletonAnimation(drives=skel.drives, root=root),
                         start_s=0.0, end_s=2.0, fps=25.0)
    traj = KinematicTrajectory(inb, anim)
    t = np.linspace(0.1, 1.9, 7)
    assert np.abs(traj.weights(t, 0)[0][:, -1]).max() > 0.1  # the in-between target is blended in
    np.testing.assert_allclose(PoseSampler(inb).positions(traj, t), traj.scan(t, 0)[0], rtol=0, atol=ROUND_OFF_M)


def test_corrected_trajectories_and_the_fallback(demo_traj):
    from kdfaces.ikd import CorrectedTrajectory, Correction, GaussianBasis, Slot

    rig = demo_traj.rig
    n = rig.num_vertices
    slots = [Slot(1.0, "position", GaussianBasis(1.0, 0.2)), Slot(1.3, "velocity", GaussianBasis(1.3, 0.2))]
    corr = Correction(slots, (n, 3))
    rng = np.random.default_rng(3)
    corr.values[:] = 1e-3 * rng.standard_normal(corr.values.shape)
    corr.update()
    sampler = PoseSampler(rig)
    t = np.linspace(0.8, 1.5, 5)
    for traj in (CorrectedTrajectory(demo_traj, corr),
                 CorrectedTrajectory(demo_traj, corr, bump=(slots[1], 1e-3 * rng.standard_normal((n, 3))))):
        assert sampler.supports(traj)
        x = sampler.positions(traj, t)
        assert np.abs(x - demo_traj.scan(t, 0)[0]).max() > 1e-4  # f (and the bump) are in it
        np.testing.assert_allclose(x, traj.evaluate(t, 0)[0], rtol=0, atol=ROUND_OFF_M)
    # a trajectory the kernel does not evaluate (a subset's, another rig's) is evaluated by itself
    view = demo_traj.restricted(np.arange(0, n, 2))
    other = KinematicTrajectory(rig.__class__.create(rig.neutral, rig.deltas, rig.faces, rig.shape_names,
                                                     skeleton=rig.skeleton, name="copy"), demo_traj.animation)
    assert not sampler.supports(view) and not sampler.supports(other)
    np.testing.assert_array_equal(sampler.positions(other, t), other.scan(t, 0)[0])
    with pytest.raises(ValueError, match="trajectory"):
        sampler.launch(other, t, np.empty((len(t), n, 3)))
