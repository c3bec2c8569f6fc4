"""IK on joint chains (kinematics lecture): the analytic chain Jacobian against finite differences of FK, DLS and
Jacobian-transpose IK, limits, look-at targets and the null-space rest preference; root motion in FK."""

from __future__ import annotations

import numpy as np
import pytest

from kdfaces.motion import (
    NECK_CHAIN,
    IKUnreachableError,
    JointTrajectory,
    KeyframeCurve,
    LookAtTarget,
    PointTarget,
    SkeletonAnimation,
    chain_frames,
    direction_jacobian,
    ik_solve,
    point_jacobian,
    solve_ik,
)
from kdfaces.motion.joints import joint_frames
from kdfaces.rig.skeleton import joint_transforms

TIP = np.array([0.0, 1.04, -0.057])  # the default hat's tip, in rest coordinates


@pytest.fixture(scope="module")
def skel(default_rig):
    return default_rig.skeleton


def _carried(skel, theta, joint, local, root=None):
    G, _, _ = chain_frames(skel, theta, root=root)
    g = G[skel.index(joint)]
    return local @ g[:3, :3].T + g[:3, 3]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_point_jacobian_matches_central_differences_of_fk(skel, seed):
    """a × (p − r) per Euler angle of the head and its ancestors; FD error is O(ε²)·|p''| ≈ 1e-12·1 m."""
    rng = np.random.default_rng(seed)
    theta = rng.normal(0.0, 0.5, (len(skel.names), 3))
    root = rng.normal(0.0, 1.0, 3)
    local = np.array([TIP, [0.05, 0.8, 0.1], [0.0, 0.7, 0.0]])
    p = _carried(skel, theta, "head", local, root)
    J = point_jacobian(skel, theta, "head", p, root=root)
    eps = 1e-6
    fd = np.zeros_like(J)
    for k in range(len(skel.names)):
        for c in range(3):
            d = np.zeros_like(theta)
            d[k, c] = eps
            fd[:, :, k, c] = (_carried(skel, theta + d, "head", local, root)
                              - _carried(skel, theta - d, "head", local, root)) / (2 * eps)
    np.testing.assert_allclose(J, fd, atol=1e-9)
    assert np.abs(J[:, :, skel.index("jaw")]).max() == 0.0  # not an ancestor of the head
    assert np.abs(J).max() > 0.1


def test_direction_jacobian_matches_central_differences(skel):
    rng = np.random.default_rng(3)
    theta = rng.normal(0.0, 0.4, (len(skel.names), 3))
    f0 = np.array([0.0, 0.0, 1.0])

    def fwd(th):
        G, _, _ = chain_frames(skel, th)
        return G[skel.index("head"), :3, :3] @ f0

    J = direction_jacobian(skel, theta, "head", fwd(theta))[0]
    eps = 1e-6
    for k in range(len(skel.names)):
        for c in range(3):
            d = np.zeros_like(theta)
            d[k, c] = eps
            np.testing.assert_allclose(J[:, k, c], (fwd(theta + d) - fwd(theta - d)) / (2 * eps), atol=1e-9)


def test_dls_reaches_a_reachable_target_to_a_micrometre(skel):
    """The target is FK of another pose, so it is reachable by construction."""
    rng = np.random.default_rng(4)
    for _ in range(5):
        start = np.zeros((len(skel.names), 3))
        goal_pose = start.copy()
        goal_pose[:4] = rng.normal(0.0, 0.25, (4, 3))
        target = _carried(skel, goal_pose, "head", TIP)
        theta = ik_solve(skel, start, [PointTarget("head", TIP, target)], dofs=NECK_CHAIN)
        assert np.linalg.norm(_carried(skel, theta, "head", TIP) - target) <= 1e-6
        assert np.abs(theta[skel.index("jaw")]).max() == 0.0  # only the chain moved


def test_dls_reports_an_unreachable_target(skel):
    """2 m above the head: beyond the 0.45 m neck chain. It says so, and its closest pose leans towards the target."""
    far = TIP + np.array([1.0, 1.5, 0.8])
    r = solve_ik(skel, np.zeros((len(skel.names), 3)), [PointTarget("head", TIP, far)], dofs=NECK_CHAIN)
    assert not r.reached and r.reason == "unreachable"
    assert r.error_m > 1.5
    with pytest.raises(IKUnreachableError, match="not reached") as info:
        ik_solve(skel, np.zeros((len(skel.names), 3)), [PointTarget("head", TIP, far)], dofs=NECK_CHAIN)
    np.testing.assert_allclose(info.value.angles, r.angles)
    closest = ik_solve(skel, np.zeros((len(skel.names), 3)), [PointTarget("head", TIP, far)], dofs=NECK_CHAIN,
                       on_unreachable="closest")
    neck = skel.positions[0]
    to_target = (far - neck) / np.linalg.norm(far - neck)
    to_tip = _carried(skel, closest, "head", TIP) - neck
    assert to_tip @ to_target / np.linalg.norm(to_tip) > 0.95  # leaning towards it (it started at 0.79)
    start_tip = TIP - neck
    assert start_tip @ to_target / np.linalg.norm(start_tip) < 0.8


def test_jacobian_transpose_converges_slower_than_dls(skel):
    goal = np.zeros((len(skel.names), 3))
    goal[:4, 1] = 0.1
    target = _carried(skel, goal, "head", TIP)
    start = np.zeros_like(goal)
    dls = solve_ik(skel, start, [PointTarget("head", TIP, target)], dofs=NECK_CHAIN, tolerance_m=1e-6)
    jt = solve_ik(skel, start, [PointTarget("head", TIP, target)], dofs=NECK_CHAIN, method="transpose",
                  tolerance_m=1e-6, max_iterations=5000)
    assert dls.reached and jt.reached
    assert dls.iterations < 10 < jt.iterations


def test_limits_hold_and_a_target_beyond_them_is_unreachable(skel):
    lim = {name: [[-0.05, 0.05]] * 3 for name in NECK_CHAIN}
    goal = np.zeros((len(skel.names), 3))
    goal[:4, 1] = 0.03  # inside the limits
    target = _carried(skel, goal, "head", TIP)
    theta = ik_solve(skel, np.zeros_like(goal), [PointTarget("head", TIP, target)], dofs=NECK_CHAIN, limits=lim)
    assert np.abs(theta).max() <= 0.05 + 1e-12
    far = _carried(skel, np.where(goal > 0, 0.3, 0.0), "head", TIP)  # needs 0.3 rad per joint
    r = solve_ik(skel, np.zeros_like(goal), [PointTarget("head", TIP, far)], dofs=NECK_CHAIN, limits=lim)
    assert not r.reached and np.abs(r.angles).max() <= 0.05 + 1e-12


def test_look_at_turns_the_face_towards_a_point(skel):
    target = np.array([0.8, 1.0, 1.2])
    theta = ik_solve(skel, np.zeros((len(skel.names), 3)), [LookAtTarget("head", target)], dofs=NECK_CHAIN)
    G, _, _ = chain_frames(skel, theta)
    h = skel.index("head")
    eye = G[h, :3, :3] @ skel.positions[h] + G[h, :3, 3]
    fwd = G[h, :3, :3] @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(fwd, (target - eye) / np.linalg.norm(target - eye), atol=1e-6)


def test_the_rest_preference_moves_only_in_the_null_space(skel):
    """Four joints, one point target: the rest term unbends an S-bent chain while the tip stays on its target."""
    bent = np.zeros((len(skel.names), 3))
    bent[:4, 1] = [0.3, -0.3, 0.3, -0.3]
    target = _carried(skel, bent, "head", TIP)
    free = solve_ik(skel, bent, [PointTarget("head", TIP, target)], dofs=NECK_CHAIN)
    assert free.iterations == 0 and free.reached  # already there, nothing to do
    pulled = solve_ik(skel, bent, [PointTarget("head", TIP, target)], dofs=NECK_CHAIN, rest_gain=0.5,
                      tolerance_m=1e-7, max_iterations=500)
    assert pulled.reached, pulled.reason
    assert np.linalg.norm(pulled.angles) < 0.5 * np.linalg.norm(bent)  # much closer to rest ...
    assert np.linalg.norm(_carried(skel, pulled.angles, "head", TIP) - target) <= 1e-7  # ... the tip unmoved


def test_root_translation_moves_every_joint_and_keeps_exact_derivatives(skel):
    """FK with a walking root: G = T(r)·G_angles, and Ġ, G̈ carry ṙ, r̈ (compared with central differences)."""
    tk = np.array([0.0, 0.5, 1.0, 1.5])
    root = KeyframeCurve.create(tk, np.c_[0 * tk, 0.02 * np.sin(6 * tk), 1.2 * tk])
    head = KeyframeCurve.create(tk, np.c_[0.2 * tk, -0.1 * tk**2, 0 * tk])
    from kdfaces.motion import JointDrive

    jt = JointTrajectory(skel, SkeletonAnimation((JointDrive(head),), root=root), start_s=0.0, end_s=1.5)
    t = np.array([0.7])
    G, dG, ddG = joint_frames(jt, t)
    G0 = joint_transforms(skel, jt.evaluate(t, 2))[0]
    r = root.evaluate(t, 0)[0]
    np.testing.assert_allclose(G[..., :3, 3], G0[..., :3, 3] + r[:, None], atol=1e-15)
    np.testing.assert_allclose(G[..., :3, :3], G0[..., :3, :3])
    eps = 1e-5
    Gp, Gm = joint_frames(jt, t + eps)[0], joint_frames(jt, t - eps)[0]
    np.testing.assert_allclose(dG, (Gp - Gm) / (2 * eps), atol=1e-8)
    np.testing.assert_allclose(ddG, (Gp - 2 * G + Gm) / eps**2, atol=1e-4)


def test_a_face_trajectory_walks_with_its_root(default_rig):
    from kdfaces import FaceAnimation, KinematicTrajectory

    root = KeyframeCurve.create([0.0, 1.0], [[0.0, 0.0, 0.0], [0.0, 0.0, 1.2]], interpolation="linear")
    walk = KinematicTrajectory(default_rig, FaceAnimation(skeleton=SkeletonAnimation(root=root)))
    still = KinematicTrajectory(default_rig, FaceAnimation())
    x, v, _ = walk.evaluate([0.5], 2)
    x0, v0, _ = still.evaluate([0.5], 2)
    np.testing.assert_allclose(x - x0, np.broadcast_to([0.0, 0.0, 0.6], x.shape), atol=1e-12)
    np.testing.assert_allclose(v - v0, np.broadcast_to([0.0, 0.0, 1.2], v.shape), atol=1e-12)
