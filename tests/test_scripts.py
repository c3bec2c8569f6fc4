"""Smoke runs of the user scripts in scripts/ (short shots), scanning their outputs for NaN."""

import importlib.util
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import LLF_TAKE

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def load(name):
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def read_pc2(path):
    data = Path(path).read_bytes()
    _, _, points, _, _, samples = struct.unpack("<12siiffi", data[:32])
    return np.frombuffer(data[32:], dtype="<f4").reshape(samples, points, 3)


def test_walkthrough(tmp_path):
    s = load("face_ikd_walkthrough").main(["--out", str(tmp_path), "--duration", "1.2", "--export", "pc2"])
    assert s["ikd_converged"] and s["ikd_error_after_m"] <= 1e-5
    assert s["max_secondary_motion_m"] > 1e-3
    cache = read_pc2(tmp_path / "walkthrough.pc2")
    assert cache.shape[0] == 32 and np.isfinite(cache).all()  # 31 frames after one leading copy (Blender frame 1)
    assert (tmp_path / "walkthrough.png").stat().st_size > 10_000


def test_livelink_to_kd(tmp_path):
    if not LLF_TAKE.exists():
        pytest.skip(f"real Live Link Face take not present at {LLF_TAKE}")
    s = load("livelink_to_kd").main(["--csv", str(LLF_TAKE), "--start", "75", "--end", "76.5", "--out",
                                     str(tmp_path), "--export", "pc2"])
    assert s["frames"] == 46 and s["fps"] == 30
    assert np.isfinite(read_pc2(tmp_path / "livelink.pc2")).all()
