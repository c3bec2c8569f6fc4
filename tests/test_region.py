"""The face region in the dynamics (issue 25): a full-body avatar simulates its moving region only, with ε, the
diameter and the windows of that region, and gets the same KD states on its face as the face on its own; vertices
outside the region are x_K exactly and cost nothing per step; the units check measures the region.

The body-like rig here is the default head plus a static torso sheet below it (no shapes, no skin: nothing moves
it), a separate connected piece appended after the head's vertices. Its moving region is then exactly the head's
vertices (the ring margin cannot cross into a separate piece), so the region's masses, gains, clusters and bake are
the head's own arrays in the same order: the face's KD states must agree bit for bit, not merely to a tolerance.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from kdfaces import BlendshapeRig, KinematicTrajectory
from kdfaces.dynamics import FaceModel, FaceSystem
from kdfaces.errors import KDInputError
from kdfaces.io import load_rig
from kdfaces.io.rigfiles import RigUnitsWarning, save_npz
from kdfaces.kd import simulate_full, simulate_kd
from kdfaces.rig import Skeleton
from kdfaces.rig.blendshapes import check_plausible_size
from kdfaces.rig.region import moving_region, region_diameter
from kdfaces.shots.builtin import demo_animation
from kdfaces.window import adaptive_windows, automatic_window

SETTLE = dict(settle_time_s=0.3, damping_ratio=0.3)
#: float64 round-off of positions about a metre from the origin, with a wide margin (x_K evaluated in other chunks)
POSITION_ATOL_M = 1e-12


def torso_sheet(head: BlendshapeRig, k: int) -> tuple[np.ndarray, np.ndarray]:
    """A k×k grid sheet [m], 0.5 m wide and 1.3 m tall, just below the head (a static "body"), and its triangles."""
    lo = head.neutral.min(axis=0)
    u, w = np.meshgrid(np.linspace(-0.25, 0.25, k), np.linspace(lo[1] - 1.3, lo[1] - 0.02, k))
    verts = np.stack([u.ravel(), w.ravel(), np.full(u.size, 0.1)], axis=1)
    idx = np.arange(k * k).reshape(k, k)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return verts, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def body_rig(head: BlendshapeRig, k: int, *, scale: float = 1.0, check_units: bool = True) -> BlendshapeRig:
    """The head with a k×k torso sheet appended (zero deltas, zero skin weights), all coordinates × ``scale``."""
    tv, tf = torso_sheet(head, k)
    n, sk = head.num_vertices, head.skeleton
    skeleton = Skeleton(sk.names, sk.positions * scale, sk.parents,
                        np.concatenate([sk.weights, np.zeros((len(tv), len(sk.names)))]))
    deltas = np.concatenate([head.deltas, np.zeros((head.num_shapes, len(tv), 3), np.float32)], axis=1)
    return BlendshapeRig.create(np.concatenate([head.neutral, tv]) * scale, deltas * scale,
                                np.concatenate([head.faces, tf + n]), head.shape_names, skeleton=skeleton,
                                name=f"body{k}", check_units=check_units)


@pytest.fixture(scope="module")
def head(default_rig):
    return default_rig


@pytest.fixture(scope="module")
def bodies(head):
    return {k: body_rig(head, k) for k in (20, 60)}


@pytest.fixture(scope="module")
def short_demo():
    """The demo's first 2.4 s: the jaw opens and closes, the head turns and stops sharply, the smile starts."""
    a = demo_animation()
    return type(a)(tracks=a.tracks, skeleton=a.skeleton, start_s=0.0, end_s=2.4, fps=a.fps, name="demo-2.4s")


def test_the_default_head_is_its_own_region(head):
    # every vertex of the head-and-neck rig is skinned to the neck/head: "auto" simulates all, as before
    model = FaceModel.from_rig(head, **SETTLE)
    assert model.region is None and model.num_simulated == head.num_vertices
    assert model.diameter_m == pytest.approx(float(np.linalg.norm(np.ptp(head.neutral, axis=0))), rel=1e-15)
    every = FaceModel.from_rig(head, region=None, **SETTLE)
    assert np.array_equal(every.clusters.members, model.clusters.members)


def test_a_body_simulates_its_face_region_with_the_heads_diameter(head, bodies):
    for body in bodies.values():
        region = moving_region(body)
        np.testing.assert_array_equal(region, np.arange(head.num_vertices))  # the head, margin stops at the piece
        model = FaceModel.from_rig(body, **SETTLE)
        np.testing.assert_array_equal(model.region, region)
        assert model.num_vertices == body.num_vertices and model.num_simulated == head.num_vertices
        assert model.diameter_m == region_diameter(body) == FaceModel.from_rig(head, **SETTLE).diameter_m
        assert np.isin(model.clusters.members, region).all()  # clusters hold region vertices only
        whole = FaceModel.from_rig(body, region=None, **SETTLE)
        assert whole.region is None and whole.diameter_m > 3 * model.diameter_m  # the body's diagonal


def test_the_bodys_face_gets_the_heads_kd_states_and_the_rest_follows_x_k(head, bodies, short_demo):
    body = bodies[60]
    n = head.num_vertices
    th, tb = KinematicTrajectory(head, short_demo), KinematicTrajectory(body, short_demo)
    sh, sb = FaceSystem(FaceModel.from_rig(head, **SETTLE)), FaceSystem(FaceModel.from_rig(body, **SETTLE))
    wh, wb = automatic_window(sh, th), automatic_window(sb, tb)
    assert wb == wh  # ε, ẍ_max, the gains and so the window: the region's, which is the head
    times = th.frame_times[[8, 16, 20, 30, 45]]
    xh = simulate_kd(sh, th, times, wh.window_s)
    xb = simulate_kd(sb, tb, times, wb.window_s)
    assert xb.shape == (len(times), body.num_vertices, 3)
    # same arrays in the same order (see the module docstring): bit for bit
    np.testing.assert_array_equal(xb[:, :n], xh)
    assert np.linalg.norm(xh - th.positions(times), axis=-1).max() > 2 * wh.epsilon_m  # the face does move
    np.testing.assert_allclose(xb[:, n:], tb.positions(times)[:, n:], rtol=0, atol=POSITION_ATOL_M)
    # the full simulation (the ground truth) likewise
    fh = simulate_full(sh, th, times[:2])
    fb = simulate_full(sb, tb, times[:2])
    np.testing.assert_array_equal(fb[:, :n], fh)
    np.testing.assert_allclose(fb[:, n:], tb.positions(times[:2])[:, n:], rtol=0, atol=POSITION_ATOL_M)


def test_the_demo_shots_dynamics_on_a_body(head, bodies, short_demo):
    # the shot-file path: the demo's [dynamics] (soft-tissue settle map, auto-rigid teeth and eyes) on the body
    from kdfaces.shots.demo import demo_face_model

    body, n = bodies[20], head.num_vertices
    mh, mb = demo_face_model(head), demo_face_model(body)
    assert mb.num_simulated == n and mh.rigid_mask.any()
    np.testing.assert_array_equal(mb.rigid_mask[:n], mh.rigid_mask)
    np.testing.assert_array_equal(mb.settle_time_s[:n], mh.settle_time_s)
    th, tb = KinematicTrajectory(head, short_demo), KinematicTrajectory(body, short_demo)
    t = th.frame_times[[20, 40]]
    xh = simulate_kd(FaceSystem(mh), th, t, 0.3)
    xb = simulate_kd(FaceSystem(mb), tb, t, 0.3)
    np.testing.assert_array_equal(xb[:, :n], xh)


def test_the_region_on_every_kernel_path(head, bodies, short_demo):
    # one state shared by two threads (split by vertices along the region's cluster graph) and the GPU's parallel
    # launches (run here on the CPU) simulate the region as the head alone does
    body, n = bodies[20], head.num_vertices
    th, tb = KinematicTrajectory(head, short_demo), KinematicTrajectory(body, short_demo)
    t = [0.8]
    for kwargs in (dict(threads=2), dict(threads=1, kernels="parallel")):
        xh = simulate_kd(FaceSystem(FaceModel.from_rig(head, **SETTLE), **kwargs), th, t, 0.3)
        xb = simulate_kd(FaceSystem(FaceModel.from_rig(body, **SETTLE), **kwargs), tb, t, 0.3)
        np.testing.assert_array_equal(xb[:, :n], xh)
        np.testing.assert_allclose(xb[:, n:], tb.positions(t)[:, n:], rtol=0, atol=POSITION_ATOL_M)


def test_adaptive_windows_are_measured_on_the_region(head, bodies, short_demo):
    th, tb = KinematicTrajectory(head, short_demo), KinematicTrajectory(bodies[20], short_demo)
    ah = adaptive_windows(FaceModel.from_rig(head, **SETTLE), th)
    ab = adaptive_windows(FaceModel.from_rig(bodies[20], **SETTLE), tb)
    assert ab.epsilon_m == ah.epsilon_m
    np.testing.assert_array_equal(ab.steps, ah.steps)
    np.testing.assert_array_equal(ab.bound_m, ah.bound_m)


def test_a_step_costs_the_region_not_the_body(head, bodies, short_demo):
    # count what one step touches: the state's and the bake's vertices, and the kernel's launch width
    counts = []
    for body in bodies.values():
        system = FaceSystem(FaceModel.from_rig(body, **SETTLE), threads=1)
        traj = KinematicTrajectory(body, short_demo)
        t0 = traj.frame_times[[5, 10]]
        system.prepare(traj, t0, 3, 1 / short_demo.fps)
        state = system.initial_state(traj, t0)
        system.step(state, traj, t0, 1 / short_demo.fps)
        counts.append((system.num_simulated, state.chunks[0].x.shape[1], state.bake.xk_np.shape[1],
                       system.memory_bytes(1, 1) - 8 * 3 * body.num_vertices))  # less observe()'s (N, 3) output
        assert system.observe(state).shape == (2, body.num_vertices, 3)
    assert counts[0] == counts[1]
    assert counts[0][:3] == (head.num_vertices,) * 3


def test_region_argument(head, bodies):
    body = bodies[20]
    n = head.num_vertices
    mask = np.zeros(body.num_vertices, dtype=bool)
    mask[:n] = True
    by_mask = FaceModel.from_rig(body, region=mask, **SETTLE)
    by_index = FaceModel.from_rig(body, region=np.arange(n)[::-1], **SETTLE)  # any order: sorted
    np.testing.assert_array_equal(by_mask.region, by_index.region)
    np.testing.assert_array_equal(by_mask.clusters.members, FaceModel.from_rig(body, **SETTLE).clusters.members)
    assert FaceModel.from_rig(body, region=np.arange(body.num_vertices), **SETTLE).region is None  # all = None
    for bad, match in (("face", "region: expected 'auto', None or vertex indices"),
                       (np.array([0, body.num_vertices]), r"region: vertex indices must lie in \[0, "),
                       (np.zeros(0, np.int64), "region: expected at least one vertex"),
                       (np.zeros(3, bool), r"region: expected a \(\d+,\) mask"),
                       (np.array([0.5, 1.5]), "region: expected a .* bool mask or 1-D integer vertex indices")):
        with pytest.raises(KDInputError, match=match):
            FaceModel.from_rig(body, region=bad, **SETTLE)
    # a mesh nothing moves (no shapes, no skeleton) has no moving region: "auto" simulates all of it
    still = BlendshapeRig.create(body.neutral, np.zeros((0, body.num_vertices, 3)), body.faces, [], name="still",
                                 check_units=False)
    assert FaceModel.from_rig(still, **SETTLE).region is None


def test_the_units_check_measures_the_moving_region(head, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        body = body_rig(head, 20)  # a 1.66 m body in metres whose face spans 0.34 m: plausible
        assert float(np.ptp(body.neutral, axis=0).max()) > 1.5
        check_plausible_size(body, 0.01, "body.npz")  # the same numbers read from a file in cm
        # the body written in centimetres and loaded as such: plausible (the old check said "fits a head in mm")
        cm = save_npz(body_rig(head, 20, scale=100.0, check_units=False), tmp_path / "body_cm.npz")
        loaded = load_rig(cm, units="cm")
    np.testing.assert_allclose(loaded.neutral, body.neutral, rtol=1e-12, atol=1e-12)
    with pytest.warns(RigUnitsWarning, match=r"read as m, its moving region \(the face\) is 33.6 m across.* "
                                             r"the numbers fit a head in cm"):
        load_rig(cm)
    with pytest.warns(RigUnitsWarning, match="the numbers fit a head in mm"):  # a head in mm read as metres
        BlendshapeRig.create(head.neutral * 1000, head.deltas * 1000, head.faces, head.shape_names)
    with pytest.warns(RigUnitsWarning, match="the numbers fit a head in mm"):  # and a body whose face is one
        body_rig(head, 20, scale=1000.0)
    # nothing moves: the whole mesh is measured (1.66 m is no head)
    with pytest.warns(RigUnitsWarning, match="read as m, the rig is 1.6"):
        BlendshapeRig.create(body.neutral, np.zeros((0, body.num_vertices, 3)), body.faces, [])


def test_the_makehuman_body_gets_its_cut_out_faces_window_and_motion():
    avatar_fixtures = pytest.importorskip("avatar_fixtures")
    if not avatar_fixtures.BODY_PATH.is_file():
        pytest.skip(f"{avatar_fixtures.BODY_PATH} is not built")
    body = avatar_fixtures.load_body()
    face = avatar_fixtures.cut_out_face(body)
    fv = avatar_fixtures.face_vertices(body)
    a = demo_animation()
    anim = type(a)(tracks=a.tracks, skeleton=a.skeleton, start_s=0.0, end_s=2.4, fps=a.fps, name="demo-2.4s")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_plausible_size(body, 1.0, "makehuman_body.npz")  # a 1.67 m body: its moving region is head-sized
    mb, mf = FaceModel.from_rig(body, **SETTLE), FaceModel.from_rig(face, **SETTLE)
    assert np.isin(fv, mb.region).all() and mb.num_simulated < 0.5 * body.num_vertices
    tb, tf = KinematicTrajectory(body, anim), KinematicTrajectory(face, anim)
    sb, sf = FaceSystem(mb), FaceSystem(mf)
    wb, wf = automatic_window(sb, tb), automatic_window(sf, tf)
    # the region is the face plus a two-ring margin into neck and shoulders: a slightly larger diameter, so ε and
    # the window differ by the margin only (the body's own diagonal would give ε 3.5× larger and a far shorter δ)
    assert wb.window_s == pytest.approx(wf.window_s, rel=0.10)
    assert wb.acceleration_max_mps2 == pytest.approx(wf.acceleration_max_mps2, rel=1e-9)
    times = tb.frame_times[[16, 20, 30, 45]]
    db = np.linalg.norm(simulate_kd(sb, tb, times, wb.window_s) - tb.positions(times), axis=-1)
    df = np.linalg.norm(simulate_kd(sf, tf, times, wf.window_s) - tf.positions(times), axis=-1)
    assert db[:, fv].max() == pytest.approx(df.max(), rel=0.20)
    outside = np.setdiff1d(np.arange(body.num_vertices), mb.region)
    assert db[:, outside].max() <= POSITION_ATOL_M


# --- the region's x_K alone (issue 25 follow-up: the per-step work depends on the region only) --------------------

#: float64 round-off of a blend of up to K = 52 shapes and one LBS product: a few units in the last place of the
#: positions (about a metre from the origin), velocities and accelerations. With OpenBLAS the subset's products are
#: the full products' columns bit for bit; another BLAS may block a column subset differently.
ROUNDOFF = 16 * np.finfo(np.float64).eps


def assert_rows_match(sub, full, rows):
    """Every order of ``sub`` (T, R, 3) equals rows ``rows`` of ``full`` (T, N, 3) to float64 round-off."""
    for s, f in zip(sub, full, strict=True):
        f = f[:, rows]
        assert s.shape == f.shape
        np.testing.assert_allclose(s, f, rtol=0, atol=ROUNDOFF * max(1.0, float(np.abs(f).max())))


def inbetween_rig(rig: BlendshapeRig) -> BlendshapeRig:
    """``rig`` with an in-between target of jawOpen at weight 0.5 (60 % of the full shape, bent sideways a little)."""
    jaw = rig.shape_indices(["jawOpen"])[0]
    half = 0.6 * rig.deltas[jaw] + 0.002 * np.roll(rig.deltas[jaw], 1, axis=1)
    return BlendshapeRig.create(rig.neutral, np.concatenate([rig.deltas, half[None]]), rig.faces,
                                (*rig.shape_names, "jawHalfTarget"), skeleton=rig.skeleton, name=f"{rig.name}-ib",
                                inbetweens=[(jaw, (rig.num_shapes, jaw), (0.5, 1.0))])


@pytest.fixture(scope="module")
def makehuman_body():
    avatar_fixtures = pytest.importorskip("avatar_fixtures")
    if not avatar_fixtures.BODY_PATH.is_file():
        pytest.skip(f"{avatar_fixtures.BODY_PATH} is not built")
    return avatar_fixtures.load_body()


def test_a_restricted_trajectory_is_the_rows_of_the_full_one(bodies, short_demo, makehuman_body):
    # blend over the deltas' columns of the rows and LBS of the rows only; in-betweens, head drives (the demo) and a
    # joint-angle override all apply as in the full trajectory
    rig = inbetween_rig(bodies[20])
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(-0.2, 2.6, 21))  # before, inside and after the shot (curves clamp)
    for r, traj in ((rig, KinematicTrajectory(rig, short_demo)), (makehuman_body,
                                                                  KinematicTrajectory(makehuman_body, short_demo))):
        region = FaceModel.from_rig(r, **SETTLE).region
        assert region is not None
        for rows in (region, np.sort(rng.choice(r.num_vertices, 37, replace=False)), np.array([r.num_vertices - 1])):
            view = traj.restricted(rows)
            assert view.num_vertices == len(rows) and view.state_shape == (len(rows), 3)
            assert_rows_match(view.evaluate(t, 2), KinematicTrajectory(r, short_demo).evaluate(t, 2), rows)
            assert_rows_match(view.scan(t, 1), traj.scan(t, 1), rows)
    # the in-between changes the jaw's x_K (so it is exercised) and the restricted path follows it
    region = FaceModel.from_rig(rig, **SETTLE).region
    plain = KinematicTrajectory(bodies[20], short_demo).restricted(region).positions(t)
    assert np.abs(KinematicTrajectory(rig, short_demo).restricted(region).positions(t) - plain).max() > 1e-4


def test_restricted_samples_are_cached_per_vertex_set_and_never_stale(bodies, short_demo):
    body = bodies[20]
    traj = KinematicTrajectory(body, short_demo)
    a, b = np.arange(0, 400, 3), np.arange(100, 2000, 7)
    va, vb = traj.restricted(a), traj.restricted(b)
    assert traj.restricted(a.copy()) is va and va.version != vb.version != traj.version  # keyed by the set
    t = traj.frame_times[:20]
    first = va.evaluate(t, 2)
    assert len(va._cache) == 20 and len(traj._cache) == 0  # its own cache; the full one is left alone
    vb.evaluate(t, 1)
    again = va.evaluate(t[::-1], 2)  # from the cache, in the order asked for
    for x, y in zip(first, again):
        np.testing.assert_array_equal(x[::-1], y)
    full = traj.evaluate(t, 2)
    assert_rows_match(vb.evaluate(t, 2), full, b)
    assert_rows_match(again, tuple(f[::-1] for f in full), a)
    # the views of the last two sets are kept, and a set asked for again after that is evaluated afresh
    assert traj.restricted(b) is vb  # b the latest, then a third set pushes a out
    traj.restricted(np.arange(5))
    assert traj.restricted(b) is vb and traj.restricted(a) is not va
    sub = va.restricted(np.arange(0, len(a), 2))  # a subset of a subset is a view of the base over those rows
    assert_rows_match(sub.evaluate(t, 0), full[:1], a[::2])
    for bad in ([3, 1], [0, body.num_vertices], [], np.zeros((2, 2), np.int64)):
        with pytest.raises(KDInputError, match="vertices"):
            traj.restricted(np.asarray(bad, dtype=np.int64))


def test_a_restricted_corrected_trajectory_reads_its_correction_live(bodies, short_demo):
    from kdfaces.ikd import CorrectedTrajectory, Correction, GaussianBasis, Slot

    body = bodies[20]
    base = KinematicTrajectory(body, short_demo)
    n = body.num_vertices
    slots = [Slot(0.8, "position", GaussianBasis(0.8, 0.2)), Slot(1.2, "velocity", GaussianBasis(1.2, 0.2))]
    corr = Correction(slots, (n, 3))
    rng = np.random.default_rng(5)
    rows = FaceModel.from_rig(body, **SETTLE).region
    t = np.linspace(0.5, 1.5, 13)
    traj = CorrectedTrajectory(base, corr)
    view = traj.restricted(rows)
    assert view.num_vertices == len(rows) and view.state_shape == (len(rows), 3)
    for _ in range(2):  # the correction edited in place: the view's values and version follow
        corr.values[:] = 1e-3 * rng.standard_normal(corr.values.shape)
        corr.update()
        assert view.version == ("restricted", traj.version, view._key)
        assert_rows_match(view.evaluate(t, 2), traj.evaluate(t, 2), rows)
    bump = CorrectedTrajectory(base, corr, bump=(slots[1], 1e-3 * rng.standard_normal((n, 3))))
    bview = bump.restricted(rows)
    assert bview.version != view.version and bview.version[1] == bump.version
    assert_rows_match(bview.evaluate(t, 2), bump.evaluate(t, 2), rows)
    assert_rows_match(bview.scan(t, 1), bump.scan(t, 1), rows)


class CountingTrajectory(KinematicTrajectory):
    """A kinematic trajectory that records (times, vertex rows) of every evaluation it does."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.evaluated = []

    def _evaluate_chunk(self, t, order=2, rows=None):
        self.evaluated.append((len(t), self.rig.num_vertices if rows is None else rows.num_rows))
        return super()._evaluate_chunk(t, order, rows)


class FullOnly:
    """A trajectory without a subset path (the generic fallback slices its full evaluation): the old bake."""

    def __init__(self, traj):
        self.traj, self.num_vertices, self.version = traj, traj.num_vertices, None
        self.start, self.end, self.fps = traj.start, traj.end, traj.fps

    def evaluate(self, times, order=2):
        return self.traj.evaluate(times, order)


def test_a_body_evaluates_x_k_of_its_region_per_step_and_of_the_rest_per_observed_state(head, bodies, short_demo):
    body = bodies[60]
    model = FaceModel.from_rig(body, **SETTLE)
    region, rest = model.num_simulated, body.num_vertices - model.num_simulated
    traj = CountingTrajectory(body, short_demo)
    times = traj.frame_times[[8, 20, 45]]
    x = simulate_kd(FaceSystem(model), traj, times, 0.3)
    # every evaluation is the region's rows (the bake) or the rest's (observe, once per state): never all N
    assert {r for _, r in traj.evaluated} == {region, rest}
    assert sum(k for k, r in traj.evaluated if r == rest) == len(times)
    # the same KD states as the full evaluation sliced (the implementation before), bit for bit where the BLAS
    # sums a column subset as the whole (checked on x_K first), else to float32 round-off of the states
    old = simulate_kd(FaceSystem(model), FullOnly(KinematicTrajectory(body, short_demo)), times, 0.3)
    t_bake = np.arange(int(0.3 * short_demo.fps) + 1) / short_demo.fps + times[:, None]
    full = KinematicTrajectory(body, short_demo).scan(t_bake.ravel(), 1)
    sub = KinematicTrajectory(body, short_demo).restricted(model.region).scan(t_bake.ravel(), 1)
    if all(np.array_equal(s, f[:, model.region]) for s, f in zip(sub, full)):
        np.testing.assert_array_equal(x, old)
    else:
        np.testing.assert_allclose(x, old, rtol=0, atol=8 * np.finfo(np.float32).eps)
    np.testing.assert_array_equal(x[:, :head.num_vertices],
                                  simulate_kd(FaceSystem(FaceModel.from_rig(head, **SETTLE)),
                                              KinematicTrajectory(head, short_demo), times, 0.3))


def test_a_trajectory_without_a_subset_path_still_drives_a_region(bodies, short_demo):
    # any object with evaluate(times, order) is a trajectory: the bake slices its full evaluation
    body = bodies[20]
    model = FaceModel.from_rig(body, **SETTLE)
    traj = KinematicTrajectory(body, short_demo)
    times = traj.frame_times[[10, 30]]
    system = FaceSystem(model)
    x = simulate_kd(system, FullOnly(traj), times, 0.2)
    np.testing.assert_array_equal(x, simulate_kd(FaceSystem(model), traj, times, 0.2))
    state = system.initial_state(FullOnly(traj), times)  # not prepared: the fallback too
    x0, xk = system.observe(state), traj.positions(times)
    inside = model.region_mask
    np.testing.assert_array_equal(x0[:, inside], xk[:, inside].astype(np.float32))  # the state holds float32
    np.testing.assert_array_equal(x0[:, ~inside], xk[:, ~inside])


def test_a_bodys_work_estimate_counts_its_face_for_the_simulation(head, bodies):
    """estimate_work counts the simulated vertices (the moving region) for the KD and solve steps, and N for the
    outputs: a body's simulation estimate is its face's, its output memory is the body's."""
    import tomllib
    from pathlib import Path

    from kdfaces.shots.shotfile import estimate_work, parse_shot

    ref = Path(__file__).resolve().parent / "reference" / "shot.toml"
    data = tomllib.loads(ref.read_text())
    face = estimate_work(parse_shot(data, ref, rig=head))
    body = bodies[60]
    est = estimate_work(parse_shot(data, ref, rig=body))
    assert face.simulated == face.vertices == head.num_vertices
    assert est.simulated == FaceModel.from_rig(body, **SETTLE).num_simulated == head.num_vertices
    assert est.vertices == body.num_vertices > head.num_vertices
    assert (est.kd_steps, est.solve_steps, est.full_steps) == (face.kd_steps, face.solve_steps, face.full_steps)
    # the outputs (every vertex) and the window scan (it samples every vertex) scale with N
    assert est.memory_bytes * head.num_vertices == face.memory_bytes * body.num_vertices
    assert est.scan_steps * head.num_vertices == pytest.approx(face.scan_steps * body.num_vertices, rel=1e-12)
    for window in ("adaptive", 0.2):
        a, b = estimate_work(parse_shot(data, ref, rig=head), window_s=window), \
            estimate_work(parse_shot(data, ref, rig=body), window_s=window)
        assert (a.kd_steps, a.solve_steps, a.full_steps) == (b.kd_steps, b.solve_steps, b.full_steps)
