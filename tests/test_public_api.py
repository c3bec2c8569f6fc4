"""The public surface: every name the packages export has a docstring (classes: their public methods and properties
too), the README's names are exported, and renamed arguments keep working for a release with a warning."""

from __future__ import annotations

import importlib
import inspect
import warnings

import numpy as np
import pytest

PACKAGES = ["kdfaces", "kdfaces.rig", "kdfaces.motion", "kdfaces.dynamics", "kdfaces.ikd", "kdfaces.io",
            "kdfaces.bake", "kdfaces.articulated",
            "kdfaces.viz", "kdfaces.shots", "kdfem", "kdfem.geometry", "kdfem.fem", "kdfem.modal",
            "kdfem.scenes", "kdfem.viewer"]


def _project(obj) -> bool:
    return (getattr(obj, "__module__", "") or "").split(".")[0] in ("kdfaces", "kdfem")


def undocumented(pkg: str) -> list[str]:
    module = importlib.import_module(pkg)
    missing = []
    for name in module.__all__:
        obj = getattr(module, name)
        if not (inspect.isclass(obj) or callable(obj)) or not _project(obj):
            continue  # data (documented by its #: comment) and re-exported foreign objects
        if not (inspect.getdoc(obj) or "").strip():
            missing.append(f"{pkg}.{name}")
        if inspect.isclass(obj):
            for attr, member in vars(obj).items():
                if attr.startswith("_"):
                    continue
                fn = member.fget if isinstance(member, property) else getattr(member, "__func__", member)
                if (inspect.isfunction(fn) or isinstance(member, property)) and not (fn.__doc__ or "").strip():
                    missing.append(f"{pkg}.{name}.{attr}")
    return missing


@pytest.mark.parametrize("pkg", PACKAGES)
def test_every_public_name_has_a_docstring(pkg):
    assert undocumented(pkg) == []


def test_the_top_level_exports_what_users_script_with():
    import kdfaces
    import kdfem

    for name in ("solve_ikd", "pose_constraint", "subset_constraint", "end_effector_constraint", "velocity_constraint",
                 "GaussianBasis", "make_basis", "kinematic_pose", "export_trajectory", "run_shot", "load_shot",
                 "JointTrajectory", "KDError", "demo_animation", "vertex_group"):
        assert name in kdfaces.__all__, name
    for name in ("default_hat_system", "window_report", "HatSystem", "run_hat_demo"):
        assert name in kdfem.__all__, name


def test_renamed_arguments_warn_and_still_work():
    from kdfaces import GaussianBasis, KDInputError, make_basis, simulate_kd, window_1d
    from kdfaces.dynamics import FaceModel

    with pytest.warns(DeprecationWarning, match="'epsilon' is renamed 'epsilon_m'"):
        old = window_1d(1.0, 100.0, 2.0, epsilon=1e-3)
    assert old == window_1d(1.0, 100.0, 2.0, epsilon_m=1e-3)
    with pytest.warns(DeprecationWarning, match="'sigma' is renamed 'width_s'"):
        assert make_basis("gaussian", 1.0, sigma=0.2) == GaussianBasis(1.0, 0.2)
    with pytest.warns(DeprecationWarning, match="'alpha' is renamed 'shape_matching_alpha'"):
        m = FaceModel.create(np.zeros((1, 3)), np.zeros((0, 3), np.int64), alpha=0.0, mass=1.0)
    assert m.shape_matching_alpha == 0.0
    with pytest.raises(KDInputError, match="both 'h'"):
        simulate_kd(None, None, [0.0], 0.1, h=0.01, step_s=0.01)


def test_one_set_of_defaults():
    """The Python API, shot files and the command line share the defaults of kdfaces.defaults."""
    from kdfaces import defaults
    from kdfaces.dynamics import FaceModel
    from kdfaces.ikd import solve_ikd
    from kdfaces.shots.shotfile import DYNAMICS_DEFAULTS, SOLVER_DEFAULTS

    create = inspect.signature(FaceModel.create).parameters
    solve = inspect.signature(solve_ikd).parameters
    assert create["settle_time_s"].default == DYNAMICS_DEFAULTS["settle_time_s"] == defaults.SETTLE_TIME_S
    assert create["damping_ratio"].default == DYNAMICS_DEFAULTS["damping_ratio"] == defaults.DAMPING_RATIO
    assert create["shape_matching_alpha"].default == DYNAMICS_DEFAULTS["shape_matching_alpha"]
    for key in ("update", "step_scale", "tolerance_m", "tolerance_mps", "max_iterations", "max_correction_m"):
        assert solve[key].default == SOLVER_DEFAULTS[key], key
    assert solve["step_s"].default is None  # the trajectory's frame interval, as a shot's step_s = "frame"


def test_library_calls_set_no_global_state(tmp_path):
    """Importing the packages and drawing a figure leave matplotlib's backend and Warp's config alone."""
    import matplotlib
    import warp as wp

    backend, level = matplotlib.get_backend(), wp.config.log_level
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import kdfem  # noqa: F401
        from kdfaces.viz.figures import save_figure, subplots

    fig, ax = subplots()
    ax.plot([0, 1], [0, 1])
    save_figure(fig, tmp_path / "f.png")
    assert matplotlib.get_backend() == backend and wp.config.log_level == level
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png"]
