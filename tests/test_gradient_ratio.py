"""The gradient ratio of a smooth lift (issue 24): the steepest slope of the correction's magnitude along a mesh edge
in units of a linear ramp from its largest value to zero over the falloff. 1 is that ramp (closed form on a strip);
the lifts of lips, jaw and brows stay at or below 3 on the default head and on a subdivided, centimetre, renamed
production-like rig, where the sharp lift (a jump over one edge) is ten to a hundred times steeper."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from test_lifts import strip

from kdfaces.ikd import Surface, gradient_ratio
from kdfaces.rig.groups import vertex_group

GROUPS = ("lips", "jaw", "brows")
FALLOFFS_M = (0.03, 0.05)
LIMIT = 3.0


@pytest.mark.parametrize("m", [5, 20])
@pytest.mark.parametrize("fraction", [1.0 - 1e-9, 0.9])
def test_the_harmonic_lift_on_a_strip_is_a_linear_ramp_with_ratio_falloff_over_its_length(m, fraction):
    """Closed form: with the first column fixed at 1 mm and the falloff ending just before column m (the first
    column held at zero), the harmonic lift is the ramp 1 − x/(m h) (linear precision); its slope 1 mm/(m h) times
    the falloff over 1 mm is falloff / (m h): 1 when the falloff is the ramp's length. The sharp lift (1 mm on the
    first column, 0 elsewhere) jumps over one edge h: falloff / h."""
    h = 0.01
    v, f = strip(m + 5, h)
    first = np.flatnonzero(v[:, 0] == 0.0)
    falloff = (m - 1 + fraction) * h  # column m − 1 inside, column m beyond: the ramp is m edges long
    surface = Surface(v, f, energy="harmonic")
    e = surface.lift_for(first, falloff_m=falloff).extend(np.tile([0.0, 0.0, 1e-3], (len(first), 1)))
    assert surface.gradient_ratio(e, falloff) == pytest.approx(falloff / (m * h), rel=1e-9)
    if fraction > 0.99:
        assert surface.gradient_ratio(e, falloff) == pytest.approx(1.0, rel=1e-8)
    sharp = np.zeros_like(e)
    sharp[first, 2] = 1e-3
    assert gradient_ratio(sharp, v, falloff, f) == pytest.approx(falloff / h, rel=1e-12)
    biharmonic = Surface(v, f).lift_for(first, falloff_m=falloff).extend(np.tile([0.0, 0.0, 1e-3], (len(first), 1)))
    assert gradient_ratio(biharmonic, v, falloff, f) > falloff / (m * h)  # C¹ at both ends: steeper in between


def test_the_ratio_ignores_scale_and_welded_copies():
    """Scaling the field or the mesh (with the falloff) leaves the ratio alone; a zero-length edge between welded
    copies of one point is left out instead of dividing by zero."""
    h = 0.01
    v, f = strip(12, h)
    first = np.flatnonzero(v[:, 0] == 0.0)
    e = Surface(v, f).lift_for(first, falloff_m=0.05).extend(np.tile([0.0, 1e-3, 0.0], (len(first), 1)))
    base = gradient_ratio(e, v, 0.05, f)
    assert gradient_ratio(7.0 * e, v, 0.05, f) == pytest.approx(base, rel=1e-12)
    assert gradient_ratio(e, 100.0 * v, 5.0, f) == pytest.approx(base, rel=1e-12)
    dup = np.concatenate([v, v[[3]]])
    ff = np.concatenate([f, [[3, 4, len(v)]]])  # a degenerate triangle onto a copy of vertex 3
    assert gradient_ratio(np.concatenate([e, e[[3]]]), dup, 0.05, ff) == pytest.approx(base, rel=1e-12)
    assert gradient_ratio(np.zeros_like(e), v, 0.05, f) == 0.0


def _ratios(rig) -> dict:
    """(group, kind, falloff) → gradient ratio of the lips, jaw and brows lifts: a subset lifted with one offset on
    every vertex, and an end effector on the group's centroid lifted for a 2 mm step; and of the sharp subset."""
    surface = Surface(rig.neutral, rig.faces)
    out = {}
    for group in GROUPS:
        idx = vertex_group(rig, group)
        for falloff in FALLOFFS_M:
            sub = surface.lift_for(idx, falloff_m=falloff).extend(np.tile([0.0, 1e-3, 5e-4], (len(idx), 1)))
            point = surface.lift_for(idx, falloff_m=falloff, weights=np.full(len(idx), 1.0 / len(idx)))
            ee = point.point(np.array([0.0, -0.002, 0.001]))
            sharp = np.zeros_like(sub)
            sharp[idx] = [0.0, 1e-3, 5e-4]
            out[group, "subset", falloff] = surface.gradient_ratio(sub, falloff)
            out[group, "end_effector", falloff] = surface.gradient_ratio(ee, falloff)
            out[group, "sharp", falloff] = surface.gradient_ratio(sharp, falloff)
    return out


def _check(ratios):
    smooth = {k: v for k, v in ratios.items() if k[1] != "sharp"}
    assert all(0.5 < v <= LIMIT for v in smooth.values()), {k: round(v, 2) for k, v in smooth.items()}
    assert all(v >= 20.0 for k, v in ratios.items() if k[1] == "sharp"), ratios  # what the smooth lift removes


def test_lips_jaw_and_brows_on_the_default_head(default_rig):
    _check(_ratios(default_rig))


@pytest.fixture(scope="module")
def production_rig(tmp_path_factory):
    """The default head Loop-subdivided (19k vertices), shapes renamed (browInnerUp split by side, tongueOut
    dropped), teeth boxes added, written as an OBJ folder in centimetres (scripts/build_production_rig.py) and
    loaded back in metres."""
    from kdfaces import load_rig

    path = Path(__file__).resolve().parents[1] / "scripts" / "build_production_rig.py"
    spec = importlib.util.spec_from_file_location("build_production_rig", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    folder = tmp_path_factory.mktemp("production") / "rig_obj"
    mod.build_production_rig(folder)
    return load_rig(folder, units="cm")


def test_lips_jaw_and_brows_on_a_subdivided_centimetre_renamed_rig(production_rig, default_rig):
    rig = production_rig
    assert rig.num_vertices > 3.5 * default_rig.num_vertices
    assert "browInnerUp_L" in rig.shape_names and "browInnerUp" not in rig.shape_names
    assert 0.1 < float(np.ptp(rig.neutral, axis=0).max()) < 1.0  # metres again
    _check(_ratios(rig))


def test_a_solve_reports_each_constraints_gradient_ratio(default_rig):
    """IKDResult.gradient_ratios: the ratio of each constraint's correction at its time on the solve's surface, at
    its falloff; None for the pose constraint's sharp lift."""
    from kdfaces import (
        GaussianBasis,
        KinematicTrajectory,
        end_effector_constraint,
        pose_constraint,
        solve_ikd,
        subset_constraint,
    )
    from kdfaces.dynamics import FaceSystem
    from kdfaces.shots import demo_animation
    from kdfaces.shots.demo import demo_face_model

    traj = KinematicTrajectory(default_rig, demo_animation())
    system = FaceSystem(demo_face_model(default_rig))
    n = traj.num_vertices
    jaw, brows = vertex_group(default_rig, "jaw"), vertex_group(default_rig, "brows")
    x1, x3 = traj.positions([1.0])[0], traj.positions([3.4])[0]
    cs = [end_effector_constraint(1.0, x1[jaw].mean(axis=0) + [0, -0.003, 0], jaw, GaussianBasis(1.0, 0.25),
                                  num_vertices=n, falloff_m=0.05),
          subset_constraint(3.4, x3[brows] + [0, 0.002, 0], brows, GaussianBasis(3.4, 0.3), num_vertices=n,
                            falloff_m=0.03),
          pose_constraint(5.0, traj.positions([5.0])[0], GaussianBasis(5.0, 0.2), num_vertices=n)]
    r = solve_ikd(system, traj, cs, window_s=0.4, tolerance_m=1e-5, max_iterations=6)
    g = r.gradient_ratios()
    assert g[2] is None
    for i in (0, 1):
        assert g[i] == pytest.approx(r.surface.gradient_ratio(r.correction_at(i), cs[i].falloff_m), rel=1e-12)
        assert 0.5 < g[i] <= LIMIT
