"""Face dynamics against closed forms: one PD particle (step, constant acceleration), uniform translation,
steady rotation, gains, clusters, stability and blow-up detection."""

from __future__ import annotations

import numpy as np
import pytest

from kdfaces.dynamics import FaceModel, FaceSystem, gains_from_settle_time, ring_clusters, time_constant
from kdfaces.errors import KDInputError, SimulationBlowUpError
from kdfaces.kd import simulate_full, simulate_kd

EPS32 = float(np.finfo(np.float32).eps)


class AnalyticTrajectory:
    """x_K(t) = f(t) for callables returning (T, N, 3) positions and velocities; defined on [start, end]."""

    def __init__(self, pos, vel, num_vertices, start=0.0, end=10.0):
        self.pos, self.vel = pos, vel
        self.num_vertices, self.start, self.end = num_vertices, start, end

    def evaluate(self, times, order=1):
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        return (self.pos(t), self.vel(t))[: order + 1]


def particle(settle, zeta, damping="relative"):
    model = FaceModel.create(np.zeros((1, 3)), np.zeros((0, 3), np.int64), settle_time_s=settle, damping_ratio=zeta,
                             shape_matching_alpha=0.0, mass=1.0, damping_mode=damping)
    return model, FaceSystem(model)


def oscillator(t, u0, v0, omega, zeta, f0=0.0, f1=0.0):
    """u'' + 2ζω u' + ω² u = f0 + f1 t (ζ < 1), u(0) = u0, u'(0) = v0 → (u, u', u'', u''')."""
    B = f1 / omega**2
    A = (f0 - 2 * zeta * omega * B) / omega**2
    a, b = u0 - A, v0 - B  # homogeneous part's initial conditions
    g, wd = -zeta * omega, omega * np.sqrt(1 - zeta**2)
    # u_h = e^{gt}(a cos wd t + c sin wd t), derivatives by the complex exponential s = g + i wd
    c = (b - g * a) / wd
    s = g + 1j * wd
    z = (a - 1j * c) * np.exp(s * t)  # u_h = Re z
    out = [np.real(z) + A + B * t, np.real(s * z) + B, np.real(s**2 * z), np.real(s**3 * z)]
    return out


def backward_euler_bound(t, derivs, omega, h):
    """Global error bound of backward Euler on the damped oscillator, for u [m].

    Backward Euler is contractive in the energy norm ‖(u, u')‖_E = √(ω²u² + u'²) for a damped oscillator, so the
    global error is at most the sum of local errors, each ≤ (h²/2)·max‖y''‖_E with y = (u, u'):
    |e_u| ≤ ‖e‖_E/ω ≤ (t_end·h/2)·max √(ω²u''² + u'''²)/ω. The PD tracking error u = x − x_K obeys that ODE.
    """
    return t[-1] * h / 2 * np.max(np.sqrt(omega**2 * derivs[2] ** 2 + derivs[3] ** 2)) / omega


@pytest.mark.parametrize("case", ["step", "acceleration", "acceleration_absolute"])
def test_particle_matches_driven_damped_oscillator(case):
    settle, zeta, a = 0.5, 0.3, 2.0
    omega = 1.0 / time_constant(settle)
    damping = "absolute" if case.endswith("absolute") else "relative"
    if case == "step":  # target jumps from 0 to 1 m just after t = 0 (ẋ_K = 0): u(0) = −1
        pos = lambda t: np.where(t > 0, 1.0, 0.0)[:, None, None] * np.array([1.0, 0, 0])  # noqa: E731
        vel = lambda t: np.zeros((len(t), 1, 3))  # noqa: E731
        u0, f0, f1 = -1.0, 0.0, 0.0
    else:  # x_K = a t²/2 from rest: u'' + 2ζωu' + ω²u = −a (relative), −a − 2ζω a t (absolute damping)
        pos = lambda t: (0.5 * a * t**2)[:, None, None] * np.array([1.0, 0, 0])  # noqa: E731
        vel = lambda t: (a * t)[:, None, None] * np.array([1.0, 0, 0])  # noqa: E731
        u0, f0, f1 = 0.0, -a, (-2 * zeta * omega * a if damping == "absolute" else 0.0)
    traj = AnalyticTrajectory(pos, vel, 1, end=2.0)
    errors = []
    for h in (1 / 100, 1 / 200):
        _, system = particle(settle, zeta, damping)
        t = np.arange(1, int(round(2.0 / h)) + 1) * h
        x = simulate_full(system, traj, t, step_s=h)[:, 0, 0]
        derivs = oscillator(t, u0, 0.0, omega, zeta, f0, f1)
        exact = derivs[0] + pos(t)[:, 0, 0]
        err = np.abs(x - exact).max()
        # float32 state: add ~100 steps' worth of rounding at the largest |x|
        assert err <= backward_euler_bound(t, derivs, omega, h) + 1e2 * EPS32 * np.abs(exact).max(), (case, h)
        errors.append(err)
    assert 1.6 < errors[0] / errors[1] < 2.4, errors  # first order: halving h halves the error


def test_absolute_damping_lags_constant_velocity_by_kd_over_kp():
    # m ẍ = kp (x_K − x) − kd ẋ at ẋ = c: x_K − x = kd c / kp, exactly also for the implicit step
    c, zeta, settle = 0.3, 0.7, 0.2
    _, system = particle(settle, zeta, "absolute")
    traj = AnalyticTrajectory(lambda t: (c * t)[:, None, None] * np.array([0, 1.0, 0]),
                              lambda t: np.full((len(t), 1, 3), [0, c, 0]), 1, end=3.0)
    x = simulate_full(system, traj, [3.0], step_s=0.04)[0, 0]
    lag = 2 * zeta * time_constant(settle) * c
    np.testing.assert_allclose(3.0 * c - x[1], lag, rtol=1e-4)


def grid_mesh(n=6, size=0.1):
    """A gently curved n×n grid patch [m] and its triangles."""
    u, v = np.meshgrid(np.linspace(-size / 2, size / 2, n), np.linspace(-size / 2, size / 2, n))
    verts = np.stack([u.ravel(), v.ravel(), 2.0 * (u**2 + v**2).ravel()], axis=1) + np.array([0.1, 0.6, 0.15])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return verts, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


@pytest.mark.parametrize("rotation", ["svd3", "iterative"])
def test_uniform_translation_leaves_kd_on_kinematic(rotation):
    verts, faces = grid_mesh()
    vel = np.array([0.4, -0.2, 0.3])
    model = FaceModel.create(verts, faces, settle_time_s=0.1, damping_ratio=0.3, shape_matching_alpha=0.5, rings=1,
                             cluster_centers="all", rotation=rotation)
    traj = AnalyticTrajectory(lambda t: verts[None] + t[:, None, None] * vel,
                              lambda t: np.broadcast_to(vel, (len(t), len(verts), 3)), len(verts), end=2.0)
    times = np.arange(1, 51) * 0.04
    x = simulate_kd(FaceSystem(model), traj, times, 1.0, step_s=0.04)
    # the exact solution is x = x_K; float32 rounding of |x| ≤ 1.2 m, a few operations per step, does not grow
    # (the step is contractive): allow 50 ulp
    np.testing.assert_allclose(x, traj.evaluate(times)[0], rtol=0, atol=50 * EPS32 * 1.2)


def rotating_steady_state(r, Omega, k, c, h):
    """Discrete steady state of the implicit PD step for x_K = R_y(Ωt) r: x_n = R(Ωnh) X, v_n = R(Ωnh) V.

    Step: v'(1 + hc + h²k) = v + hk (x_K' − x) + hc ẋ_K',  x' = x + h v'. With Q = R_y(Ωh) and ẋ_K = Ω ŷ × x_K:
    (1 + hc + h²k) Q V = V + hk (Q r − X) + hc Q (Ω ŷ × r),   Q X = X + h Q V   — a 6×6 linear system per vertex.
    """
    cs, sn = np.cos(Omega * h), np.sin(Omega * h)
    Q = np.array([[cs, 0, sn], [0, 1, 0], [-sn, 0, cs]])
    I3 = np.eye(3)
    M = np.block([[h * k * I3, (1 + h * c + h * h * k) * Q - I3], [Q - I3, -h * Q]])
    w = Omega * np.cross([0, 1.0, 0], r)
    rhs = np.concatenate([h * k * (Q @ r) + h * c * (Q @ w), np.zeros(3)])
    return np.linalg.solve(M, rhs)[:3]


def test_steady_rotation_offset_is_centripetal_over_omega_squared():
    # no shape matching: each vertex is an independent PD particle on a circle about the y axis
    rng = np.random.default_rng(1)
    verts = rng.uniform(-0.1, 0.1, size=(40, 3))
    Omega, settle, zeta, h = 2.0, 0.3, 0.3, 0.01
    model = FaceModel.create(verts, np.zeros((0, 3), np.int64), settle_time_s=settle, damping_ratio=zeta,
                             shape_matching_alpha=0.0, mass=1.0)

    def rot(t):
        cs, sn = np.cos(Omega * t), np.sin(Omega * t)
        z, o = np.zeros_like(t), np.ones_like(t)
        return np.stack([np.stack([cs, z, sn], -1), np.stack([z, o, z], -1), np.stack([-sn, z, cs], -1)], -2)

    traj = AnalyticTrajectory(lambda t: np.einsum("tij,nj->tni", rot(t), verts),
                              lambda t: np.einsum("tij,nj->tni", rot(t), Omega * np.cross([0, 1.0, 0], verts)),
                              len(verts), end=4.0)
    t_end = 4.0  # transient decays as e^{−ζωt}, ζω = 3.2/s: e^{−12.6} ≈ 3e-6 of the initial lag
    x = simulate_full(FaceSystem(model), traj, [t_end], step_s=h)[0]
    k, c = model.kp[0], model.kd[0]
    R = rot(np.array([t_end]))[0]
    expect = np.stack([R @ rotating_steady_state(r, Omega, k, c, h) for r in verts])
    offset = expect - traj.evaluate([t_end])[0][0]
    np.testing.assert_allclose(x, expect, rtol=0, atol=1e-5 * np.abs(offset).max() + 200 * EPS32 * 0.2)
    # the discrete steady offset tends to the continuous one, Ω² r⊥ / (ω² − Ω² + 2iζωΩ) in the rotating plane
    # (≈ centripetal acceleration / ω_n² for Ω ≪ ω_n), with backward Euler's O(h) error
    omega = np.sqrt(k)
    r_perp = verts * np.array([1.0, 0, 1.0])
    for hh in (1e-3, 1e-4):
        u = np.stack([rotating_steady_state(r, Omega, k, c, hh) for r in verts]) - verts
        z = Omega**2 / (omega**2 - Omega**2 + 2j * zeta * omega * Omega)  # outward (Re) and along motion (Im)
        cont = np.real(z) * r_perp + np.imag(z) * np.cross([0, 1.0, 0], verts)
        np.testing.assert_allclose(u, cont, rtol=0, atol=5 * hh * omega * np.abs(cont).max())
    centripetal = Omega**2 * r_perp
    np.testing.assert_allclose(np.real(z) * r_perp, centripetal / omega**2,
                               rtol=0, atol=3 * (Omega / omega) ** 2 * np.abs(centripetal / omega**2).max())


def test_gains_follow_on_the_beat_eq4():
    kp, kd = gains_from_settle_time(0.5, damping_ratio=1.0)  # eq. 4 as published: critically damped
    lam = 0.5 / (-1 / np.log(0.9))
    np.testing.assert_allclose([kp, kd], [1 / lam**2, 2 / lam])
    # critically damped: the error e(t) = (1 + t/λ) e^{−t/λ}; with ζ it keeps ω_n and scales damping
    kp3, kd3 = gains_from_settle_time(np.array([0.5, 1.0]), damping_ratio=0.3)
    np.testing.assert_allclose(kd3 / (2 * np.sqrt(kp3)), 0.3)
    for bad in (0.0, -1.0, np.nan):
        with pytest.raises(KDInputError, match="settle_time"):
            gains_from_settle_time(bad)


def test_ring_clusters_match_mesh_neighbourhoods():
    verts, faces = grid_mesh(5)
    cl = ring_clusters(faces, len(verts), rings=1)
    # interior vertex of a triangulated grid with one diagonal direction has 6 neighbours + itself
    centre = 12
    members = set(cl.members[cl.offsets[centre]:cl.offsets[centre + 1]])
    edges = {tuple(sorted(e)) for f in faces for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
    expect = {centre} | {a if b == centre else b for a, b in edges if centre in (a, b)}
    assert members == expect
    # the vertex → cluster map is the transpose
    for v in range(len(verts)):
        for c in cl.vertex_clusters[cl.vertex_offsets[v]:cl.vertex_offsets[v + 1]]:
            assert v in cl.members[cl.offsets[c]:cl.offsets[c + 1]]
    cover = ring_clusters(faces, len(verts), rings=2, centers="cover")
    assert cover.num_clusters < len(verts)
    assert (np.diff(cover.vertex_offsets) >= 1).all()  # every vertex lies in a cluster


def test_stable_at_25hz_for_short_settle_times():
    verts, faces = grid_mesh()
    rng = np.random.default_rng(0)
    noise = rng.normal(size=(len(verts), 3))
    traj = AnalyticTrajectory(lambda t: verts[None] + 0.02 * np.sin(40 * t)[:, None, None] * noise,
                              lambda t: 0.8 * np.cos(40 * t)[:, None, None] * noise, len(verts), end=4.0)
    for zeta in (0.1, 1.0):
        model = FaceModel.create(verts, faces, settle_time_s=0.05, damping_ratio=zeta, shape_matching_alpha=1.0,
                                 rings=1,
                                 cluster_centers="all")
        x = simulate_full(FaceSystem(model), traj, np.arange(1, 101) * 0.04, step_s=0.04)
        # a stable step keeps the state near the ±2 cm target motion: bounded by a few target amplitudes
        assert np.isfinite(x).all()
        assert np.abs(x - traj.evaluate(np.arange(1, 101) * 0.04)[0]).max() < 0.1


def test_blow_up_and_bad_input_raise_one_clear_error():
    verts, faces = grid_mesh()
    still = AnalyticTrajectory(lambda t: np.broadcast_to(verts, (len(t), len(verts), 3)),
                               lambda t: np.zeros((len(t), len(verts), 3)), len(verts), end=1.0)
    system = FaceSystem(FaceModel.create(verts, faces), check_every=1)
    for poke, what in ((np.nan, "position not finite"), (1e3, "beyond")):
        system.prepare(still, np.zeros(1), 10, 0.04)
        state = system.initial_state(still, np.zeros(1))
        for k in range(3):
            system.step(state, still, np.array([k * 0.04]), 0.04)
        x = state.chunks[0].x.numpy()
        x[0, 7] = poke
        state.chunks[0].x.assign(x)
        with pytest.raises(SimulationBlowUpError, match=f"{what}.* at t = 0.16 s"):
            system.step(state, still, np.array([0.12]), 0.04)
    broken = AnalyticTrajectory(lambda t: np.where(t[:, None, None] > 0.5, np.nan, verts[None]),
                                lambda t: np.zeros((len(t), len(verts), 3)), len(verts), end=1.0)
    with pytest.raises(KDInputError, match="not finite at t = 0.52"):
        simulate_full(system, broken, [1.0], step_s=0.04)
    with pytest.raises(KDInputError, match="mass"):
        FaceModel.create(verts, faces, mass=0.0)
    with pytest.raises(KDInputError, match="settle_time"):
        FaceModel.create(verts, faces, settle_time_s=np.full(len(verts), -0.1))
    with pytest.raises(KDInputError, match="vertices"):
        FaceSystem(FaceModel.create(verts[:-1], faces[:0])).initial_state(still, np.zeros(1))


def test_full_simulation_reaches_times_between_grid_points_by_a_partial_step():
    """simulate_full at any time: grid times as before, a time between grid points by one shorter step from the grid
    point before it — equal, bit for bit, to stepping there with that shorter step, and as accurate as a grid time
    (backward Euler, error O(h)) against the driven oscillator."""
    settle, zeta, a = 0.5, 0.3, 2.0
    omega = 1.0 / time_constant(settle)
    pos = lambda t: (0.5 * a * t**2)[:, None, None] * np.array([1.0, 0, 0])  # noqa: E731
    vel = lambda t: (a * t)[:, None, None] * np.array([1.0, 0, 0])  # noqa: E731
    traj = AnalyticTrajectory(pos, vel, 1, end=2.0)
    h = 0.01
    _, system = particle(settle, zeta, "relative")
    t = np.array([1.0, 1.0037, 1.5, 1.2061])  # two grid times, two between them (out of order on purpose)
    x = simulate_full(system, traj, t, step_s=h)[:, 0, 0]
    grid = simulate_full(system, traj, [1.0, 1.5, 1.2], step_s=h)[:, 0, 0]
    np.testing.assert_array_equal(x[[0, 2]], grid[:2])
    # 1.0037 = grid point 1.00 plus one step of 0.0037 s: the same as simulating to 1.00 and then that step
    _, ref_system = particle(settle, zeta, "relative")
    state = ref_system.initial_state(traj, np.array([0.0]))
    for k in range(100):
        ref_system.step(state, traj, np.array([k * h]), h)
    ref_system.step(state, traj, np.array([1.0]), 0.0037)
    assert x[1] == ref_system.observe(state)[0, 0, 0]
    derivs = oscillator(t, 0.0, 0.0, omega, zeta, -a, 0.0)
    exact = derivs[0] + pos(t)[:, 0, 0]
    bound = backward_euler_bound(np.array([2.0]), oscillator(np.linspace(0, 2, 201), 0.0, 0.0, omega, zeta, -a, 0.0),
                                 omega, h)
    assert np.abs(x - exact).max() <= bound


def test_iterative_rotation_matches_svd3_within_a_hundredth_of_epsilon_on_the_demo(default_rig):
    """The default fit (Newton on SO(3), 2 iterations) reproduces svd3's KD states on every demo frame at the
    automatic window within ε/100 (ε = 0.1 % of the face diameter)."""
    from kdfaces import KinematicTrajectory, automatic_window
    from kdfaces.shots import demo_animation
    from kdfaces.shots.demo import demo_face_model

    traj = KinematicTrajectory(default_rig, demo_animation())
    svd = FaceSystem(demo_face_model(default_rig, rotation="svd3"))
    est = automatic_window(svd, traj, step_s=0.04)
    t = traj.frame_times
    ref = simulate_kd(svd, traj, t, est.window_s, step_s=0.04)
    x = simulate_kd(FaceSystem(demo_face_model(default_rig)), traj, t, est.window_s, step_s=0.04)
    assert FaceSystem(demo_face_model(default_rig)).model.rotation == "iterative"
    assert np.linalg.norm(ref - traj.positions(t), axis=2).max() > 100 * est.epsilon_m / 100  # it does move
    assert np.linalg.norm(x - ref, axis=2).max() <= est.epsilon_m / 100


def test_iterative_rotation_matches_svd3_on_thin_clusters():
    """A strip two vertices wide (2 mm across, 6 mm along): its 1-ring clusters are thin (second moments ~30:1),
    so their rotation about the strip's line is weakly determined, and the strip twists fast (2 rad at 8 rad/s)
    with stiff shape matching. Both fits agree within ε/100; one Newton iteration per step would not (0.3 mm), nor
    would a fit biased about the weak axis (svd3 with η = 10⁻³: 0.5 mm), so the case can tell them apart."""
    n, width = 40, 0.002
    u = np.arange(n) * 0.006
    verts = np.concatenate([np.stack([u, np.zeros(n), np.zeros(n)], 1),
                            np.stack([u, np.full(n, width), np.zeros(n)], 1)])
    a, b = np.arange(n - 1), np.arange(n - 1) + n
    faces = np.concatenate([np.stack([a, a + 1, b + 1], 1), np.stack([a, b + 1, b], 1)])
    s = verts[:, 0] / u[-1]  # 0..1 along the strip

    def pose(t, order):
        twist, bend = 2.0 * np.sin(8 * t)[:, None] * s, 0.04 * np.sin(5 * t)[:, None] * s**2
        dtwist, dbend = 16.0 * np.cos(8 * t)[:, None] * s, 0.2 * np.cos(5 * t)[:, None] * s**2
        y, z = verts[:, 1], verts[:, 2]
        c, sn = np.cos(twist), np.sin(twist)
        x = np.stack([np.broadcast_to(verts[:, 0], c.shape), c * y - sn * z, sn * y + c * z + bend], axis=2)
        v = np.stack([np.zeros_like(c), -dtwist * (sn * y + c * z), dtwist * (c * y - sn * z) + dbend], axis=2)
        return (x, v)[order]

    traj = AnalyticTrajectory(lambda t: pose(t, 0), lambda t: pose(t, 1), len(verts), end=3.0)
    eps = 1e-3 * float(np.linalg.norm(verts.max(0) - verts.min(0)))
    times = np.arange(10, 75) * 0.04
    kw = dict(settle_time_s=1.0, damping_ratio=0.3, shape_matching_alpha=1.0, rings=1, cluster_centers="all")
    x = {r: simulate_kd(FaceSystem(FaceModel.create(verts, faces, rotation=r, **kw)), traj, times, 0.4, step_s=0.04)
         for r in ("svd3", "iterative")}
    assert np.linalg.norm(x["svd3"] - traj.evaluate(times)[0], axis=2).max() > 1e-2  # it does twist away
    assert np.linalg.norm(x["iterative"] - x["svd3"], axis=2).max() <= eps / 100
