"""Contact at impact (issue #28, the door's lintel): an object carried by its bone into a fixed box faster than a
step can stop it. A block of tets hangs from a bone that moves down at 1.2 m/s onto a box (12 mm a step with 5 mm
top cells and an 8 mm gap): the whole block carried along collides with the box within the step, and moving the
attached nodes alone inverts the top cells, so the step has no admissible first guess. Before the fix the line
search started from the inverting guess and raised "line search with contact found no decrease"; the stepper now
reaches the step's minimiser by continuation. Every step: no intersection, ipctk's minimum distance > 0, no
inverted tet, and the block rests on the box once the bone stops."""

import numpy as np
import pytest

from kdfem.fem.contact import ContactModel, FixedCollider
from kdfem.fem.integrator import FEMState, ImplicitEuler
from kdfem.fem.materials import Material
from kdfem.fem.model import FEMModel
from kdfem.geometry.tetmesh import TetMesh

ipctk = pytest.importorskip("ipctk")

EDGE_M = 0.01  # cell edge across (x, z) [m]
LAYERS_M = (0.01, 0.01, 0.005)  # cell heights from the bottom up [m]: the top cells (at the bone) 5 mm thin
GAP_M = 0.008  # the tip's height above the box at the start [m]
SPEED_MPS = 1.2  # the bone's downward speed [m/s], the hat tip's at the door's lintel
STEP_S = 0.01
MOVING_STEPS = 1  # the bone moves one step (12 mm), then stops
STEPS = 12  # steps simulated (the block has stopped after ~6)


def _block():
    """A block of 2 × len(LAYERS_M) × 2 cells (Kuhn's 6 tets each: conforming on the grid), bottom at y = GAP_M."""
    ys = GAP_M + np.concatenate([[0.0], np.cumsum(LAYERS_M)])
    nx, ny = 3, len(ys)
    ix, iy, iz = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nx), indexing="ij")
    nodes = np.stack([ix * EDGE_M, ys[iy], iz * EDGE_M], axis=-1).reshape(-1, 3).astype(np.float64)

    def node(i, j, k):
        return (i * ny + j) * nx + k

    tets = []
    perms = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    for i in range(nx - 1):
        for j in range(ny - 1):
            for k in range(nx - 1):
                for p in perms:  # Kuhn: the path from the cell's corner 000 to 111 flipping one axis at a time
                    c = [0, 0, 0]
                    tet = [node(i, j, k)]
                    for a in p:
                        c[a] = 1
                        tet.append(node(i + c[0], j + c[1], k + c[2]))
                    tets.append(tet)
    tets = np.array(tets)
    for t in tets:  # orient every tet positively
        a, b, cc, d = nodes[t]
        if np.dot(np.cross(b - a, cc - a), d - a) < 0:
            t[[1, 2]] = t[[2, 1]]
    return TetMesh(nodes, tets)


def _box():
    """A fixed closed box under the block: x, z ∈ [−0.05, 0.06] m, y ∈ [−0.02, 0] m (outward triangles)."""
    x0, x1, y0, y1, z0, z1 = -0.05, 0.06, -0.02, 0.0, -0.05, 0.06
    V = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], dtype=np.float64)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64)
    return FixedCollider(V, F, name="box", solid=True)


@pytest.fixture(scope="module")
def impact():
    mesh = _block()
    top = np.flatnonzero(np.isclose(mesh.nodes[:, 1], mesh.nodes[:, 1].max()))
    model = FEMModel(mesh, Material(youngs_pa=2e5, density_kg_m3=500.0), top, rayleigh_alpha=5.0,
                     rayleigh_beta=0.0)
    faces = mesh.boundary_faces()
    faces = faces[~np.isin(faces, top).all(axis=1)]
    box = _box()
    cm = ContactModel(faces, [box]).bind(model)
    stepper = ImplicitEuler(model, STEP_S, contact=cm)
    x0 = mesh.nodes.copy()
    v0 = np.zeros_like(x0)
    v0[:, 1] = -SPEED_MPS  # carried down at the bone's speed
    state = FEMState(x=x0[None].copy(), v=v0[None].copy())
    C = box.rest_vertices[None]
    obstacles = (C, C, [None], [None])
    cm.check_start(state.x, C, [None])
    rec = {"min_distance_m": [], "intersections": 0, "min_det": [], "tip_y_m": []}
    y_bone = 0.0
    for k in range(STEPS):
        moving = k < MOVING_STEPS
        y_bone -= SPEED_MPS * STEP_S if moving else 0.0
        G1 = np.eye(4)[None].copy()
        G1[0, 1, 3] = y_bone
        dG1 = np.zeros((1, 4, 4))
        dG1[0, 1, 3] = -SPEED_MPS if moving else 0.0
        stepper.step(state, G1, dG1, obstacles=obstacles)
        xo = state.x[0, cm.nodes]
        rec["intersections"] += int(cm.intersects(xo, C[0]))
        rec["min_distance_m"].append(cm.min_distance(xo, C[0]))
        rec["min_det"].append(float(model.forces(state.x, np.zeros_like(state.x), damping=False)[2].min()))
        rec["tip_y_m"].append(float(state.x[0, :, 1].min()))
    return stepper, cm, state, rec


def test_impact_step_needs_the_continuation(impact):
    """The first contact step has no admissible first guess: the block carried rigidly crosses the box (the
    tip moves 12 mm toward an 8 mm gap) and the attached nodes moved alone invert the top cells (12 mm down in a
    5 mm cell); the continuation rounds ran."""
    stepper, *_ = impact
    assert SPEED_MPS * STEP_S > GAP_M and SPEED_MPS * STEP_S > LAYERS_M[-1]
    assert stepper.contact_rounds >= 2


def test_impact_never_intersects_and_keeps_a_gap(impact):
    stepper, cm, state, rec = impact
    assert rec["intersections"] == 0
    assert min(rec["min_distance_m"]) > 0
    assert min(rec["min_det"]) > 0
    # the tip went no lower than the box's top (y = 0): it was stopped, not passed through
    assert min(rec["tip_y_m"]) > 0
    # the bone pushed the block 12 mm down onto an 8 mm gap: the tip was in the barrier's reach (d̂) at the end
    assert rec["tip_y_m"][-1] < cm.dhat_m


def test_impact_block_comes_to_rest(impact):
    """After the bone stops, the barrier and damping (α = 5/s) leave the block nearly still: its speed is far
    below the 1.2 m/s of the impact."""
    _, _, state, _ = impact
    assert np.abs(state.v[0]).max() < 0.05 * SPEED_MPS
