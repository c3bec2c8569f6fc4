"""One default per concept: every public signature of kdfaces and kdfem (the names in each package's and
subpackage's ``__all__``, and the public methods of exported classes) gives a parameter of one name one literal
default, and the concepts with a name in :mod:`kdfaces.defaults` use its value. A name that means different things
in different places is listed below with the reason; None ("the default", documented) is always allowed."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from collections import defaultdict
from pathlib import Path

import pytest

from kdfaces import defaults

ROOT = Path(__file__).resolve().parents[1]

#: parameter name → the kdfaces.defaults name every place must use
CONCEPTS = {
    "settle_time_s": "SETTLE_TIME_S", "damping_ratio": "DAMPING_RATIO", "shape_matching_alpha": "SHAPE_MATCHING_ALPHA",
    "width_s": "WIDTH_S", "ease_out_s": "EASE_OUT_S", "threads": "THREADS", "edge_length_fac": "TET_EDGE_LENGTH_FAC",
    "envelope_fac": "TET_ENVELOPE_FAC", "coarsen": "TET_COARSEN", "youngs_pa": "YOUNGS_PA",
    "poisson_ratio": "POISSON_RATIO", "density_kg_m3": "DENSITY_KG_M3", "tol_m": "NEWTON_TOL_M",
    "attach_distance_m": "ATTACH_DISTANCE_M", "omega_max_radps": "OMEGA_MAX_RADPS", "v_max_mps": "V_MAX_MPS",
    "rayleigh_alpha": "RAYLEIGH_ALPHA", "rayleigh_beta": "RAYLEIGH_BETA", "falloff_m": "FALLOFF_M",
    "step_scale": "STEP_SCALE", "tolerance_mps": "TOLERANCE_MPS", "max_correction_m": "MAX_CORRECTION_M",
    "frame_start": "FRAME_START",
}

#: (parameter, place) → (the value it must have, why it is another concept than the same name elsewhere)
OTHER_CONCEPTS = {
    ("damping_ratio", "OnTheBeat"): (defaults.JOINT_DAMPING_RATIO, "a joint's PD, not the face's soft tissue"),
    ("damping_ratio", "SkeletalSystem"): (defaults.JOINT_DAMPING_RATIO, "a joint's PD, not the face's soft tissue"),
    ("settle_time_s", "SkeletalSystem"): (defaults.JOINT_SETTLE_TIME_S, "a joint's PD, not the face's soft tissue"),
    ("settle_time_s", "run_follow"): ("FOLLOW_SETTLE_S", "the follow scene's neck tension"),
    ("step_s", "run_follow"): (defaults.HAT_STEP_S, "the hat's step"),
    ("step_s", "run_hat_demo"): (defaults.HAT_STEP_S, "the hat's step"),
    ("step_s", "simulate_keyframes"): (0.002, "the articulated engines' step (stiff joints), not a face's frame step"),
    ("step_s", "constraint_markers"): (0.04, "the spacing of drawn velocity markers, not a simulation step"),
    ("step_s", "BakeResult"): (0.0, "a result field (filled in), not a parameter"),
    ("window_s", "BakeResult"): (0.0, "a result field (filled in), not a parameter"),
    ("window_s", "run_hat_demo"): (defaults.HAT_WINDOW_S, "the hat's §5.3 window"),
    ("tolerance_m", "solve_ik"): (1e-7, "plain IK of a skeleton (no dynamics), not the IKD stopping tolerance"),
    ("max_iterations", "solve_ik"): (200, "plain IK of a skeleton (no dynamics), not IKD sweeps"),
    ("update", "offset_grid"): ("paper", "the Fig. 9 figure's baseline update, compared against the secant"),
    ("pinv_damping", "SurfaceLift.point"): (0.0, "the lift of one point, exact unless asked"),
    ("unit_m", "load_makehuman"): ("MAKEHUMAN_UNIT_M", "MakeHuman files are in decimetres"),
    ("max_steps", "check_door_work"): ("DOOR_MAX_STEPS", "KD steps of the door scene, not vertex-steps"),
    ("modes", "window_report"): (6, "modes reported, not a reduced basis"),
    ("modes", "modal_adaptive_windows"): (12, "modes summed in the adaptive envelope, not a reduced basis"),
    ("rings", "ring_clusters"): (1, "k of a k-ring (the generic function; FaceModel.create uses CLUSTER_RINGS)"),
    ("rings", "HatParams"): (24, "mesh divisions along the hat's cone"),
    ("fraction", "vertex_group"): (0.25, "a share of the mesh, not a settle fraction"),
    ("torque_limit_nm", "neck_chain_model"): (40.0, "the neck's motors, not the arm's"),
    ("threads", "hat_offset_grid"): (1, "the Fig. 9 figure on one thread: its numbers repeat exactly (a hat batch "
                                        "split over threads differs in round-off)"),
    ("threads", "hat_tip_problem"): (1, "the Fig. 9 figure's hat, on one thread like the figure"),
}
#: names that are words of different things everywhere: labels, messages' "where", modes, figure sizes
UNRELATED = {"label", "where", "name", "mode", "size", "local", "damping"}


def public_modules():
    for pkg_name in ("kdfaces", "kdfem"):
        pkg = importlib.import_module(pkg_name)
        yield pkg
        for info in pkgutil.walk_packages(pkg.__path__, pkg_name + "."):
            if info.ispkg:
                yield importlib.import_module(info.name)


def public_callables():
    """(place, parameters) of every public callable of both packages: each name in a public module's ``__all__``
    (once) and the public methods of exported classes, by qualified name."""
    seen = set()
    for module in public_modules():
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if id(obj) in seen or (getattr(obj, "__module__", "") or "").split(".")[0] not in ("kdfaces", "kdfem"):
                continue
            seen.add(id(obj))
            fns = [(obj.__qualname__, obj)] if callable(obj) else []
            if inspect.isclass(obj):
                fns += [(f"{obj.__qualname__}.{a}", getattr(m, "__func__", m)) for a, m in vars(obj).items()
                        if not a.startswith("_") and inspect.isfunction(getattr(m, "__func__", m))]
            for place, fn in fns:
                try:
                    yield place, inspect.signature(fn).parameters.values()
                except (TypeError, ValueError):
                    continue


def signatures():
    """(place, parameter name, default) of every literal default in a public signature."""
    out = []
    for place, params in public_callables():
        for p in params:
            if p.default is not inspect.Parameter.empty and p.default is not None and \
                    isinstance(p.default, bool | int | float | str | tuple):
                out.append((place, p.name, p.default))
    return out


def _expected(value):
    if isinstance(value, str) and value.isupper():
        for module in ("kdfem.scenes", "kdfaces.io.rigfiles", "kdfem.scenes.door", "kdfem.scenes.follow"):
            m = importlib.import_module(module)
            if hasattr(m, value):
                return getattr(m, value)
    return value


def test_one_literal_default_per_concept():
    by_name = defaultdict(list)
    for place, name, default in signatures():
        by_name[name].append((place, default))
    problems = []
    for name, places in sorted(by_name.items()):
        if name in UNRELATED:
            continue
        rest = []
        for place, default in places:
            if (name, place) in OTHER_CONCEPTS:
                want = _expected(OTHER_CONCEPTS[name, place][0])
                if default != want:
                    problems.append(f"{place}({name}={default!r}): expected {want!r}, the value listed here")
            else:
                rest.append((place, default))
        if name in CONCEPTS:
            want = getattr(defaults, CONCEPTS[name])
            problems += [f"{place}({name}={d!r}): expected defaults.{CONCEPTS[name]} = {want!r}"
                         for place, d in rest if d != want]
        elif len({repr(d) for _, d in rest}) > 1:
            problems.append(f"{name}: {sorted({(repr(d), p) for p, d in rest})}")
    assert problems == []


def test_the_walk_sees_both_packages_and_the_listed_places_exist():
    places = {(name, place) for place, name, _ in signatures()}
    assert {"FaceModel.create", "tetrahedralize", "window_report", "Material", "HatSystem", "ImplicitEuler"} <= \
        {p for _, p in places}
    assert set(OTHER_CONCEPTS) <= places, set(OTHER_CONCEPTS) - places  # a stale exception is an error too


def test_a_second_literal_default_is_caught(monkeypatch):
    import kdfaces.dynamics

    def gains_from_settle_time(settle_time, *, damping_ratio: float = 1.0):
        """A stand-in with the old default."""

    gains_from_settle_time.__module__ = "kdfaces.dynamics.gains"
    monkeypatch.setattr(kdfaces.dynamics, "gains_from_settle_time", gains_from_settle_time)
    with pytest.raises(AssertionError, match=r"gains_from_settle_time\(damping_ratio=1.0\)"):
        test_one_literal_default_per_concept()


def test_the_material_and_the_demo_hat_agree():
    from kdfem.fem import DEFAULT_MATERIAL, Material

    assert DEFAULT_MATERIAL == Material()
    assert (Material().youngs_pa, Material().poisson_ratio, Material().density_kg_m3) == \
        (defaults.YOUNGS_PA, defaults.POISSON_RATIO, defaults.DENSITY_KG_M3)


def test_every_default_is_documented_with_its_unit():
    """Every data name of kdfaces.defaults has a #: comment (its meaning and unit), shared by the names right after
    it; the docs' Defaults page renders them from the module (docs/_ext/kd_defaults.py), so it cannot go stale."""
    import sys

    sys.path.insert(0, str(ROOT / "docs" / "_ext"))
    from kd_defaults import default_entries

    entries = default_entries()
    data = [n for n in defaults.__all__ if not callable(getattr(defaults, n))]
    assert [e[0] for e in entries] == data
    assert all(doc.strip() for _, _, doc in entries), [n for n, _, d in entries if not d.strip()]
    page = (ROOT / "docs" / "defaults.rst").read_text()
    assert ".. kd-defaults::" in page and "defaults" in (ROOT / "docs" / "index.rst").read_text()
    assert re.search(r"autodoc_preserve_defaults\s*=\s*False", (ROOT / "docs" / "conf.py").read_text())
