"""The glossary's rule, for kdfaces and kdfem alike: a parameter or field of a public signature that carries a
physical quantity names its unit as a suffix (docs/glossary.rst lists them), and every suffix in use is one the
glossary explains. Walks the same signatures as tests/test_defaults.py."""

from __future__ import annotations

import re
from pathlib import Path

from test_defaults import public_callables  # the same walk

ROOT = Path(__file__).resolve().parents[1]

#: quantity names that need a unit (the names renamed with shims keep working, but not in a signature)
BARE = re.compile(r"^(h|tol|time|distance|speed|velocity|acceleration(_max)?|initial_speed|length|height|radius|"
                  r"width|thickness|diameter|youngs|density|omega_max|v_max|epsilon|sigma|brim_width|brim_height|"
                  r"base_center|attach_distance|attach_below|settle_time|window|step)$")
#: unit suffixes (the longest match wins)
SUFFIXES = ("_kg_m3", "_kg_m2", "_mps2", "_radps", "_mps", "_deg", "_pa", "_fac", "_hz", "_nm", "_m3", "_ms",
            "_s", "_m")
#: (parameter, place) left as they are, with the reason
LEFT = {
    ("window", "ModalAnalysis"): "a ModalWindow (its window_s is the seconds), not a length of time",
}


def parameters():
    """(place, parameter name) of every public signature of both packages, fields of exported classes included."""
    return {(place, p.name) for place, params in public_callables() for p in params if p.name not in ("self", "cls")}


def test_quantities_carry_their_unit_in_both_packages():
    params = parameters()
    assert {p for p, _ in params} >= {"window_report", "Material", "HatParams", "ImplicitEuler", "FaceModel.create"}
    bare = sorted((name, place) for place, name in params if BARE.match(name) and (name, place) not in LEFT)
    assert bare == []


def test_every_suffix_in_use_is_in_the_glossary():
    text = (ROOT / "docs" / "glossary.rst").read_text()
    rule = text.split(".. glossary::")[0]
    used = {next(s for s in SUFFIXES if name.endswith(s)) for _, name in parameters()
            if any(name.endswith(s) for s in SUFFIXES)}
    assert {"_s", "_m", "_mps"} <= used
    assert sorted(s for s in used if f"``{s}``" not in rule) == []


def test_the_left_names_still_exist():
    params = {(name, place) for place, name in parameters()}
    assert set(LEFT) <= params  # once renamed, drop them here


def test_the_old_names_warn_for_one_release_and_still_work():
    import numpy as np
    import pytest

    from kdfaces import defaults
    from kdfaces.dynamics import FaceModel
    from kdfaces.window import WindowEstimate
    from kdfem.fem.integrator import ImplicitEuler
    from kdfem.fem.materials import Material
    from kdfem.geometry.hat import HatParams
    from kdfem.modal.window import window_report

    with pytest.warns(DeprecationWarning, match="'youngs' is renamed 'youngs_pa'"):
        m = Material(youngs=3e4, poisson_ratio=0.25, density_kg_m3=100.0)
    assert (m.youngs_pa, m.poisson_ratio, m.density_kg_m3) == (3e4, 0.25, 100.0)
    with pytest.warns(DeprecationWarning, match="'density' is renamed 'density_kg_m3'"):
        assert m.density == 100.0
    with pytest.warns(DeprecationWarning, match="'height' is renamed 'height_m'"):
        assert HatParams(height=0.25).height_m == 0.25
    with pytest.warns(DeprecationWarning, match="'brim_width' is renamed 'brim_width_m'"):
        assert HatParams().brim_width == HatParams().brim_width_m
    with pytest.warns(DeprecationWarning, match="'acceleration_max' is renamed 'acceleration_max_mps2'"):
        w = WindowEstimate(window_s=0.1, epsilon_m=1e-4, acceleration_max=3.0, initial_speed_mps=0.1, regime="x")
    assert w.acceleration_max_mps2 == 3.0
    with pytest.warns(DeprecationWarning, match="'initial_speed' is renamed 'initial_speed_mps'"):
        assert w.initial_speed == 0.1
    face = FaceModel.create(np.array([[0.0, 0, 0], [0.1, 0, 0]]), np.zeros((0, 3), np.int64), mass=1.0)
    with pytest.warns(DeprecationWarning, match="'diameter' is renamed 'diameter_m'"):
        assert face.diameter == face.diameter_m == pytest.approx(0.1)
    with pytest.warns(DeprecationWarning, match="'HAT_EDGE_LENGTH_FAC' is renamed 'TET_EDGE_LENGTH_FAC'"):
        assert defaults.HAT_EDGE_LENGTH_FAC == defaults.TET_EDGE_LENGTH_FAC
    assert ImplicitEuler.__init__.renamed_kwargs == {"h": "step_s", "tol": "tol_m"}
    assert {"omega_max": "omega_max_radps", "v_max": "v_max_mps"}.items() <= window_report.renamed_kwargs.items()


def test_load_rig_takes_unit_m_like_save_obj_folder(tmp_path):
    import pytest

    from kdfaces import KDInputError
    from kdfaces.io.rigfiles import load_default_rig, load_rig, save_obj_folder

    folder = save_obj_folder(load_default_rig(), tmp_path / "objs", unit_m=0.01)  # written in cm
    rig = load_rig(folder, unit_m=0.01)
    with pytest.warns(DeprecationWarning, match="'scale' is renamed 'unit_m'"):
        old = load_rig(folder, scale=0.01)
    assert abs(old.neutral - rig.neutral).max() == 0.0
    with pytest.raises(KDInputError, match=r"\.unit_m: expected a positive number"):
        load_rig(folder, unit_m=-1.0)
