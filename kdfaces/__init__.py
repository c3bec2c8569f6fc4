"""kdfaces: kinodynamics (KD) and inverse kinodynamics (IKD) for blend-shape face rigs.

Units are SI throughout: metres, seconds, kilograms. Arrays of vertex positions are (N, 3) or (T, N, 3).
The subpackages follow the pipeline (rig → motion → dynamics → KD → IKD → viz/io, shots); this module re-exports
what scripts use most. Its names are imported on first use (PEP 562), so ``import kdfaces.cli`` starts fast and the
command-line tools can take over Ctrl-C before any heavy library loads.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    'default_step': 'defaults',
    'FaceModel': 'dynamics',
    'FaceSystem': 'dynamics',
    'soft_tissue_settle_map': 'dynamics',
    'KDError': 'errors',
    'KDInputError': 'errors',
    'KDIOError': 'errors',
    'KDNumericalError': 'errors',
    'SimulationBlowUpError': 'errors',
    'AsymmetricBell': 'ikd',
    'CorrectedTrajectory': 'ikd',
    'Correction': 'ikd',
    'GaussianBasis': 'ikd',
    'IKDResult': 'ikd',
    'PolyBell': 'ikd',
    'end_effector_constraint': 'ikd',
    'independent_check': 'ikd',
    'make_basis': 'ikd',
    'pose_constraint': 'ikd',
    'solve_ikd': 'ikd',
    'subset_constraint': 'ikd',
    'velocity_constraint': 'ikd',
    'export_rig': 'io',
    'export_trajectory': 'io',
    'livelinkface_animation': 'io',
    'load_default_rig': 'io',
    'load_gltf': 'io',
    'load_rig': 'io',
    'read_livelinkface': 'io',
    'save_gltf': 'io',
    'save_npz': 'io',
    'save_obj_folder': 'io',
    'observe_kinematic': 'kd',
    'simulate_full': 'kd',
    'simulate_kd': 'kd',
    'window_steps': 'kd',
    'FaceAnimation': 'motion',
    'JointDrive': 'motion',
    'JointTrajectory': 'motion',
    'KeyframeCurve': 'motion',
    'KinematicTrajectory': 'motion',
    'ShapeTrack': 'motion',
    'SkeletonAnimation': 'motion',
    'BlendshapeRig': 'rig',
    'Skeleton': 'rig',
    'kinematic_pose': 'rig',
    'rig_pose': 'rig',
    'vertex_group': 'rig',
    'DEMO_SHOT': 'shots',
    'demo_animation': 'shots',
    'load_shot': 'shots',
    'run_shot': 'shots',
    'kd_error_report': 'viz.kd_report',
    'write_kd_report': 'viz.kd_report',
    'AdaptiveWindows': 'window',
    'WindowEstimate': 'window',
    'adaptive_windows': 'window',
    'automatic_window': 'window',
    'window_1d': 'window',
}

__all__ = [
    # rigs and motion
    "BlendshapeRig", "Skeleton", "kinematic_pose", "rig_pose", "vertex_group", "KeyframeCurve", "ShapeTrack",
    "FaceAnimation", "JointDrive", "SkeletonAnimation", "KinematicTrajectory", "JointTrajectory",
    # files
    "load_default_rig", "load_rig", "save_npz", "save_obj_folder", "load_gltf", "save_gltf", "read_livelinkface",
    "livelinkface_animation", "export_trajectory", "export_rig",
    # face kinodynamics (§3, §4.5, §5.2)
    "FaceModel", "FaceSystem", "soft_tissue_settle_map", "simulate_kd", "simulate_full", "observe_kinematic",
    "window_steps", "default_step", "automatic_window", "window_1d", "WindowEstimate", "adaptive_windows",
    "AdaptiveWindows", "kd_error_report",
    "write_kd_report",
    # inverse kinodynamics (§3.1, §4)
    "solve_ikd", "IKDResult", "independent_check", "pose_constraint", "subset_constraint", "velocity_constraint",
    "end_effector_constraint", "GaussianBasis", "PolyBell", "AsymmetricBell", "make_basis", "Correction",
    "CorrectedTrajectory",
    # shots
    "load_shot", "run_shot", "demo_animation", "DEMO_SHOT",
    # errors
    "KDError", "KDInputError", "KDNumericalError", "SimulationBlowUpError", "KDIOError",
]


def lazy_exports(package: str, exports: dict, names) -> tuple:
    """(``__getattr__``, ``__dir__``) for a package whose public names are imported on first use (PEP 562):
    ``exports`` maps a name to the submodule (relative to ``package``) that defines it; ``__version__`` comes from
    the installed distribution's metadata (kdfaces and kdfem are one distribution); ``dir()`` shows ``names`` and
    ``__version__`` only."""
    import sys

    def __getattr__(name: str):
        if name == "__version__":
            from importlib.metadata import PackageNotFoundError, version

            try:
                value = version("kdfaces")
            except PackageNotFoundError:  # pragma: no cover - a source tree that was never installed
                value = "0+unknown"
        elif name in exports:
            value = getattr(importlib.import_module(f".{exports[name]}", package), name)
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        setattr(sys.modules[package], name, value)
        return value

    def __dir__():
        return sorted([*names, "__version__"])

    return __getattr__, __dir__


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, __all__)
