"""Face KD on a proxy, the dense mesh embedded (kdfaces.dynamics.proxy, issue #29).

The dense reference is the default head subdivided once by Loop (18,957 vertices) with the demo's dynamics; the
proxy has about 6,000 of its vertices. Reference KD states are costly (13 ms per state at 19k), so the accuracy
checks use every 5th frame of the demo (31 of 151) and every 90th frame of a 60 s synthetic Live Link Face capture
(20 of 1,800); ``benchmarks/bench_proxy.py`` measures every frame and the 75k face.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from kdfaces import KinematicTrajectory, simulate_kd
from kdfaces.defaults import EPSILON_FRACTION, PROXY_ABOVE_VERTICES
from kdfaces.dynamics import FaceModel, FaceSystem
from kdfaces.dynamics.proxy import FaceProxy, ProxyFaceSystem, build_proxy, proxy_rig
from kdfaces.errors import KDInputError

PROXY_VERTICES = 6_000
WINDOW_S = 0.8  # the demo's automatic window on this face (0.80 s dense, 0.80 s proxy)
FLOAT32_M = 4 * float(np.finfo(np.float32).eps) * 1.0  # float32 state round-off on a head within 1 m of the origin


@pytest.fixture(scope="module")
def dense_rig(default_rig):
    from kdfaces.rig import subdivide_rig

    return subdivide_rig(default_rig, 1)


@pytest.fixture(scope="module")
def demo(dense_rig):
    from kdfaces.shots.builtin import demo_animation
    from kdfaces.shots.demo import demo_face_model

    traj = KinematicTrajectory(dense_rig, demo_animation())
    dense = demo_face_model(dense_rig, proxy=None)
    proxy = demo_face_model(dense_rig, proxy=PROXY_VERTICES)  # W fitted (the default)
    return traj, dense, proxy


@pytest.fixture(scope="module")
def closest(dense_rig):
    """The same proxy with the shape-space W it is fitted from (proxy_embedding="closest")."""
    from kdfaces.shots.demo import demo_face_model

    return demo_face_model(dense_rig, proxy=PROXY_VERTICES, proxy_embedding="closest")


def _kd(model, traj, times):
    system = FaceSystem(model, threads=2)
    try:
        return simulate_kd(system, traj, times, WINDOW_S, step_s=1.0 / traj.fps)
    finally:
        system.close()


def test_the_proxy_is_a_vertex_subset_with_an_exact_embedding(dense_rig, demo, closest):
    from kdfaces.dynamics.proxy_fit import FIT_NEIGHBOURS

    _, dense, model = demo
    W, proxy = model.embedding, model.region
    n = dense_rig.num_vertices
    assert model.proxy and not dense.proxy
    assert 0.9 * PROXY_VERTICES <= len(proxy) <= 1.1 * PROXY_VERTICES
    np.testing.assert_array_equal(closest.region, proxy)  # the fit changes W only
    free = ~dense.rigid_mask
    # the shape-space W: identity rows on the proxy (its dense states are its own states); the fitted W fits
    # those rows too, about the identity (the proxy's own deviation carries most of its vertex's)
    assert (closest.embedding[proxy] != sp.identity(len(proxy), format="csr")).nnz == 0
    assert np.median(W[proxy].diagonal()) > 0.5
    for E, most in ((closest.embedding, 3), (W, FIT_NEIGHBOURS)):
        assert E.shape == (n, len(proxy)) and sp.isspmatrix_csr(E)
        # rows of the non-rigid vertices sum to one (a translation of the deviation is carried exactly) ...
        sums = np.asarray(E.sum(axis=1)).ravel()
        np.testing.assert_allclose(sums[free], 1.0, rtol=0, atol=1e-12)
        assert np.diff(E.indptr).max() <= most
        # ... and rigid parts (eyes, teeth) have zero rows: they follow x_K exactly
        assert dense.rigid_mask.any() and np.diff(E.indptr)[dense.rigid_mask].max() == 0
    # the shape-space W is barycentric: three non-negative weights; the fit carries the same vertices
    assert closest.embedding.data.min() >= 0.0
    np.testing.assert_array_equal(np.diff(W.indptr) > 0, np.diff(closest.embedding.indptr) > 0)
    # the dense face's ε: the diameter is the dense region's, and the proxy's masses are the dense mass (W^T m)
    assert model.diameter_m == dense.diameter_m
    np.testing.assert_allclose(model.mass[proxy].sum(), dense.mass[free].sum(), rtol=1e-12)
    # the settle-time map and gains are the dense model's, read at the proxy's vertices
    np.testing.assert_array_equal(model.kp[proxy], dense.kp[proxy])
    assert model.num_simulated == len(proxy) and model.clusters.num_clusters > 0


def test_the_proxys_clusters_are_the_dense_clusters_restricted(dense_rig, demo):
    _, dense, model = demo

    def member_sets(clusters):
        return [frozenset(clusters.members[a:b].tolist()) for a, b in zip(clusters.offsets[:-1],
                                                                          clusters.offsets[1:], strict=True)]

    proxy = frozenset(model.region.tolist())
    ours = member_sets(model.clusters)
    assert len(set(ours)) == len(ours)  # no cluster twice
    # exactly the dense clusters with three or more proxy members, restricted to the proxy
    restricted = {s for s in (c & proxy for c in member_sets(dense.clusters)) if len(s) >= 3}
    assert set(ours) == restricted
    # they cover most of the proxy (the others track x_K by PD alone); members are proxy vertices only
    covered = frozenset().union(*ours)
    assert covered <= proxy and len(covered) > 0.9 * len(proxy), len(covered) / len(proxy)
    assert model.shape_matching_alpha == dense.shape_matching_alpha > 0
    # shape matching off: no clusters, as on the dense model
    px = FaceProxy(vertices=model.region, faces=np.searchsorted(model.region, model.proxy_faces),
                   weights=model.embedding)
    assert FaceModel.from_rig(dense_rig, proxy=px, shape_matching_alpha=0.0,
                              proxy_embedding="closest").clusters.num_clusters == 0
    with pytest.raises(KDInputError, match="shape_matching_alpha"):
        FaceModel.from_rig(dense_rig, proxy=px, shape_matching_alpha=1.5)


def test_the_shape_space_fit_is_the_closest_point_of_the_triangle():
    from kdfaces.rig.proxy import _simplex_fit

    rng = np.random.default_rng(3)
    m, d = 400, 7
    corners = rng.normal(size=(m, 3, d))
    # a point of the triangle (weights drawn on the simplex) is its own closest point
    w0 = rng.dirichlet(np.ones(3), size=m)
    w, e = _simplex_fit(corners, np.einsum("mj,mjd->md", w0, corners))
    np.testing.assert_allclose(w, w0, rtol=0, atol=1e-9)  # normal equations of O(1) edges: round-off ~1e-15 × cond
    assert e.max() <= 1e-20
    # any point: the weights lie on the simplex and satisfy its optimality (KKT) conditions: the gradient
    # g_j = c_j · (Σ w c − x) equals its least value on every corner with weight > 0 and is no smaller elsewhere
    x = 2.0 * rng.normal(size=(m, d))
    w, e = _simplex_fit(corners, x)
    assert w.min() >= 0.0
    np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    r = np.einsum("mj,mjd->md", w, corners) - x
    np.testing.assert_allclose(e, (r * r).sum(axis=1), rtol=1e-12)
    g = np.einsum("mjd,md->mj", corners, r)
    lam = g.min(axis=1, keepdims=True)
    tol = 1e-9 * (1.0 + np.abs(g).max())  # O(1) data: the candidates' round-off, far below any active-set gap
    assert (np.where(w > 1e-12, g - lam, 0.0) <= tol).all()
    # and no other point of the triangle is closer (a grid of 1,326 weights on the simplex)
    a, b = np.meshgrid(np.linspace(0, 1, 51), np.linspace(0, 1, 51))
    grid = np.stack([1 - a - b, a, b], axis=-1).reshape(-1, 3)
    grid = grid[grid.min(axis=1) >= -1e-12]
    grid_e = (((grid @ corners[:20]) - x[:20, None]) ** 2).sum(-1).min(axis=1)
    assert (e[:20] <= grid_e + 1e-12).all()


def test_the_settle_time_map_is_a_coordinate_of_the_proxys_shape_space(default_rig):
    from kdfaces.rig.proxy import SETTLE_TIME_FEATURE_M_PER_S, settle_time_features, shape_features
    from kdfaces.shots.demo import demo_face_model

    n = default_rig.num_vertices
    # a scalar or constant settle time is no coordinate (it moves no vertex nearer to another); a map is λ·t̂ [m]
    assert settle_time_features(None, n) is None and settle_time_features(0.4, n) is None
    assert settle_time_features(np.full(n, 0.4), n) is None
    dense = demo_face_model(default_rig, proxy=None)
    t = dense.settle_time_s
    assert np.ptp(t) > 0.3  # the demo's soft-tissue map: 0.25 s over bone to 0.6 s in the lips
    feat = settle_time_features(t, n)
    np.testing.assert_array_equal(feat, SETTLE_TIME_FEATURE_M_PER_S * t[:, None])
    # extra coordinates follow the shape features' principal components, centred as they are
    base = shape_features(default_rig.neutral, default_rig.deltas)
    ext = shape_features(default_rig.neutral, default_rig.deltas, feat)
    np.testing.assert_array_equal(ext[:, :-1], base)
    np.testing.assert_allclose(ext[:, -1], feat[:, 0] - feat[:, 0].mean(), rtol=0, atol=1e-15)
    with pytest.raises(KDInputError, match="proxy features"):
        shape_features(default_rig.neutral, default_rig.deltas, np.ones((n - 1, 1)))
    # from_rig builds the proxy with the model's settle-time map as that coordinate ...
    simulated = dense.region_mask & ~dense.rigid_mask
    model = demo_face_model(default_rig, proxy=2_000, proxy_embedding="closest")
    px = build_proxy(default_rig.neutral, default_rig.faces, simulated, 2_000, default_rig.deltas, feat)
    np.testing.assert_array_equal(model.region, px.vertices)
    assert (model.embedding != px.weights).nnz == 0
    # ... so W's weights sit on corners of about a vertex's own settle time (its gains, On the Beat §4.1, eq. 4): W
    # carries the map itself within 7 ms, against 25 ms without it (the demo's map on the default head, 2k proxy)
    plain = build_proxy(default_rig.neutral, default_rig.faces, simulated, 2_000, default_rig.deltas)
    carried = {name: np.abs(p.weights @ t[p.vertices] - t)[simulated].max() for name, p in (("map", px),
                                                                                          ("plain", plain))}
    assert carried["map"] <= 0.5 * carried["plain"], carried


def test_the_proxy_rig_is_the_dense_rigs_rows(dense_rig, demo):
    traj, _, model = demo
    proxy = FaceProxy(vertices=model.region, faces=np.searchsorted(model.region, model.proxy_faces),
                      weights=model.embedding)
    small = proxy_rig(dense_rig, proxy)
    assert small.num_vertices == len(model.region) and small.num_shapes == dense_rig.num_shapes
    t = traj.frame_times[[10, 60, 120]]
    x_small = KinematicTrajectory(small, traj.animation).evaluate(t, order=1)
    x_dense = traj.evaluate(t, order=1)
    for a, b in zip(x_small, x_dense, strict=True):
        np.testing.assert_allclose(a, b[:, model.region], rtol=0, atol=1e-12)


def test_auto_is_off_for_the_default_head_and_bit_identical(default_rig):
    from kdfaces.shots.builtin import demo_animation
    from kdfaces.shots.demo import demo_face_model

    assert default_rig.num_vertices <= PROXY_ABOVE_VERTICES
    auto, off = demo_face_model(default_rig), demo_face_model(default_rig, proxy=None)
    assert auto.embedding is None and off.embedding is None
    for name in ("mass", "kp", "kd", "settle_time_s"):
        np.testing.assert_array_equal(getattr(auto, name), getattr(off, name))
    np.testing.assert_array_equal(auto.clusters.members, off.clusters.members)
    traj = KinematicTrajectory(default_rig, demo_animation())
    sys_auto = FaceSystem(auto)
    assert type(sys_auto) is FaceSystem
    t = traj.frame_times[[30, 75]]
    np.testing.assert_array_equal(simulate_kd(sys_auto, traj, t, WINDOW_S), simulate_kd(FaceSystem(off), traj, t,
                                                                                        WINDOW_S))


def test_the_proxy_system_observes_the_dense_mesh(demo):
    traj, dense, model = demo
    system = FaceSystem(model, threads=1)
    assert isinstance(system, ProxyFaceSystem) and system.num_simulated == len(model.region)
    t = traj.frame_times[[50, 100]]
    x = simulate_kd(system, traj, t, WINDOW_S)
    xk = traj.evaluate(t, order=0)[0]
    assert x.shape == xk.shape
    # rigid parts and every vertex W leaves out follow x_K (float64 x_K, not the float32 state); the dense pose is
    # PoseSampler's kernel, the trajectory's sums in another order: float64 round-off of a 1 m head (~1e-16 m)
    still = np.diff(model.embedding.indptr) == 0
    np.testing.assert_allclose(x[:, still], xk[:, still], rtol=0, atol=1e-12)
    # every other vertex is x_K + W (x_proxy − x_K,proxy), the proxy's own (W fits their rows too) and the carried
    # ones, with x_proxy the state (float32). The carry's weights and deviations are float32 and summed in float32
    # (kdfaces.dynamics.carry): each of a row's K products and K sums rounds by at most 2^-24 relative, so a row
    # is within (2K + 2)·2^-24·Σ_j |w_j||d_j| of the float64 product (rounding w and d: 2 more)
    from kdfaces.kd import step_states, time_steps

    h = 1.0 / traj.fps
    n = int(time_steps(system, traj, t, WINDOW_S, h)[0])
    state = step_states(system, traj, t - n * h, n, h)  # the proxy's state: its positions in the region's order
    d = system._positions(state).astype(np.float64) - xk[:, model.region]
    width = int(np.diff(model.embedding.indptr).max())
    for b in range(len(t)):
        bound = 1e-12 + (2 * width + 2) * 2.0 ** -24 * (abs(model.embedding) @ np.abs(d[b]))[~still]
        err = np.abs(x[b, ~still] - (xk[b, ~still] + (model.embedding @ d[b])[~still]))
        assert (err <= bound).all(), float((err / bound).max())
    # the deviation rows simulated_kinematic names are exactly the vertices that differ from x_K
    rows, xs = system.simulated_kinematic(traj, t)
    differ = np.flatnonzero(np.abs(x - xk).max(axis=(0, 2)) > 1e-12)  # beyond the pose's round-off (above)
    assert np.isin(differ, rows).all()
    np.testing.assert_array_equal(xs, xk[:, rows])
    system.close()
    # the scrub path (one state, two threads: the dense pose on a worker during the steps) gives the same bits
    # as the batch on one thread
    system = FaceSystem(model, threads=2)
    for b in range(len(t)):
        np.testing.assert_array_equal(simulate_kd(system, traj, t[b:b + 1], WINDOW_S)[0], x[b])
    system.close()


@pytest.mark.parametrize("narrow", [True, False])
def test_the_carry_kernel_is_the_sparse_product(narrow):
    """The fixed-width carry (uint16 or int32 columns) adds W d to the carried rows: rows of any length (zero
    padding), a batch of times, the rows it does not carry untouched; float32 sums within the bound above."""
    import warp as wp

    from kdfaces.dynamics.carry import CARRY_BLOCK_ROWS, carry_kernel, padded_rows

    rng = np.random.default_rng(3)
    E, P, N, T = 3 * CARRY_BLOCK_ROWS + 17, 300, 1200, 3
    W = sp.random(E, P, density=0.02, random_state=4, format="csr", data_rvs=lambda k: rng.normal(size=k))
    cols, vals = padded_rows(W)
    assert cols.shape == vals.shape == (E, max(1, int(np.diff(W.indptr).max())))
    np.testing.assert_array_equal(sp.csr_matrix((vals.ravel(), cols.ravel(), np.arange(0, cols.size + 1,
                                                                                        cols.shape[1])),
                                                shape=W.shape).toarray(), W.toarray())
    carried = rng.choice(N, E, replace=False).astype(np.int32)
    dev = rng.normal(size=(T, P, 3)) * 1e-2
    xk = rng.normal(size=(T, N, 3))
    out = xk.copy()
    kernel = carry_kernel(cols.shape[1], narrow)
    wp.launch(kernel, dim=-(-E // CARRY_BLOCK_ROWS), inputs=[
        0, wp.array(carried, dtype=wp.int32), wp.array(cols.astype(np.uint16 if narrow else np.int32),
                                                       dtype=wp.uint16 if narrow else wp.int32),
        wp.array(vals.astype(np.float32), dtype=wp.float32), wp.array(dev.astype(np.float32), dtype=wp.vec3),
        wp.array(out, dtype=wp.vec3d, copy=False)], device="cpu")
    rest = np.setdiff1d(np.arange(N), carried)
    np.testing.assert_array_equal(out[:, rest], xk[:, rest])
    for t in range(T):
        want = xk[t, carried] + W @ dev[t]
        bound = 1e-15 + (2 * cols.shape[1] + 2) * 2.0 ** -24 * (abs(W) @ np.abs(dev[t]))
        assert (np.abs(out[t, carried] - want) <= bound).all()


def _accuracy(traj, dense, models, times):
    """Per model, |x_model − x_dense| (T, N) [m]; and |x_dense − x_K| (T, N) [m]."""
    x_dense = _kd(dense, traj, times)
    xk = traj.evaluate(times, order=0)[0]
    return [np.linalg.norm(_kd(m, traj, times) - x_dense, axis=-1) for m in models], \
        np.linalg.norm(x_dense - xk, axis=-1)


#: The proxy's error relative to ε; the issue asks for ε/2 on every frame. W is fitted, the proxy's own rows
#: included, to the dense and proxy KD states of the excitation take (kdfaces.dynamics.proxy_fit), which shares
#: nothing with these takes. Measured on these frames (demo, capture): 0.193, 0.227 ε in all, 0.049, 0.073 ε at the
#: 99th percentile, 0.121, 0.164 ε at the proxy's own vertices (on every frame: 0.19, 0.46 ε; docs/dense-rigs.md).
#: With the shape-space W (proxy_embedding="closest", identity rows on the proxy): 0.699, 0.684 ε, 0.221, 0.293 ε
#: and 0.376, 0.400 ε; its largest errors sit around the mouth, where the deviation changes by ~10 mm over a
#: centimetre. The bounds hold what is reached with ~20 % margin, so that a regression fails; the fit must at least
#: cut the 99th percentile to 0.4 of the shape-space W's.
P99_FRACTION, MAX_FRACTION, PROXY_VERTEX_FRACTION = 0.09, 0.28, 0.20
FIT_GAIN = 0.4


@pytest.mark.parametrize("take", ["demo", "capture"])
def test_proxy_kd_states_are_close_to_the_dense_kd_states(take, demo, closest, dense_rig, tmp_path):
    traj, dense, model = demo
    if take == "demo":
        times = traj.frame_times[::5]
    else:
        from avatar_fixtures import write_livelink_take

        from kdfaces import livelinkface_animation

        path = write_livelink_take(tmp_path / "take.csv", 60.0, fps=30, seed=5)
        traj = KinematicTrajectory(dense_rig, livelinkface_animation(path))
        times = traj.frame_times[::90]
    eps = EPSILON_FRACTION * dense.diameter_m
    (err, base), dev = _accuracy(traj, dense, (model, closest), times)
    assert dev.max() > 10 * eps  # the face deviates: the comparison is not between two copies of x_K
    per_vertex = err.max(axis=0)
    assert np.quantile(per_vertex, 0.99) <= P99_FRACTION * eps, np.quantile(per_vertex, 0.99) / eps
    assert err.max() <= MAX_FRACTION * eps < 0.5 * eps, err.max() / eps
    # the proxy's own vertices: its dynamics, their rows of W fitted too
    assert err[:, model.region].max() <= PROXY_VERTEX_FRACTION * eps, err[:, model.region].max() / eps
    # the fitted W against the shape-space W it starts from, on the same proxy
    assert np.quantile(per_vertex, 0.99) <= FIT_GAIN * np.quantile(base.max(axis=0), 0.99), \
        (np.quantile(per_vertex, 0.99) / eps, np.quantile(base.max(axis=0), 0.99) / eps)


def test_ikd_on_the_proxy_meets_the_constraints_on_the_dense_mesh(dense_rig, demo):
    from kdfaces.ikd import solve_ikd
    from kdfaces.shots.demo import DEMO_SHOT
    from kdfaces.shots.shotfile import load_shot

    traj, _, model = demo
    shot = load_shot(DEMO_SHOT, rig=dense_rig)
    constraints = shot.constraints(traj)  # the demo's four: chin end effector, tilted-smile pose, lips, brows velocity
    assert {c.kind for c in constraints} == {"end_effector", "pose", "subset", "velocity"}
    options = shot.solver_options()
    system = FaceSystem(model, threads=2)
    res = solve_ikd(system, traj, constraints, window_s=WINDOW_S, step_s=1.0 / traj.fps, **options)
    assert res.converged, res.reason
    # the positions measured again on the dense KD states of the corrected trajectory (every dense vertex a
    # constraint names: the pose constraint names all of them, carried ones included)
    h = 1.0 / traj.fps
    x = simulate_kd(system, res.trajectory, np.array([c.time_s for c in constraints]), WINDOW_S, step_s=h)
    for c, xc, tol in zip(constraints, x, res.history[-1], strict=True):
        if c.kind == "end_effector":
            err = np.linalg.norm(c.weights @ xc[c.indices] - c.target)
        elif c.kind == "velocity":
            assert tol <= options["tolerance_mps"], (c.label, tol)
            continue
        else:
            err = np.linalg.norm(xc[c.indices] - c.target, axis=1).max()
        assert err <= options["tolerance_m"] + FLOAT32_M, (c.label, err)
    system.close()


def test_bad_proxies_are_one_clear_error(dense_rig, default_rig):
    with pytest.raises(KDInputError, match="proxy: expected a vertex count"):
        FaceModel.from_rig(default_rig, proxy=10)
    with pytest.raises(KDInputError, match="proxy: expected 'auto'"):
        FaceModel.from_rig(default_rig, proxy="coarse")
    with pytest.raises(KDInputError, match="proxy_embedding: expected one of"):
        FaceModel.from_rig(default_rig, proxy=2_000, proxy_embedding="nearest")
    with pytest.raises(KDInputError, match="not more than the proxy's"):
        FaceModel.from_rig(default_rig, proxy=10_000)
    px = build_proxy(default_rig.neutral, default_rig.faces, np.ones(default_rig.num_vertices, bool), 2_000)
    with pytest.raises(KDInputError, match="built for a rig of"):
        FaceModel.from_rig(dense_rig, proxy=px)


def test_windows_work_unchanged_on_the_proxy(demo):
    from kdfaces.window import adaptive_windows, automatic_window

    traj, dense, model = demo
    sp_, sd = FaceSystem(model, threads=1), FaceSystem(dense, threads=1)
    h = 1.0 / traj.fps
    # the automatic window scans the proxy's vertices (a subset of the dense region): the same window within a step
    assert abs(automatic_window(sp_, traj).window_s - automatic_window(sd, traj).window_s) <= h
    t = traj.frame_times[20::30]
    steps_p, steps_d = adaptive_windows(sp_, traj, t).steps, adaptive_windows(sd, traj, t).steps
    assert np.abs(steps_p - steps_d).max() <= 1 and steps_p.max() > 0
    sp_.close()
    sd.close()
