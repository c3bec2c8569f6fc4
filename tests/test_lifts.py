"""Smooth lifts of constraint errors onto the surface (kdfaces.ikd.lifts): exact on the constrained vertices, linear
precision on a flat patch, zero beyond the falloff and on other pieces, one factorisation per constraint."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from kdfaces import GaussianBasis, KinematicTrajectory, defaults, end_effector_constraint, solve_ikd, subset_constraint
from kdfaces.dynamics import FaceSystem
from kdfaces.ikd import Surface, seam_ratio
from kdfaces.ikd.lifts import mesh_edges
from kdfaces.rig.groups import vertex_group
from kdfaces.shots import demo_animation
from kdfaces.shots.demo import demo_face_model


def patch(n: int = 21, size_m: float = 0.1, jitter: float = 0.3, seed: int = 0):
    """A flat n × n grid on [0, size]² (z = 0), interior vertices jittered by ``jitter`` spacings, and the index sets
    of its boundary rings (ring 0 outermost)."""
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    h = size_m / (n - 1)
    v = np.stack([i.ravel() * h, j.ravel() * h, np.zeros(n * n)], axis=1)
    ring = np.minimum.reduce([i.ravel(), j.ravel(), n - 1 - i.ravel(), n - 1 - j.ravel()])
    inner = ring > 0
    v[inner, :2] += rng.uniform(-jitter, jitter, size=(inner.sum(), 2)) * h
    a = (i[:-1, :-1] * n + j[:-1, :-1]).ravel()
    f = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
    return v, f, ring


def test_the_extension_reproduces_the_constrained_values_exactly(default_rig):
    surface = Surface(default_rig.neutral, default_rig.faces)
    lips = vertex_group(default_rig, "lips")
    values = np.random.default_rng(1).normal(scale=1e-3, size=(len(lips), 3))
    lift = surface.lift_for(lips, falloff_m=0.03)
    e = lift.extend(values)
    np.testing.assert_array_equal(e[lips], values)
    outside = np.setdiff1d(np.arange(default_rig.num_vertices), lift.region)
    assert len(outside) > 1000 and (e[outside] == 0).all()  # nothing moves beyond the falloff
    assert np.isfinite(e).all() and np.abs(e).max() <= np.abs(values).max() * 2


@pytest.mark.parametrize("energy, rings", [("harmonic", 1), ("biharmonic", 2)])
def test_a_linear_field_is_reproduced_on_a_flat_patch(energy, rings):
    """Linear precision of the cotangent Laplacian on a planar (irregular) triangulation: a linear field fixed on the
    boundary (two rings for the biharmonic energy) extends to itself, to round-off."""
    v, f, ring = patch()
    fixed = np.flatnonzero(ring < rings)
    a = np.array([[0.3, -1.2, 0.0], [0.8, 0.5, 0.0], [-0.4, 0.9, 0.0]])
    field = v @ a.T + np.array([1e-3, -2e-3, 5e-4])
    e = Surface(v, f, energy=energy).lift_for(fixed, falloff_m=1.0).extend(field[fixed])
    np.testing.assert_allclose(e, field, rtol=0, atol=1e-10 * np.abs(field).max())


def test_an_end_effector_moves_its_point_exactly_by_the_damped_step(default_rig):
    surface = Surface(default_rig.neutral, default_rig.faces)
    jaw = vertex_group(default_rig, "jaw")
    w = np.random.default_rng(2).uniform(0.5, 1.5, len(jaw))
    w /= w.sum()
    r = np.array([0.0, -0.003, 0.001])
    mu = 0.1
    e = surface.lift_for(jaw, falloff_m=0.05, weights=w).point(r, pinv_damping=mu)
    np.testing.assert_allclose(w @ e[jaw], r / (1 + mu**2), rtol=1e-9, atol=0)
    # a dome over the jaw (peak ≈ 1.5× the step for 5 cm), not one piece (the lower teeth) flung far to move the mean
    assert np.linalg.norm(e, axis=1).max() <= 2.5 * np.linalg.norm(r)
    sharp = np.zeros_like(e)
    sharp[jaw] = r
    assert seam_ratio(sharp, default_rig.faces) == pytest.approx(1.0)
    assert surface.seam_ratio(e) < 0.35  # the tear of the sharp lift is gone (see the report for the mesh limit)


def test_the_lift_is_seamless_where_the_mesh_resolves_the_falloff():
    """On a regular 1 mm grid a uniform 2 mm offset of a 2 cm disc falls off over the default 5 cm with no seam."""
    v, f, _ = patch(n=201, size_m=0.2, jitter=0.0)
    disc = np.flatnonzero(np.linalg.norm(v[:, :2] - 0.1, axis=1) < 0.02)
    e = Surface(v, f).lift_for(disc, falloff_m=0.05).extend(np.tile([0.0, 0.0, 0.002], (len(disc), 1)))
    assert seam_ratio(e, f) <= 0.05
    far = np.linalg.norm(v[:, :2] - 0.1, axis=1) > 0.02 + 0.05 + 1e-3
    assert (e[far] == 0).all()


def strip(n: int, h_m: float = 0.01):
    """A flat strip of n × 2 vertices, spacing ``h_m`` [m], triangulated like :func:`patch`: (vertices, faces)."""
    i, j = np.meshgrid(np.arange(n), np.arange(2), indexing="ij")
    v = np.stack([i.ravel() * h_m, j.ravel() * h_m, np.zeros(2 * n)], axis=1)
    a = (i[:-1, :-1] * 2 + j[:-1, :-1]).ravel()
    f = np.concatenate([np.stack([a, a + 2, a + 3], 1), np.stack([a, a + 3, a + 1], 1)])
    return v, f


@pytest.mark.parametrize("m", [3, 7, 20])
def test_the_harmonic_lift_attains_the_seam_bound_on_a_strip(m):
    """Closed form: on a strip with the first column fixed and the falloff ending before column m, every path to a
    vertex held at zero has m edges, so no field has a seam ratio below 1/m; the harmonic lift is the linear ramp
    (linear precision, and the strip's free edges have zero normal derivative), which attains it: 1/m exactly."""
    h = 0.01
    v, f = strip(m + 5, h)
    first = np.flatnonzero(v[:, 0] == 0.0)
    for energy in ("harmonic", "biharmonic"):
        lift = Surface(v, f, energy=energy).lift_for(first, falloff_m=(m - 0.5) * h)
        assert lift.seam_bound == pytest.approx(1.0 / m, rel=1e-12)
        e = lift.extend(np.tile([0.0, 0.0, 1e-3], (len(first), 1)))
        if energy == "harmonic":
            np.testing.assert_allclose(e[:, 2], 1e-3 * np.clip(1.0 - v[:, 0] / (m * h), 0.0, None), atol=1e-15)
            assert seam_ratio(e, f) == pytest.approx(1.0 / m, rel=1e-9)
        else:  # C¹ at both ends: steeper in the middle
            assert seam_ratio(e, f) > 1.0 / m


def test_no_lift_on_the_default_head_goes_below_its_seam_bound(default_rig):
    """The floor holds for the chin end effector and a lips subset at several falloffs, and at the default 5 cm it
    is above 0.05 for both: every path from the falloff region to the vertices held at zero is at most 16 (jaw) and
    18 (lips) edges long on this mesh (edges up to 43 mm; 4.7 mm median), so no correction that falls off to zero
    within 5 cm has a seam ratio of 0.05 here, however it is computed."""
    surface = Surface(default_rig.neutral, default_rig.faces)
    jaw, lips = vertex_group(default_rig, "jaw"), vertex_group(default_rig, "lips")
    rng = np.random.default_rng(4)
    for falloff in (0.03, 0.05, 0.1):
        point = surface.lift_for(jaw, falloff_m=falloff, weights=np.full(len(jaw), 1.0 / len(jaw)))
        values = surface.lift_for(lips, falloff_m=falloff)
        fields = [(point, point.point(np.array([0.0, -0.002, 0.0]))),
                  (values, values.extend(np.tile([0.0, 0.001, 0.0005], (len(lips), 1)))),
                  (values, values.extend(rng.normal(scale=1e-3, size=(len(lips), 3))))]
        for lift, e in fields:
            assert 0.0 < lift.seam_bound <= surface.seam_ratio(e)
    default = defaults.FALLOFF_M
    assert surface.lift_for(jaw, falloff_m=default, weights=np.full(len(jaw), 1.0 / len(jaw))).seam_bound > 0.05
    assert surface.lift_for(lips, falloff_m=default).seam_bound > 0.05


def test_other_pieces_stay_still_and_non_manifold_meshes_work():
    """Two patches side by side (one with a fin glued to an interior edge: three triangles on one edge) and a copy
    of the first patch's seam column (split vertices): the lift stays on its piece, crosses the split seam
    smoothly, and is finite everywhere."""
    v, f, _ = patch(n=11, size_m=0.1, jitter=0.0)
    n = len(v)
    v2 = v + [0.3, 0.0, 0.0]
    fin_apex = np.array([[0.05, 0.05, 0.05]])
    verts = np.concatenate([v, v2, fin_apex])
    faces = np.concatenate([f, f + n, [[n + 5 * 11 + 5, n + 5 * 11 + 6, 2 * n]]])
    # split the first patch along x = 0.05: triangles right of it use duplicated vertices
    col = np.flatnonzero(np.isclose(v[:, 0], 0.05))
    dup = np.arange(len(verts), len(verts) + len(col))
    verts = np.concatenate([verts, v[col]])
    remap = np.arange(len(verts))
    remap[col] = dup
    right = (verts[faces[:, :3]][:, :, 0].mean(axis=1) > 0.05) & (faces.max(axis=1) < n)
    faces[right] = remap[faces[right]]
    surface = Surface(verts, faces)
    assert not surface.manifold  # the fin: exact geodesics are skipped, edge paths measure the falloff
    left = np.flatnonzero((v[:, 0] < 0.02) & (np.abs(v[:, 1] - 0.05) < 0.02))
    e = surface.lift_for(left, falloff_m=0.06).extend(np.tile([0.0, 0.0, 1e-3], (len(left), 1)))
    assert np.isfinite(e).all()
    assert (e[n:2 * n + 1] == 0).all()  # the other piece and the fin
    np.testing.assert_array_equal(e[col], e[dup])  # split copies move together
    assert np.abs(e[dup]).max() > 0  # ... and the falloff reaches across the seam


def test_an_end_effector_on_two_pieces_moves_each_share_by_the_step():
    """A point over a patch and a small separate plate inside the falloff (a jaw and its teeth): each piece's share
    of the point moves by r, the plate rigidly, instead of the free plate taking the whole step."""
    v, f, _ = patch(n=11, size_m=0.1, jitter=0.0)
    plate = np.array([[0.05, 0.05, -0.01], [0.06, 0.05, -0.01], [0.05, 0.06, -0.01]])
    verts = np.concatenate([v, plate])
    faces = np.concatenate([f, [[len(v), len(v) + 1, len(v) + 2]]])
    centre = np.flatnonzero(np.linalg.norm(v[:, :2] - 0.05, axis=1) < 0.015)
    idx = np.concatenate([centre, len(v) + np.arange(3)])
    w = np.full(len(idx), 1.0 / len(idx))
    r = np.array([0.0, 0.0, 0.002])
    e = Surface(verts, faces).lift_for(idx, falloff_m=0.03, weights=w).point(r)
    np.testing.assert_allclose(w @ e[idx], r, rtol=1e-9)
    np.testing.assert_allclose(e[len(v):], np.tile(r, (3, 1)), rtol=1e-6)  # the plate: rigidly by r
    np.testing.assert_allclose(e[centre].mean(axis=0), r, rtol=1e-9)  # the patch's share: by r too


@pytest.fixture(scope="module")
def face(default_rig):
    traj = KinematicTrajectory(default_rig, demo_animation())
    return FaceSystem(demo_face_model(default_rig)), traj


def test_each_lift_is_factorised_once_and_reused_every_iteration(face, default_rig):
    system, traj = face
    jaw = vertex_group(default_rig, "jaw")
    lips = vertex_group(default_rig, "lips")
    x1 = traj.positions([1.0])[0]
    constraints = [
        end_effector_constraint(1.0, x1[jaw].mean(axis=0) + [0, -0.003, 0], jaw, GaussianBasis(1.0, 0.25),
                                num_vertices=traj.num_vertices),
        subset_constraint(3.4, traj.positions([3.4])[0] + [0, 0, 0.002], lips, GaussianBasis(3.4, 0.3),
                          num_vertices=traj.num_vertices),
    ]
    r = solve_ikd(system, traj, constraints, window_s=0.4, update="paper", tolerance_m=1e-6, max_iterations=4)
    assert r.converged and r.iterations >= 2, (r.reason, r.history)
    assert r.extra["lift_factorizations"] == 2  # one per constraint, not one per iteration
    assert r.extra["lift_solves"] >= 2 * r.iterations
    seams = r.seam_ratios()
    assert seams[0] < 0.35 and seams[1] < 0.8  # (sharp: 1.0 both; the lips' own KD error varies vertex to vertex)
    # a shared surface reuses the factorisations of an earlier solve
    again = solve_ikd(system, traj, constraints, window_s=0.4, update="secant", tolerance_m=1e-6,
                      max_iterations=6, surface=r.surface)
    assert again.converged and again.extra["lift_factorizations"] == 0
    # falloff_m = 0: the paper's sharp lift, the correction on the group only
    sharp = [dataclasses.replace(c, falloff_m=0.0) for c in constraints]
    s = solve_ikd(system, traj, sharp, window_s=0.4, update="secant", tolerance_m=1e-6, max_iterations=6)
    assert s.converged and s.extra["lift_factorizations"] == 0
    assert s.seam_ratios(default_rig.faces)[0] == pytest.approx(1.0)


def test_mesh_edges_are_unique_and_undirected():
    e = mesh_edges([[0, 1, 2], [2, 1, 3]])
    np.testing.assert_array_equal(e, [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]])
