"""One set of defaults, used alike by the Python API, shot files and the command-line tools.

Change a default here and every entry point follows. ``None`` for a step means "the animation's frame interval"
(:func:`default_step`), so frames land on the simulation grid whatever the capture rate.
"""

from __future__ import annotations

from .errors import KDInputError

__all__ = [
    "SETTLE_TIME_S", "DAMPING_RATIO", "JOINT_SETTLE_TIME_S", "JOINT_DAMPING_RATIO", "SHAPE_MATCHING_ALPHA",
    "DAMPING_MODE", "AREAL_DENSITY_KG_M2",
    "CLUSTER_RINGS", "REGION_MARGIN_RINGS", "ROTATION", "ROTATION_ITERATIONS",
    "PROXY_ROTATION_ITERATIONS", "WINDOW_S", "STEP_S", "EPSILON_FRACTION",
    "FACE_REGION", "FACE_PROXY", "PROXY_ABOVE_VERTICES", "PROXY_EMBEDDING", "PROXY_EMBEDDINGS",
    "MAX_WINDOW_STEPS", "MAX_SOLVE_WALL_S", "WIDTH_S", "CURVE", "PINV_DAMPING", "FALLOFF_M", "LIFT_ENERGY",
    "SOLVER_UPDATE",
    "STEP_SCALE", "TOLERANCE_M", "TOLERANCE_MPS", "MAX_ITERATIONS", "MAX_CORRECTION_M", "EASE_OUT_S", "THREADS",
    "TET_EDGE_LENGTH_FAC", "TET_ENVELOPE_FAC", "TET_COARSEN", "YOUNGS_PA", "POISSON_RATIO", "DENSITY_KG_M3",
    "MATERIAL_MODEL", "NEWTON_TOL_M", "CONTACT_DHAT_FAC", "CONTACT_GRID_NODES", "CONTACT_FRICTION_EPS_V_MPS",
    "CCD_TOLERANCE", "CCD_MAX_ITERATIONS", "ATTACH_DISTANCE_M", "HAT_COLLIDERS", "OMEGA_MAX_RADPS", "V_MAX_MPS",
    "RAYLEIGH_ALPHA", "RAYLEIGH_BETA", "HAT_STEP_S", "HAT_WINDOW_S", "BAKE_CHUNK_FRAMES", "FRAME_START",
    "WINDOW_MODES", "FIXED_WINDOW_S", "MAX_STEPS", "SCAN_COST", "default_step", "user_cache_dir", "window_argument",
    "max_steps_argument",
]

# --- face dynamics (paper §4.5; On the Beat eq. 4) ----------------------------------------------------------------
#: Settle time t̂ [s]: 90 % of a tracking error is gone after this long.
SETTLE_TIME_S = 0.25
#: Damping ratio ζ (1 = critically damped, On the Beat eq. 4; < 1 overshoots, which is the secondary motion).
DAMPING_RATIO = 0.3
#: The skeletal KD's joint controller (:class:`kdfaces.articulated.SkeletalSystem`, On the Beat §4): settle time
#: t̂ [s] and damping ratio ζ of each joint's PD (1: critically damped, eq. 4 as published). Another concept than
#: the face's soft tissue above, which overshoots on purpose.
JOINT_SETTLE_TIME_S = 0.2
JOINT_DAMPING_RATIO = 1.0
#: Müller shape-matching stiffness α ∈ [0, 1].
SHAPE_MATCHING_ALPHA = 0.2
#: "relative" damps ẋ − ẋ_K; "absolute" is the paper's −K_d·ẋ.
DAMPING_MODE = "relative"
#: Lumped vertex mass per unit area [kg/m²].
AREAL_DENSITY_KG_M2 = 10.0
#: Shape-matching clusters are the k-rings of cluster centres.
CLUSTER_RINGS = 2
#: The moving region (:func:`kdfaces.rig.region.moving_region`) reaches this many mesh rings past the vertices the
#: shapes move and the head chain skins, so its boundary does not cut through moving skin.
REGION_MARGIN_RINGS = 2
#: What a face model simulates (:meth:`kdfaces.dynamics.FaceModel.from_rig`): "auto", the rig's moving region
#: (the rest follows x_K exactly), or None for every vertex.
FACE_REGION = "auto"
#: Face KD on a proxy (:meth:`kdfaces.dynamics.FaceModel.from_rig`, :mod:`kdfaces.dynamics.proxy`): "auto" simulates
#: a proxy and carries the dense mesh with it when the region has more than :data:`PROXY_ABOVE_VERTICES` non-rigid
#: vertices; None: always the dense mesh.
FACE_PROXY = "auto"
#: "auto" proxies faces above this many simulated vertices: above the 27k production rigs, whose dense KD is 25 ms per
#: state and whose tests are held to dense tolerances; the default head (4.8k) and its 19k subdivision stay dense.
PROXY_ABOVE_VERTICES = 30_000
#: How a proxy carries the dense mesh (W, :meth:`kdfaces.dynamics.FaceModel.from_rig`'s ``proxy_embedding``):
#: "fitted" learns every row's weights from the dense and proxy KD states of an excitation take
#: (:mod:`kdfaces.dynamics.proxy_fit`; every frame of the demo and of a 60 s capture within ε/2 at 19k and 75k);
#: "closest" is the closest point of a proxy triangle in shape space (:func:`kdfaces.rig.proxy.embedding_matrix`;
#: up to 1.04 ε at 19k and 1.84 ε at 75k), built without simulating anything.
PROXY_EMBEDDING = "fitted"
PROXY_EMBEDDINGS = ("fitted", "closest")
#: Cluster rotation fit: "iterative" (Newton on SO(3), warm-started; matches "svd3" within ε/100, several times
#: faster) or "svd3"; and the iterative fit's Newton iterations per step.
ROTATION = "iterative"
ROTATION_ITERATIONS = 2
#: The iterative fit's Newton iterations per step on a proxy (:meth:`kdfaces.dynamics.FaceModel.from_rig` with a
#: proxy, unless ``rotation_iterations`` is given): warm-started from the previous step's rotation, one Newton step
#: lags the exact fit by about the square of the step's rotation change and the lag does not accumulate. On the 75k
#: face's 4k proxy it takes a fifth off every step; the proxy's largest error against the dense KD states stayed
#: 0.19 / 0.33 ε on the demo (19k / 75k) and 0.48 ε on the 60 s capture (75k), as with two (docs/dense-rigs.md).
PROXY_ROTATION_ITERATIONS = 1

# --- KD windows (§3, §5) -------------------------------------------------------------------------------------------
#: "auto": the §5.2 (faces) or §5.3 (FEM objects) window; "adaptive": a window per frame, the smallest whose
#: truncation error is bounded by ε (:func:`kdfaces.window.adaptive_windows`); or seconds.
WINDOW_S = "auto"
#: The window values that are words, not seconds.
WINDOW_MODES = ("auto", "adaptive")
#: The seconds a Blender object's KD window starts at when its window mode is switched to "seconds"
#: (kdfaces/blender: the panel's field; "auto" stays the default mode, :data:`WINDOW_S`).
FIXED_WINDOW_S = 0.5
#: Simulation step [s]; None = the animation's frame interval.
STEP_S = None
#: ε as a fraction of the object's diameter (§5.3 uses 0.1 %).
EPSILON_FRACTION = 1e-3
#: The most steps one KD window may take (a window is seconds long, not hours; a larger count is a unit mix-up or
#: an absurd settle time or damping ratio, and would run for hours).
MAX_WINDOW_STEPS = 10_000
#: The longest an IKD solve may run [s] before it stops and reports what it reached.
MAX_SOLVE_WALL_S = 3600.0

# --- IKD (§3.1, §4) ------------------------------------------------------------------------------------------------
#: Width σ [s] of a constraint's correction bell (the ease-in width of an asymmetric bell).
WIDTH_S = 0.3
#: Ease-out width [s] of an asymmetric bell (after the constraint time): twice :data:`WIDTH_S`, so that an
#: ``"asymmetric"`` bell without an explicit ``ease_out_s`` is asymmetric.
EASE_OUT_S = 0.6
#: Shape of the correction bell: "gaussian", "poly" or "asymmetric".
CURVE = "gaussian"
#: μ of the damped pseudo-inverse Jᵀ(JJᵀ + μ²I)⁻¹ of end-effector constraints, relative to ‖J‖².
PINV_DAMPING = 1e-3
#: Geodesic radius [m] over which a subset, velocity or end-effector correction falls off to zero outside its
#: vertices (0: the paper's sharp lift, the correction on the constrained vertices only).
FALLOFF_M = 0.05
#: Smoothness energy of that falloff: "biharmonic" (LᵀM⁻¹L, C¹) or "harmonic" (−L).
LIFT_ENERGY = "biharmonic"
#: "secant" (batched, ours) or "paper" (Algorithm 1).
SOLVER_UPDATE = "secant"
#: Scale s of each update (0.8 is the paper's "scaled" variant).
STEP_SCALE = 1.0
#: Stop when every constraint is within these [m], [m/s].
TOLERANCE_M = 1e-5
TOLERANCE_MPS = 1e-4
#: Sweeps over all constraints.
MAX_ITERATIONS = 20
#: Largest per-vertex correction [m] before a target is reported out of reach.
MAX_CORRECTION_M = 0.5

# --- threads ------------------------------------------------------------------------------------------------------
#: CPU threads per KD step (the face: the calling thread and ``THREADS`` − 1 persistent workers share one state or
#: split a batch; the hat: groups of whole windows in parallel). Two, everywhere: the demos, ``run_shot`` and the
#: viewer always ran on two (so their outputs stay as they were), a face's results do not depend on it (bit for
#: bit, tests/test_kd.py; the hat's agree within round-off), the KD step is ~1.8× faster on two cores, and a
#: second thread costs little on one. Bake workers pass ``threads=1`` themselves (one Dask worker process per core).
THREADS = 2

# --- FEM objects (kdfem) -------------------------------------------------------------------------------------------
#: pytetwild target edge length and envelope, relative to the surface's bounding-box diagonal, and whether it
#: coarsens: a coarse (~1k-tet for the hat) simulation mesh in which the fine surface is embedded. One set for
#: every mesher entry point (:func:`kdfem.geometry.tetrahedralize`, the hat, :func:`kdfem.modal.window_report` of a
#: user's mesh). (0.06, 1e-3, False) gives a fine mesh that follows the surface tightly.
TET_EDGE_LENGTH_FAC = 0.09
TET_ENVELOPE_FAC = 0.004
TET_COARSEN = True
#: The FEM material (:class:`kdfem.fem.Material`): a floppy knitted hat. Young's modulus E [Pa], Poisson ratio ν [-],
#: mass density ρ [kg/m³], energy ("neohookean": stable Neo-Hookean; "corotated").
YOUNGS_PA = 3.0e3
POISSON_RATIO = 0.3
DENSITY_KG_M3 = 150.0
MATERIAL_MODEL = "neohookean"
#: Newton tolerance [m] of the FEM's backward-Euler step: the largest position update max|Δv|·h at convergence.
NEWTON_TOL_M = 1e-6
#: Contact barrier activation distance d̂ / the object's rest bounding-box diagonal (kdfem.fem.contact).
CONTACT_DHAT_FAC = 1e-3
#: ipctk's TightInclusion CCD in the FEM contact step (kdfem.fem.integrator): its tolerance (of the time of impact
#: over a step, so of the step fraction [-]) and iteration bound. The result stays a conservative collision-free
#: step; ipctk's defaults (1e-6, 10⁷) spent up to 20 s on one query of a face resting parallel to a collider's.
CCD_TOLERANCE = 1e-4
CCD_MAX_ITERATIONS = 1_000_000
#: Nodes of a collider's broad-phase distance grid (over its bounding box; kdfem.fem.contact.DistanceGrid).
CONTACT_GRID_NODES = 2 ** 18
#: Friction mollifier ε_v [m/s]: tangential speeds below it are static friction (IPC §5; ipctk FrictionPotential).
CONTACT_FRICTION_EPS_V_MPS = 1e-3
#: FEM nodes within this distance [m] of the head surface follow the head joint.
ATTACH_DISTANCE_M = 0.02
#: Whether the hat's scenes (``kdfem demo``, ``door``, ``follow``) give the hat the head as a collider (and the
#: door's lintel in ``kdfem door``; kdfem.fem.contact); ``--no-colliders`` turns them off.
HAT_COLLIDERS = True
#: The worst-case jump of the bone's angular [rad/s] and linear [m/s] speed the modal window is sized for (eq. 30).
OMEGA_MAX_RADPS = 4.0
V_MAX_MPS = 2.0
#: Rayleigh damping C = αM + βK: α [1/s], β [s].
RAYLEIGH_ALPHA = 1.0
RAYLEIGH_BETA = 0.01
#: The hat's simulation step [s] and KD window [s].
HAT_STEP_S = 0.01
HAT_WINDOW_S = 0.568

# --- work limits (estimated before anything runs) -----------------------------------------------------------------
#: The most work a command plans, in vertex-steps (one vertex advanced by one simulation step), estimated when the
#: shot is loaded, before the window scan, the IKD solve or any allocation (:func:`kdfaces.shots.estimate_work`):
#: frames × steps per KD state × vertices for the KD of every frame (twice with constraints: KD and IKD), the IKD
#: solve's KD states, and the automatic window's scan of x_K (each sampled vertex counts :data:`SCAN_COST`).
#: 1e10 is about 15 minutes of face KD on two CPU cores (~1e7 vertex-steps/s measured on the default 4,774-vertex
#: head): a two-minute 60 fps take on a 30,000-vertex rig fits, a ten-hour keyed shot does not. ``--max-steps``
#: raises it; ``max_steps=None`` (Python) lifts it.
MAX_STEPS = 1e10
#: What sampling x_K, ẋ_K, ẍ_K of one vertex at one time costs, in vertex-steps (blend shapes and neck/head
#: skinning: about four face steps, measured).
SCAN_COST = 4

# --- bakes (kdfaces bake) ------------------------------------------------------------------------------------------
#: Frames per bake task (one chunk of the store): large enough that a task's KD batch dwarfs Dask's per-task
#: overhead, small enough that a 2-minute take gives every worker of a few machines many tasks.
BAKE_CHUNK_FRAMES = 32

# --- exports (USD, PC2, glTF) --------------------------------------------------------------------------------------
#: The scene frame of a shot's first frame in every export: shot frame k is scene frame FRAME_START + k (USD time
#: code, PC2 header start and Mesh Cache start frame, glTF key time (FRAME_START + k) / fps). 1 is Blender's default
#: scene start.
FRAME_START = 1


def user_cache_dir():
    """Where the command-line tools keep parsed rigs and tet meshes by content hash: ``$KDFACES_CACHE``, else
    ``~/.cache/kdfaces`` (library calls cache only where they are told to)."""
    import os
    from pathlib import Path

    return Path(os.environ.get("KDFACES_CACHE", Path.home() / ".cache" / "kdfaces"))


def default_step(trajectory, step_s: float | None = None) -> float:
    """``step_s`` [s] if given, else the trajectory's frame interval 1/fps (so frames lie on the step grid)."""
    if step_s is not None:
        s = step_s
    else:
        fps = getattr(trajectory, "fps", None)
        if fps is None:
            raise KDInputError("step_s: this trajectory has no frame rate; give the simulation step in seconds")
        s = 1.0 / float(fps)
    if isinstance(s, bool) or not isinstance(s, int | float) or not (s > 0 and s < float("inf")):
        raise KDInputError(f"step_s: expected a positive number of seconds, got {s!r}")
    return float(s)


def window_argument(text: str):
    """A ``--window`` command-line value: seconds (a float), or one of :data:`WINDOW_MODES`."""
    import argparse

    if text in WINDOW_MODES:
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, 'auto' or 'adaptive', got {text!r}") from None


def max_steps_argument(text: str) -> float:
    """A ``--max-steps`` command-line value: a positive number of vertex-steps (``1e10``, ``3e11``; ``inf`` lifts
    the limit); see :data:`MAX_STEPS`."""
    import argparse
    import math

    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number of vertex-steps (e.g. 1e10), got {text!r}")
    return value


_RENAMED = {"HAT_EDGE_LENGTH_FAC": "TET_EDGE_LENGTH_FAC", "HAT_ENVELOPE_FAC": "TET_ENVELOPE_FAC"}


def __getattr__(name: str):
    if name in _RENAMED:
        from .deprecation import warn_renamed

        warn_renamed("kdfaces.defaults", name, _RENAMED[name])
        return globals()[_RENAMED[name]]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
