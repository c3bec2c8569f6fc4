"""No silent wrong answer: each case found by writing scripts from the docs alone, as a new user would, either gives
the right answer or one clear error (or warning) naming the argument and what was expected."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from kdfaces import (
    FaceAnimation,
    KDInputError,
    KeyframeCurve,
    KinematicTrajectory,
    ShapeTrack,
    load_default_rig,
    simulate_kd,
)
from kdfaces.dynamics import FaceModel, FaceSystem, soft_tissue_settle_map
from kdfaces.rig import BlendshapeRig
from kdfaces.window import automatic_window


@pytest.fixture(scope="module")
def rig():
    return load_default_rig()


def _smile(rig):
    """The README's ten-line smile."""
    smile = ShapeTrack(("mouthSmile_L", "mouthSmile_R"),
                       KeyframeCurve.create([0.0, 0.4, 1.0], [[0, 0], [1, 1], [0.2, 0.2]]))
    return KinematicTrajectory(rig, FaceAnimation(tracks=(smile,), end_s=1.0, fps=25))


def test_a_window_of_zero_means_no_dynamics_the_kinematic_state(rig):
    from kdfaces import solve_ikd
    from kdfaces.ikd import make_basis, subset_constraint

    traj = _smile(rig)
    system = FaceSystem(FaceModel.from_rig(rig))
    est = automatic_window(system, traj)
    assert est.window_s == 0.0  # too gentle to deviate by ε: the automatic window is none at all
    t = traj.frame_times
    x = simulate_kd(system, traj, t, est.window_s)
    assert np.array_equal(x, simulate_kd(system, traj, t, np.zeros(len(t))))  # a scalar 0 as an array of 0
    assert np.allclose(x, traj.evaluate(t, order=0)[0], atol=1e-12)  # x_K itself
    # IKD at window 0 moves x_K itself onto the target
    group = np.arange(10)
    target = traj.evaluate([0.4], order=0)[0][0] + np.array([0.0, 0.002, 0.0])
    c = subset_constraint(0.4, target, group, make_basis("gaussian", 0.4, width_s=0.2), num_vertices=rig.num_vertices)
    r = solve_ikd(system, traj, [c], window_s=0.0)
    assert r.converged and r.errors_after[0] < 1e-5
    with pytest.raises(KDInputError, match="window_s"):
        simulate_kd(system, traj, t, -0.1)


def test_float_face_indices_are_refused_not_truncated(rig):
    faces = rig.faces.astype(np.float64)
    ok = BlendshapeRig.create(rig.neutral, rig.deltas, faces, rig.shape_names)  # whole-number floats are fine
    assert np.array_equal(ok.faces, rig.faces)
    faces[3, 1] += 0.7
    with pytest.raises(KDInputError, match="faces: expected whole-number indices, got"):
        BlendshapeRig.create(rig.neutral, rig.deltas, faces, rig.shape_names)


def test_a_rig_created_from_centimetre_arrays_gets_the_units_warning(rig):
    from kdfaces.io.rigfiles import RigUnitsWarning

    with pytest.warns(RigUnitsWarning, match="the numbers fit a head in cm"):
        BlendshapeRig.create(rig.neutral * 100, rig.deltas * 100, rig.faces, rig.shape_names)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        BlendshapeRig.create(rig.neutral, rig.deltas, rig.faces, rig.shape_names)  # metres: silent


def test_the_settle_map_of_a_rig_without_the_soft_tissue_shapes_is_an_error(rig):
    # numbered names that spell no ARKit name (AK_25_JawOpen canonicalises to jawOpen: tests/test_names.py)
    renamed = BlendshapeRig.create(rig.neutral, rig.deltas, rig.faces,
                                   [f"shape{i:02d}" for i, n in enumerate(rig.shape_names)], name="studio")
    with pytest.raises(KDInputError, match="rig 'studio' has none of the soft-tissue shapes .* pass shapes="):
        soft_tissue_settle_map(renamed, stiff_s=0.2, loose_s=0.5)
    mapped = soft_tissue_settle_map(renamed, stiff_s=0.2, loose_s=0.5,
                                    shapes=[f"shape{i:02d}" for i, n in enumerate(rig.shape_names)
                                            if n.startswith(("jaw", "mouthSmile"))])
    assert mapped.min() == pytest.approx(0.2) and mapped.max() > 0.4  # cheeks and lips loose, bone stiff
    # aliases count: the default rig's own map is unchanged by the alias-aware lookup
    assert np.ptp(soft_tissue_settle_map(rig, stiff_s=0.2, loose_s=0.5)) > 0.2


def test_a_settle_time_of_zero_names_settle_time_s():
    from kdfaces.dynamics.gains import gains_from_settle_time

    with pytest.raises(KDInputError, match=r"^settle_time_s: expected positive seconds"):
        gains_from_settle_time(0.0)


def test_joint_drive_angles_beyond_a_turn_are_degrees_typed_as_radians():
    from kdfaces.motion.joints import JointDrive

    JointDrive(KeyframeCurve.create([0.0, 1.0], [[0.0, 0.0, 0.0], [np.radians(30), 0.0, 0.0]]))
    with pytest.raises(KDInputError, match=r"yaw 30 at key 1 is beyond ±2π; expected radians .* 0.5236 rad"):
        JointDrive(KeyframeCurve.create([0.0, 1.0], [[0.0, 0.0, 0.0], [30.0, 0.0, 0.0]]))


def test_a_youngs_modulus_in_kpa_gets_a_warning():
    from kdfem.fem.materials import Material, MaterialUnitsWarning

    with pytest.warns(MaterialUnitsWarning, match="3 Pa is outside 100–1e.09 Pa"):
        Material(youngs_pa=3.0)
    with pytest.warns(MaterialUnitsWarning):
        Material(youngs_pa=5e10)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Material(youngs_pa=3e3)


def test_subset_constraint_with_a_group_name_says_where_indices_come_from():
    from kdfaces.ikd import make_basis, subset_constraint

    b = make_basis("gaussian", 0.4, width_s=0.2)
    with pytest.raises(KDInputError, match="got the name 'lips'; a named group's indices come from"):
        subset_constraint(0.5, np.zeros((10, 3)), "lips", b, num_vertices=10)
    with pytest.raises(KDInputError, match="whole-number vertex indices"):
        subset_constraint(0.5, np.zeros((2, 3)), [1.5, 2.0], b, num_vertices=10)


def test_tetrahedralize_with_a_missing_envelope_is_one_error():
    import trimesh

    from kdfem.geometry.tetmesh import tetrahedralize

    box = trimesh.creation.box(extents=(0.02, 0.02, 0.04))
    with pytest.raises(KDInputError, match=r"envelope_fac: expected a fraction in \(0, 0.1\), got None"):
        tetrahedralize(box.vertices, box.faces, envelope_fac=None)


def test_window_report_names_its_own_argument_not_the_cli_flag(tmp_path):
    import trimesh

    from kdfem.modal.window import window_report

    path = tmp_path / "box.obj"
    trimesh.creation.box(extents=(0.02, 0.02, 0.04)).export(path)
    with pytest.raises(KDInputError, match=r"^scale: expected a positive factor") as e:
        window_report(path, scale=-1, figures=False, progress=False)
    assert "--scale" not in str(e.value)


def test_the_attachment_message_names_the_object_and_the_argument(rig):
    from kdfem.fem.attachment import attached_nodes

    with pytest.raises(KDInputError, match=r"no node of the object lies within attach_distance_m = 0.02 m"):
        attached_nodes(rig.neutral + np.array([0.0, 5.0, 0.0]), rig.neutral)
    nodes = np.concatenate([rig.neutral[:5], rig.neutral[:5] + [0.0, 1.0, 0.0]])
    with pytest.warns(DeprecationWarning, match="distance"):  # the old keyword still works for one release
        assert attached_nodes(nodes, rig.neutral, distance=0.05).tolist() == [0, 1, 2, 3, 4]


QUIET_SCRIPT = """
import kdfaces, kdfem
from kdfaces import KinematicTrajectory, demo_animation, load_default_rig, simulate_kd
from kdfaces.dynamics import FaceModel, FaceSystem
from kdfem import default_hat_system
rig = load_default_rig()
traj = KinematicTrajectory(rig, demo_animation())
simulate_kd(FaceSystem(FaceModel.from_rig(rig)), traj, [1.0], 0.2)
hat, _, _ = default_hat_system(rig)
simulate_kd(hat, traj, [1.0], 0.05, step_s=0.01)
"""


def test_library_calls_print_nothing_on_stdout(tmp_path):
    """A script that builds a face and a hat system and runs a KD state of each prints nothing to stdout (Warp's
    banner and module-load lines went there); a user who starts Warp first keeps their own settings."""
    import subprocess
    import sys

    env_script = tmp_path / "quiet.py"
    env_script.write_text(QUIET_SCRIPT)
    r = subprocess.run([sys.executable, str(env_script)], capture_output=True, text=True, timeout=600,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout == ""
    user = tmp_path / "user.py"
    user.write_text("import warp as wp\nwp.config.log_level = wp.LOG_INFO\nwp.init()\n"
                    "from kdfaces.resources import init_warp\ninit_warp()\nprint(wp.config.log_level == wp.LOG_INFO)\n")
    r = subprocess.run([sys.executable, str(user)], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.strip().splitlines()[-1] == "True", (r.stdout, r.stderr)


def test_versions_come_from_the_package_metadata_and_dir_shows_public_names():
    from importlib.metadata import version

    import kdfaces
    import kdfem

    assert kdfaces.__version__ == kdfem.__version__ == version("kdfaces")
    for mod in (kdfaces, kdfem):
        names = dir(mod)
        assert "__version__" in names and "annotations" not in names and "importlib" not in names
        assert set(names) == set(mod.__all__) | {"__version__"}


def test_window_report_passes_the_meshing_arguments_through_for_a_user_mesh(tmp_path, monkeypatch):
    """``envelope_fac`` and ``coarsen`` were hard-coded (1e-3, False) for a user's mesh, whatever was given."""
    import trimesh

    import kdfem.geometry.tetmesh as tetmesh
    from kdfem.modal.window import load_object

    seen = {}

    def spy(v, f, **kwargs):
        seen.update(kwargs)
        raise KDInputError("stop here: the arguments are what this test checks")

    monkeypatch.setattr(tetmesh, "tetrahedralize_cached", spy)
    path = tmp_path / "box.obj"
    trimesh.creation.box(extents=(0.02, 0.02, 0.04)).export(path)
    with pytest.raises(KDInputError, match="stop here"):
        load_object(path, envelope_fac=0.007, coarsen=False, edge_length_fac=0.2)
    assert (seen["envelope_fac"], seen["coarsen"], seen["edge_length_fac"]) == (0.007, False, 0.2)


def test_hat_surface_without_an_embedding_is_the_nodes_as_documented():
    from kdfem.fem.system import HatSystem

    doc = HatSystem.surface.__doc__
    assert "without one the tet mesh is its own render mesh" in doc and "needs ``embedding``" not in doc
    x = np.zeros((2, 5, 3))
    fake = type("NoEmbedding", (), {"embedding": None})()
    assert HatSystem.surface(fake, x) is x
