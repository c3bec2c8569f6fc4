"""The braid scene (issue 28): the structured braid mesh, the body collider, the independent contact check, the
shoulder flip and ``kdfem braid``'s summary."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kdfaces.errors import KDInputError


@pytest.fixture(scope="module")
def collider():
    from kdfem.geometry.colliders import body_collider

    return body_collider()


@pytest.fixture(scope="module")
def scene_free():
    """The scene without contact (the braid's own dynamics; no collider in the system)."""
    from kdfem.scenes.braid import build_braid_scene

    return build_braid_scene(contact=False, threads=1)


@pytest.fixture(scope="module")
def scene_contact():
    """The scene with the body as collider."""
    from kdfem.scenes.braid import build_braid_scene

    return build_braid_scene(contact=True, threads=1)


#: The flip test's frames: the first 1.2 s (turn, flip and hold) at every second frame.
FLIP_SPAN_S = 1.2
#: The ground-truth check's frames (test_cheap_plan_windows_meet_epsilon_against_the_full_simulation).
PLAN_FRAMES_S = (2.72, 6.0)


@pytest.fixture(scope="module")
def contact_runs(scene_contact):
    """The expensive simulations of the contact tests, each run once and on two threads at a time: the full
    simulation with contact (the ground truth: the flip test's frames and the plan's frames in one run from the
    shot start, so the flip test's 1.2 s are the first steps of the plan's 6 s) and the fixed-window KD state at
    2.72 s on a second scene of its own, while this thread runs the cheap pass, the plan and the contact-aware KD
    state at 2.72 s; the second scene then takes the aware state at 6.0 s and plans again from a copy of the same
    pass (on its own, fresh system). A system steps one batch at a time (its stepper cache and pending window are
    its own), hence two scenes; each KD state is its own simulation with its own step count, so the states are the
    bits one batch of both would give.

    Returns a dict: flip_times, frames (s); full_flip, full_frames (the full simulation there); eps, window (the
    §5.3 estimate); pass_times, pass_X (the cheap pass); aw, aw2 (the plan, and again on the second scene), events;
    aware, fixed (KD at the frames with the plan's windows, at the first frame with the fixed window)."""
    from concurrent.futures import Future, ThreadPoolExecutor

    from kdfaces.kd import simulate_full, simulate_kd
    from kdfaces.resources import single_threaded_blas
    from kdfem.modal.adaptive import CONTACT_PASS_SAMPLE_STEPS, contact_aware_windows, contact_pass
    from kdfem.scenes.braid import build_braid_scene

    sc = scene_contact
    sys_, h = sc.system, sc.step_s
    est = sys_.automatic_window(sc.joints, step_s=h)
    eps, window = float(est.epsilon_m), float(est.window_s)
    flip_times = sc.animation.frame_times[::2]
    flip_times = flip_times[flip_times <= FLIP_SPAN_S + 1e-9]
    F = np.array(PLAN_FRAMES_S)
    H = CONTACT_PASS_SAMPLE_STEPS * h
    tp = H * np.arange(int(round(F.max() / H)) + 1)
    plan = {}

    def second_scene():
        other = build_braid_scene(contact=True, threads=1)
        full = simulate_full(other.system, other.joints, np.concatenate([flip_times, F]), step_s=h)
        fixed = simulate_kd(other.system, other.joints, F[:1], window, step_s=h)
        ready.result()  # the plan, from this thread's pass
        late = simulate_kd(other.system, other.joints, F[1:], plan["aw"].window_s[1:], step_s=h)
        aw2, _ = contact_aware_windows(other.system, other.joints, F, plan["pass_X"].copy(), pass_times=tp,
                                       step_s=h, epsilon_m=eps)
        return full, fixed, late, aw2

    # one BLAS limit over both threads (kdfaces.resources.single_threaded_blas: concurrent blocks share it)
    ready = Future()  # set once this thread's plan exists (or failed)
    with single_threaded_blas(), ThreadPoolExecutor(1) as pool:
        other = pool.submit(second_scene)
        try:
            Xp = contact_pass(sys_, sc.joints, tp, step_s=h)
            aw, events = contact_aware_windows(sys_, sc.joints, F, Xp, pass_times=tp, step_s=h, epsilon_m=eps)
            plan.update(aw=aw, pass_X=Xp)
            ready.set_result(True)
        except BaseException as exc:
            ready.set_exception(exc)
            raise
        early = simulate_kd(sys_, sc.joints, F[:1], aw.window_s[:1], step_s=h)
        full, fixed, late, aw2 = other.result()
    return {"flip_times": flip_times, "frames": F, "full_flip": full[:len(flip_times)],
            "full_frames": full[len(flip_times):], "eps": eps, "window": window, "pass_times": tp, "pass_X": Xp,
            "aw": aw, "aw2": aw2, "events": events, "aware": np.concatenate([early, late]), "fixed": fixed}


def test_braid_mesh_valid():
    from kdfem.geometry.braid import BraidParams, braid_tetmesh
    from kdfem.geometry.tetmesh import tet_quality

    b = braid_tetmesh()
    m = b.mesh
    c, S = BraidParams().cells, BraidParams().segments
    assert m.num_tets == 6 * c * c * S and m.num_nodes == (c + 1) ** 2 * (S + 1)
    assert (m.volumes() > 0).all()
    # the tube's volume: the elliptical map's disk of c × c cells is a polygon inside the circle; the frustum
    # π/3 L (r0² + r0 r1 + r1²) bounds it from above, the inscribed square (area 2 r²) from below
    p = BraidParams()
    frustum = np.pi / 3 * p.length_m * (p.root_radius_m ** 2 + p.root_radius_m * p.tip_radius_m + p.tip_radius_m ** 2)
    assert 2 / np.pi * frustum < m.volumes().sum() < frustum
    assert tet_quality(m)["min_dihedral_deg"] > 10.0
    # deterministic: the same bytes every time
    b2 = braid_tetmesh()
    assert np.array_equal(b2.mesh.nodes, m.nodes) and np.array_equal(b2.mesh.tets, m.tets)
    # the attached nodes are the root ring, the tip is the far end
    root = np.asarray(p.root_center_m)
    assert np.allclose(m.nodes[b.attached, 1], root[1]) and len(b.attached) == b.ring_size
    assert np.allclose(m.nodes[b.root], root)
    assert np.isclose(np.linalg.norm(m.nodes[b.tip] - root), p.length_m)
    # a closed, outward surface
    import trimesh

    surf = trimesh.Trimesh(m.nodes, m.boundary_faces(), process=False)
    assert surf.is_watertight and np.isclose(surf.volume, m.volumes().sum())


def test_braid_params_refused():
    from kdfem.geometry.braid import BraidParams

    with pytest.raises(KDInputError, match="length_m"):
        BraidParams(length_m=-0.1)
    with pytest.raises(KDInputError, match="attached_rings"):
        BraidParams(attached_rings=0)


def test_body_collider_moves_with_head_chain(collider, scene_free):
    """The collider is the body's head, neck, shoulders and upper back; its vertices move with the head chain's
    skin (the KinematicTrajectory of the sub-rig), the torso stays put, and the contact collider gives the same
    positions."""
    from kdfaces.io.rigfiles import load_rig
    from kdfem.geometry.colliders import BODY_RIG_PATH, BODY_Y_MIN_M

    body = load_rig(BODY_RIG_PATH)
    v = collider.rest_vertices
    assert np.array_equal(v, body.neutral[collider.source_vertices])
    assert v[:, 1].min() >= BODY_Y_MIN_M and v[:, 1].max() == pytest.approx(body.neutral[:, 1].max())
    sc = scene_free
    t = np.array([0.0, 0.6, 1.0])
    P = collider.positions(sc.trajectory, t)
    assert np.allclose(P[0], v)
    W = collider.rig.skeleton.weights.sum(axis=1)
    moved = np.linalg.norm(P[1] - v, axis=1)
    assert moved[W < 1e-9].max() == 0.0  # the fixed torso
    assert moved[W > 0.99].max() > 0.05  # the head turned
    # head vertices move rigidly with the head joint: distances between them are kept
    from kdfaces.motion.joints import joint_frames

    G = joint_frames(sc.joints, t[1:2])[0][0, collider.rig.skeleton.index("head")]
    head_only = collider.rig.skeleton.weights[:, collider.rig.skeleton.index("head")] > 1 - 1e-9
    assert np.allclose(P[1][head_only], v[head_only] @ G[:3, :3].T + G[:3, 3], atol=1e-12)
    Q = collider.contact_collider().positions(t, sc.joints)
    assert np.allclose(Q, P, atol=1e-12)


def test_contact_check_matches_igl(collider, scene_free):
    """The independent check's minimum distance against libigl's point–surface distance (vertex–face pairs only, so
    igl's is an upper bound of ipctk's, equal when the closest pair is a vertex and a face)."""
    import igl

    from kdfem.scenes.braid import contact_check

    sc = scene_free
    x = sc.system.rest_equilibrium
    c = contact_check(sc, [0.0], x[None], dhat_m=0.02)
    free = np.setdiff1d(np.unique(sc.braid.mesh.boundary_faces()), sc.braid.attached)
    d2, _, _ = igl.point_mesh_squared_distance(x[free], collider.rest_vertices, collider.faces)
    assert c["intersections"] == 0
    assert 0 < c["min_distance_m"] <= np.sqrt(d2.min()) + 1e-12
    assert c["min_distance_m"] > 0.5 * np.sqrt(d2.min())
    # the rest equilibrium hangs clear of the body (a KD window start must not touch it), and close to the back
    assert 1e-3 < c["min_distance_m"] < 1e-2
    # a braid pushed into the back intersects
    y = x.copy()
    y[free, 2] += 0.02
    assert contact_check(sc, [0.0], y[None])["intersections"] == 1


def test_shoulder_flip_detection(scene_free):
    from kdfem.scenes.braid import shoulder_flip

    sc = scene_free
    x = sc.system.rest_equilibrium
    flip, front = shoulder_flip(sc, [0.0], x[None])
    assert flip is None and front[0] < -0.05
    y = x.copy()
    y[:, 2] += 0.2  # the whole braid in front of the shoulders
    flip, front = shoulder_flip(sc, [0.0, 0.5], np.stack([x, y]))
    assert flip == 0.5 and front[1] > 0.1


def test_contact_aware_windows_call_site(scene_free):
    from kdfem.scenes.braid import contact_aware_windows

    sc = scene_free
    t = np.array([0.4, 1.0, 2.0])
    aw, method, events = contact_aware_windows(sc.system, sc.joints, t, step_s=sc.step_s)
    assert "not contact-aware" in method and events == []
    assert aw.window_s.shape == (3,) and (aw.window_s >= 0).all()


def test_contact_aware_windows_reach_back_past_contact(scene_contact):
    """A pass that comes within the contact band at one frame: one event starting a frame earlier; windows of the
    frames from there on start before it (by its own modal window) until its left-behind deviation has decayed
    below ε under the modal envelope; frames before it keep their §5.3 windows; never before the shot start."""
    from kdfem.scenes.braid import contact_aware_windows

    sc = scene_contact
    t = np.round(np.arange(0.0, 0.2801, 0.04), 10)
    X = sc.system.observe_kinematic(sc.joints, t)  # head still until 0.3 s: the rest 4.1 mm from the back
    cm = sc.system.contact
    k = 3
    X[k:k + 2, :, 2] += 4.13e-3 - 0.5 * cm.dhat_m  # two frames pushed within d̂ of the back
    C, _ = cm.collider_pose(t, sc.joints)
    assert not cm.intersects(X[k, cm.nodes], C[k])
    aw, method, events = contact_aware_windows(sc.system, sc.joints, t, step_s=sc.step_s, pass_positions=X)
    modal = sc.system.adaptive_windows(sc.joints, t, step_s=sc.step_s)
    assert "contact-aware" in method and len(events) == 1
    ev = events[0]
    assert ev["start_s"] == pytest.approx(t[k - 1]) and ev["end_s"] == pytest.approx(t[k + 1])
    assert ev["left_behind_m"] > 0
    assert np.array_equal(aw.steps[:k - 1], modal.steps[:k - 1])
    gone = np.inf if ev["decayed_s"] is None else ev["decayed_s"]
    live = (t >= ev["start_s"]) & ((t <= ev["end_s"]) | (t < gone))
    assert live[k - 1:k + 2].all()
    assert (t[live] - aw.window_s[live] <= ev["window_start_s"] + 1e-9).all()
    assert (aw.window_s >= modal.window_s - 1e-12).all() and (t - aw.window_s >= -1e-9).all()


def test_full_simulation_flips_braid_without_intersection(scene_contact, contact_runs):
    """The full simulation with contact flips the braid over the shoulder (its tip crosses the shoulder plane, at
    t ≈ 0.72 s under BRAID_HEAD_KEYS) and the independent ipctk check finds no intersection and a positive distance
    on every evaluated frame. The first 1.2 s (turn, flip and hold) at every second frame, to keep the test short
    (the first steps of the ground truth's run, :func:`contact_runs`)."""
    from kdfem.scenes.braid import contact_check, shoulder_flip

    sc = scene_contact
    times, X = contact_runs["flip_times"], contact_runs["full_flip"]
    assert len(times) == 16 and times[-1] == pytest.approx(FLIP_SPAN_S)  # 0, 0.08, …, 1.2 s at 25 fps
    flip, front = shoulder_flip(sc, times, X)
    assert flip is not None and front.max() > 0
    c = contact_check(sc, times, X)
    assert c["intersections"] == 0 and c["min_distance_m"] > 0
    # every step went through the contact model's own check too: the minimum distance stayed positive
    cm = sc.system.contact
    C, _ = cm.collider_pose(times, sc.joints)
    assert all(not cm.intersects(X[k][cm.nodes], C[k]) for k in range(len(times)))


def test_contact_model_min_distance_is_braid_body(scene_contact):
    """ContactModel.min_distance on the rest shape is the braid–body distance of the independent check (a distance,
    not its square; no collider–collider or attached pairs), and inf within the default d̂ (the rest hangs clear)."""
    from kdfem.scenes.braid import contact_check

    sc = scene_contact
    cm, x = sc.system.contact, sc.system.rest_equilibrium
    C, _ = cm.collider_pose([0.0], sc.joints)
    ref = contact_check(sc, [0.0], x[None], dhat_m=0.02)["min_distance_m"]
    assert cm.min_distance(x[cm.nodes], C[0]) == np.inf and ref > cm.dhat_m
    assert cm.min_distance(x[cm.nodes], C[0], within_m=0.02) == pytest.approx(ref, rel=1e-12)


def test_kinematic_start_projected_out_of_the_body(scene_contact):
    """A window start with the head turned: the carried rest shape intersects the body, the kinematic start is the
    sweep out of it (HatSystem.start_state): clear (independent ipctk check), the same bits every time, attached
    nodes exactly on the head; a start with the head still is the carried shape bit for bit."""
    from kdfem.scenes.braid import contact_check

    sc = scene_contact
    cm = sc.system.contact
    t = np.array([1.0])
    kin = sc.system.observe_kinematic(sc.joints, t)
    C, _ = cm.collider_pose(t, sc.joints)
    assert cm.intersects(kin[0, cm.nodes], C[0])  # the carried shape goes through the shoulder
    s1 = sc.system.initial_state(sc.joints, t)
    s2 = sc.system.initial_state(sc.joints, t)
    assert np.array_equal(s1.x, s2.x) and np.array_equal(s1.v, s2.v)
    c = contact_check(sc, t, s1.x)
    assert c["intersections"] == 0 and c["min_distance_m"] > 0
    att = sc.braid.attached
    assert np.allclose(s1.x[0, att], kin[0, att], atol=1e-12)
    still = sc.system.initial_state(sc.joints, np.array([0.2]))
    assert np.array_equal(still.x, sc.system.observe_kinematic(sc.joints, [0.2]))


def test_run_braid_summary_without_contact(tmp_path):
    """The outputs and summary keys of the scene, on the braid's own dynamics (contact off, every 4th frame)."""
    from kdfem.scenes.braid import run_braid

    s = run_braid(tmp_path, frame_stride=4, movie=False, contact=False)
    data = json.loads((tmp_path / "summary.json").read_text())
    assert data["kd"]["epsilon_m"] == pytest.approx(s["kd"]["epsilon_m"])
    for key in ("window_s", "max_error_vs_full_m"):
        assert key in data["kd"]["fixed"]
    for key in ("mean_window_s", "max_error_vs_full_m", "method"):
        assert key in data["kd"]["contact_aware"]
    for key in ("min_distance_m", "intersections", "flip_time_s"):
        assert key in data["contact"]
    assert data["collider"]["contact"] is False
    for name in data["outputs"]:
        assert (tmp_path / name).stat().st_size > 0


def test_cheap_plan_windows_meet_epsilon_against_the_full_simulation(scene_contact, contact_runs):
    """The contact-aware plan from the cheap pass (a coarse-step contact simulation, not the ground truth's run) and
    x_K, checked against the full simulation with contact on the frames that matter (every frame would take an hour
    on two shared cores): 2.72 s, the braid draped over the shoulder longer ago than the §5.3 window (KD with the
    fixed window fails there, the paper's §6.3 failure; the plan's window reaches back before the flip and is within
    ε); 6.0 s, after its swing has decayed, where the window shrinks to start after the fall-back and is within ε
    too. (3.6 s, just after the second move threw it back, is in the every-8th-frame table of docs/hat.md: its
    window reaches back before the flip, the test's costliest state, so it is left out to keep the suite short.) The
    plan is the same bits when computed again from the same pass (by a second, fresh system of the same scene). The
    runs are :func:`contact_runs`'s."""
    from kdfem.scenes.braid import shoulder_flip

    sc = scene_contact
    r = contact_runs
    eps, window, F, tp, Xp = r["eps"], r["window"], r["frames"], r["pass_times"], r["pass_X"]
    aw, aw2, events = r["aw"], r["aw2"], r["events"]
    assert np.array_equal(aw.steps, aw2.steps)
    flip, _ = shoulder_flip(sc, tp, Xp)
    assert flip is not None and 0.6 < flip < 1.0  # the cheap pass flips the braid too
    assert events and events[0]["start_s"] < flip
    start = F - aw.window_s
    assert start[0] <= flip - 0.2  # the draped braid remembers the flip
    assert start[1] > 2.5  # decayed: the window no longer reaches back to the drape, only into the second move
    full = r["full_frames"]
    _, front = shoulder_flip(sc, F, full)
    assert front[0] > 0 and front[1] < 0  # over the shoulder at 2.72 s, down the back after
    aware = r["aware"]
    err = np.linalg.norm((aware - full).reshape(len(F), -1), axis=1)
    assert (err <= eps).all(), (err, eps)
    fixed = r["fixed"]
    assert F[0] - window > flip  # the fixed window starts after the flip …
    assert np.linalg.norm(fixed[0] - full[0]) > 10 * eps  # … and misses it by far more than ε
