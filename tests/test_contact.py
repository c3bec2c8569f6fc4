"""Contact with ipctk (kdfem.fem.contact): the barrier's convention and derivatives, a block dropped on a plane
resting at the barrier distance, no intersection on any step, and the bad-input errors."""

import numpy as np
import pytest
from scipy.optimize import brentq

from kdfaces.errors import KDInputError
from kdfem.fem.contact import ContactModel, FixedCollider, closed_surface
from kdfem.fem.integrator import FEMState, ImplicitEuler
from kdfem.fem.materials import Material
from kdfem.fem.model import FEMModel
from kdfem.geometry.tetmesh import TetMesh

ipctk = pytest.importorskip("ipctk")

CUBE_TETS = np.array([[0, 1, 3, 5], [0, 3, 2, 6], [0, 5, 4, 6], [3, 5, 6, 7], [0, 3, 5, 6]])


def _block(edge_m=0.05, height_m=0.0):
    """A cube of 5 tets (nodes 0–7, bottom face y = height_m) and a far anchor tet (nodes 8–11, attached)."""
    c = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.float64) * edge_m
    c[:, 1] += height_m
    c[:, [0, 2]] += 0.1  # clear of the floor's diagonal x + z = 0: every bottom node meets one triangle's interior
    anchor = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64) * 0.01 + [1.0, 1.0, 1.0]
    tets = np.vstack([CUBE_TETS, np.array([[8, 9, 10, 11]])])
    nodes = np.vstack([c, anchor])
    # orient every tet positively
    for t in tets:
        a, b, cc, d = nodes[t]
        if np.dot(np.cross(b - a, cc - a), d - a) < 0:
            t[[1, 2]] = t[[2, 1]]
    return TetMesh(nodes, tets)


def _plane(half_m=0.5):
    V = np.array([[-half_m, 0, -half_m], [half_m, 0, -half_m], [half_m, 0, half_m], [-half_m, 0, half_m]])
    return FixedCollider(V, np.array([[0, 3, 1], [1, 3, 2]]), name="floor")


def _setup(height_m, kappa=None):
    mesh = _block(height_m=height_m)
    model = FEMModel(mesh, Material(youngs_pa=1e6, density_kg_m3=500.0), np.arange(8, 12), rayleigh_alpha=5.0,
                     rayleigh_beta=0.0)
    faces = mesh.boundary_faces()
    faces = faces[(faces < 8).all(axis=1)]
    cm = ContactModel(faces, [_plane()], kappa=kappa).bind(model)
    return model, cm


def test_barrier_convention_and_derivatives():
    """ipctk 1.6's barrier is b(d², d̂²) = −(d² − d̂²)² ln(d²/d̂²); its gradient and Hessian match central
    differences (tolerances from the differences' truncation, h²·|third derivative|, and round-off)."""
    model, cm = _setup(0.0)
    dh = cm.dhat_m
    x = model.mesh.nodes[cm.nodes].copy()
    x[:, 1] += 0.3 * dh + 0.1 * dh * np.arange(len(x)) / len(x)  # bottom nodes within d̂ of the floor
    C = _plane().rest_vertices
    V = cm.vertices(x, C)
    col = ipctk.NormalCollisions()
    col.build(cm.mesh, V, dh)
    assert len(col) > 0
    d = x[:, 1][x[:, 1] < dh]  # the bottom nodes' heights: each one vertex–floor pair
    expected = sum(-(di ** 2 - dh ** 2) ** 2 * np.log(di ** 2 / dh ** 2) for di in d)
    assert cm.barrier(col, cm.mesh, V) == pytest.approx(expected, rel=1e-12)
    g = cm.barrier.gradient(col, cm.mesh, V)
    H = cm.barrier.hessian(col, cm.mesh, V).toarray()
    eps = 1e-3 * dh
    n = 3 * cm.num_object
    fd_g, fd_H = np.zeros(n), np.zeros((n, n))
    for i in range(n):
        Vp, Vm = V.copy(order="F"), V.copy(order="F")
        Vp.ravel(order="C")  # (row-major DOFs: vertex i, coordinate c → 3i + c)
        Vp[i // 3, i % 3] += eps
        Vm[i // 3, i % 3] -= eps
        cp, cmn = ipctk.NormalCollisions(), ipctk.NormalCollisions()
        cp.build(cm.mesh, Vp, dh)
        cmn.build(cm.mesh, Vm, dh)
        fd_g[i] = (cm.barrier(cp, cm.mesh, Vp) - cm.barrier(cmn, cm.mesh, Vm)) / (2 * eps)
        fd_H[i] = (cm.barrier.gradient(cp, cm.mesh, Vp) - cm.barrier.gradient(cmn, cm.mesh, Vm))[:n] / (2 * eps)
    scale_g, scale_H = np.abs(g).max(), np.abs(H).max()
    # central differences: error ~ eps²·|b'''| ~ (eps/d)² relative, plus round-off ~1e-16·b/eps
    tol = 10 * (eps / d.min()) ** 2
    np.testing.assert_allclose(fd_g, g[:n], atol=tol * scale_g)
    np.testing.assert_allclose(fd_H, H[:n, :n], atol=tol * scale_H)


def test_block_dropped_on_a_plane_rests_at_the_barrier_distance():
    """The block falls onto the floor, never intersects it, and rests where its weight balances the barrier:
    m g = (κ̃/h²) · 4 · 2d* |b'(d*²)| for its four bottom nodes at height d* (velocity form, κ̃ fixed)."""
    h = 0.01
    model, cm0 = _setup(0.002)
    kappa = 10 * cm0.kappa_min
    model, cm = _setup(0.002, kappa=kappa)
    stepper = ImplicitEuler(model, h, tol_m=1e-10, contact=cm)
    x0 = model.mesh.nodes.copy()
    state = FEMState(x=x0[None].copy(), v=np.zeros((1, *x0.shape)))
    C = _plane().rest_vertices[None]
    G = np.eye(4)[None]
    obstacles = (C, C, [None], [None])
    cm.check_start(state.x, C, [None])
    for _ in range(150):
        stepper.step(state, G, np.zeros((1, 4, 4)), obstacles=obstacles)
        xo = state.x[0, cm.nodes]
        assert not cm.intersects(xo, C[0])
        md = cm.min_distance(xo, C[0])
        assert md > 0
    bottom = state.x[0, :8][:, 1]
    bottom = np.sort(bottom)[:4]
    m = model.masses[:8].sum()
    g = 9.81
    dh = cm.dhat_m
    force = lambda d: kappa / h ** 2 * 4 * 2 * d * abs(  # noqa: E731
        -2 * (d * d - dh * dh) * np.log(d * d / dh / dh) - (d * d - dh * dh) ** 2 / (d * d))
    d_star = brentq(lambda d: force(d) - m * g, 1e-6 * dh, dh * (1 - 1e-12))
    assert 0 < bottom.min() and bottom.max() < dh
    # at rest: the nodes are still and the block is stiff (its sag m g /(E·edge) ~ 1e-7 m ≪ d*)
    np.testing.assert_allclose(bottom, d_star, rtol=0.05)
    assert np.abs(state.v[0, :8]).max() < 1e-3


def test_bad_input_errors():
    model, cm = _setup(-0.01)  # the block starts through the floor
    C = _plane().rest_vertices[None]
    with pytest.raises(KDInputError, match="intersects a collider"):
        cm.check_start(model.mesh.nodes[None], C, [None])
    open_box = FixedCollider(_plane().rest_vertices, np.array([[0, 2, 1], [0, 3, 2]]), solid=True)
    assert not closed_surface(open_box.faces)
    faces = model.mesh.boundary_faces()
    with pytest.raises(KDInputError, match="not closed"):
        ContactModel(faces[(faces < 8).all(axis=1)], [open_box])
    with pytest.raises(KDInputError, match="float64 cannot resolve"):
        ContactModel(faces[(faces < 8).all(axis=1)], [_plane()], dhat_m=1e-12).bind(model)
    with pytest.raises(KDInputError, match="dhat_m"):
        ContactModel(faces, [_plane()], dhat_m=-1.0)


def _tilted(mu, tan_theta, kappa_fac=10.0):
    """The block resting on the floor under gravity tilted by θ (a floor tilted by θ): starts still at the barrier
    rest height for the normal load m g cos θ, no Rayleigh damping (α would drag it)."""
    theta = np.arctan(tan_theta)
    g = 9.81 * np.array([np.sin(theta), -np.cos(theta), 0.0])
    mesh = _block(height_m=0.0)
    model0 = FEMModel(mesh, Material(youngs_pa=1e6, density_kg_m3=500.0), np.arange(8, 12), rayleigh_alpha=0.0,
                      rayleigh_beta=0.0, gravity=tuple(g))
    faces = mesh.boundary_faces()
    faces = faces[(faces < 8).all(axis=1)]
    kappa = kappa_fac * ContactModel(faces, [_plane()]).bind(model0).kappa_min
    cm = ContactModel(faces, [_plane()], kappa=kappa, friction=mu).bind(model0)
    h, dh = 0.01, cm.dhat_m
    m = model0.masses[:8].sum()
    force = lambda d: kappa / h ** 2 * 4 * 2 * d * abs(  # noqa: E731
        -2 * (d * d - dh * dh) * np.log(d * d / dh / dh) - (d * d - dh * dh) ** 2 / (d * d))
    d_star = brentq(lambda d: force(d) - m * 9.81 * np.cos(theta), 1e-6 * dh, dh * (1 - 1e-12))
    x0 = mesh.nodes.copy()
    x0[:8, 1] += d_star
    return model0, cm, x0, h, theta


@pytest.mark.parametrize("tan_theta", [0.3, 0.8])
def test_friction_block_on_a_tilted_plane_sticks_below_mu_and_slides_above(tan_theta):
    """Coulomb friction μ = 0.5 through ipctk's lagged friction potential (normal forces and tangent bases from the
    step start): below tan θ = μ the block stays put (tangential speed within the mollifier's ε_v); above, it slides
    with a = g (sin θ − μ cos θ) (λ = m g cos θ at the barrier rest height; tolerance: the lag and the implicit
    step)."""
    mu = 0.5
    model, cm, x0, h, theta = _tilted(mu, tan_theta)
    stepper = ImplicitEuler(model, h, tol_m=1e-10, contact=cm)
    state = FEMState(x=x0[None].copy(), v=np.zeros((1, *x0.shape)))
    C = _plane().rest_vertices[None]
    obstacles = (C, C, [None], [None])
    vx = []
    for _ in range(40):
        stepper.step(state, np.eye(4)[None], np.zeros((1, 4, 4)), obstacles=obstacles)
        assert not cm.intersects(state.x[0, cm.nodes], C[0])
        vx.append(state.v[0, :8, 0].mean())
    vx = np.array(vx)
    if np.tan(theta) < mu:
        assert np.abs(vx).max() < 2 * cm.friction_eps_v_mps
    else:
        a = np.polyfit(h * np.arange(20, 40), vx[20:], 1)[0]
        expected = 9.81 * (np.sin(theta) - mu * np.cos(theta))
        assert a == pytest.approx(expected, rel=0.05)
        # frictionless, it would accelerate at g sin θ: friction is acting
        assert a < 0.7 * 9.81 * np.sin(theta)


def test_demo_hat_never_enters_the_head():
    """The demo scene (the default hat on the default head, the demo's nod) with the head as a collider
    (:func:`attached_object_collider`: the head minus where the hat rests on it): a full simulation of 0.3 s around
    the nod's swing, and the same with a floor pressed onto the brim (contact active), never intersect the head
    or the floor (ipctk on the whole collider, every step) and keep a positive distance; without contact the
    steps are the contact-free ones, bit for bit."""
    from kdfaces.io.rigfiles import load_default_rig
    from kdfaces.motion.trajectory import KinematicTrajectory
    from kdfaces.shots.builtin import demo_animation
    from kdfem.fem.contact import attached_object_collider
    from kdfem.fem.default_hat import default_hat_system
    from kdfem.fem.system import HatSystem

    rig = load_default_rig()
    traj = KinematicTrajectory(rig, demo_animation())
    base, _, _ = default_hat_system(rig, threads=1)
    head = attached_object_collider(base.model, base.rest_equilibrium, rig)
    t0, h, steps = 4.8, 0.01, 30
    x_k = base.observe_kinematic(traj, np.array([t0]))[0]
    cm0 = ContactModel(base.model.mesh.boundary_faces(), [head]).bind(base.model)
    y = float(x_k[cm0.nodes, 1].min()) - 2e-3
    c = x_k[cm0.nodes].mean(axis=0)
    floor = FixedCollider(np.array([[c[0] - 0.5, y, c[2] - 0.5], [c[0] + 0.5, y, c[2] - 0.5],
                                    [c[0] + 0.5, y, c[2] + 0.5], [c[0] - 0.5, y, c[2] + 0.5]]),
                          np.array([[0, 3, 1], [1, 3, 2]]), name="floor")
    ref = None
    for colliders in ([head], [head, floor]):
        system = HatSystem(base.model, embedding=base.embedding, threads=1, colliders=colliders)
        cm = system.contact
        state = system.initial_state(traj, np.array([t0]))
        if len(colliders) == 1:
            ref = base.initial_state(traj, np.array([t0]))
        for k in range(steps):
            t = np.array([t0 + k * h])
            system.step(state, traj, t, h)
            C, _ = cm.collider_pose(t + h, traj)
            xo = state.x[0, cm.nodes]
            assert not cm.intersects(xo, C[0]), f"step {k}: the hat intersects {[c.name for c in colliders]}"
            assert cm.min_distance(xo, C[0]) > 0
            if len(colliders) == 1:
                base.step(ref, traj, t, h)
        steps_on_contact = system.stepper(h).contact_steps
        if len(colliders) == 1:  # the broad phase clears every step: the contact-free result, bit for bit
            assert steps_on_contact == 0
            assert np.array_equal(state.x, ref.x)
        if len(colliders) == 2:
            assert steps_on_contact > 0  # the floor did press on the brim


def test_broad_phase_exact_fallback_clears_gaps_finer_than_its_grid():
    """The distance grid's bound loses up to h√3/2 (h the spacing); below the grid's resolution the broad phase
    bounds a triangle by its centroid's exact distance less its radius (:func:`kdfem.fem.contact._surface_bound`).
    Against a plane y = 0 the exact distance of a triangle above it is its lowest corner's height (closed form): the
    bound never exceeds it, and with the exact fallback it decides a 4 mm gap under a 9 mm grid, which the grid
    alone cannot (its error 7.8 mm is larger than the gap)."""
    from kdfem.fem.contact import DistanceGrid, _surface_bound

    floor = _plane(0.2)
    h = 0.009
    grid = DistanceGrid(floor.rest_vertices, floor.faces, h, 0.05)
    rng = np.random.default_rng(3)
    for gap in (0.002, 0.004, 0.01):
        # 40 triangles of ~8 mm edges, tilted at random, lowest corner at height gap
        c = rng.uniform(-0.1, 0.1, (40, 1, 3)) * [1, 0, 1]
        T = c + rng.normal(scale=0.005, size=(40, 3, 3))
        T[:, :, 1] += gap - T[:, :, 1].min(axis=1, keepdims=True)
        for levels in (0, 2):
            lb = _surface_bound(grid, T, margin_m=0.0015, r_stop_m=0.5 * h, exact_levels=levels)
            assert lb <= gap + 1e-12
        grid_only = _surface_bound(grid, T, margin_m=0.0015, r_stop_m=0.5 * h, exact_levels=0)
        exact = _surface_bound(grid, T, margin_m=0.0015, r_stop_m=0.5 * h, exact_levels=2)
        assert exact >= grid_only - 1e-12
        if gap == 0.004:
            assert grid_only <= 0.0015 < exact  # only the exact fallback proves the gap exceeds 1.5 mm
        if gap == 0.01:
            assert grid_only > 0.0015 and exact > 0.0015  # the grid decides a 10 mm gap by itself
    q = rng.uniform(-0.1, 0.1, (50, 3))
    assert np.allclose(grid.exact_distance(q), np.abs(q[:, 1]), atol=1e-12)
