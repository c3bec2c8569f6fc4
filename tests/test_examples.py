"""The three tutorial scripts in examples/ run as written (they are also rendered in the API reference site; the
notebook examples/authoring_tutorial.ipynb runs in tests/test_notebook.py)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_kd_keyed_animation(tmp_path):
    s = load("kd_keyed_animation").main(["--out", str(tmp_path), "--duration", "1.6"])
    assert s["scrub_equals_batch"] and s["max_deviation_m"] > 1e-3
    assert s["max_error_vs_full_m"] <= s["epsilon_m"]  # the automatic window keeps KD within ε of the full sim
    assert (tmp_path / "kd_deviation.png").stat().st_size > 10_000


def test_ikd_pose_to_usd(tmp_path):
    pxr = pytest.importorskip("pxr")
    s = load("ikd_pose_to_usd").main(["--out", str(tmp_path), "--frames", "70"])
    assert s["converged"] and s["error_after_m"] <= 1e-5 and s["error_before_m"] > 1e-2
    assert s["independent_check_m"] == pytest.approx(s["error_after_m"], abs=1e-12)
    stage = pxr.Usd.Stage.Open(s["usd"])
    points = stage.GetPrimAtPath("/tilt").GetAttribute("points")
    assert len(points.GetTimeSamples()) == 70
    assert np.isfinite(np.asarray(points.Get(62))).all()  # the constrained frame, 2.48 s at 25 fps


def test_hat_kd_and_window(tmp_path):
    s = load("hat_kd_and_window").main(["--out", str(tmp_path)])
    assert s["regime"] == "underdamped" and 0.1 < s["window_s"] < 3.0
    assert s["max_swing_m"] > 0.01  # the nod swings the hat by centimetres
    assert s["max_kd_error_vs_full_m"] <= s["epsilon_m"]
