"""The `kdfaces demo` command end to end: summary.json keys and a filmstrip that shows a face."""

import json
from pathlib import Path

import pytest

from kdfaces.cli import main


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--out", str(out)]) == 0
    return out, json.loads((out / "summary.json").read_text())


def test_demo_summary(demo_run):
    out, s = demo_run
    assert s["rig"]["name"] == "makehuman_head" and s["rig"]["shapes"] == 52 and 4000 < s["rig"]["vertices"] < 5000
    assert s["fps"] == 25 and s["frames"] == 151 and abs(s["duration_s"] - 6.0) < 1e-9
    assert s["outputs"] and all((out / p).exists() for p in s["outputs"])


def test_demo_kd_and_ikd_summary(demo_run):
    _, s = demo_run
    kd = s["kd"]
    assert set(kd) >= {"window_s", "window_auto_s", "epsilon_m", "settle_time_s", "ms_per_state",
                       "max_deviation_from_kinematic_m", "sweep", "max_error_vs_full_at_auto_m"}
    assert kd["max_deviation_from_kinematic_m"] >= 2e-3  # visible secondary motion on the ≈0.3 m head
    assert kd["max_error_vs_full_at_auto_m"] <= kd["epsilon_m"]
    errs = [row["max_error_vs_full_m"] for row in sorted(kd["sweep"], key=lambda r: r["window_s"])]
    assert all(b <= a for a, b in zip(errs, errs[1:]))  # KD → full as δ grows
    ikd = s["ikd"]
    assert ikd["converged"] and ikd["iterations"] <= 10
    kinds = {c["kind"] for c in ikd["constraints"]}
    assert kinds == {"pose", "subset", "velocity", "end_effector"}
    for c in ikd["constraints"]:
        assert c["error_after_m"] <= (1e-3 if c["kind"] == "velocity" else 1e-5)
    assert ikd["independent_check_max_error_m"] == max(c["error_after_m"] for c in ikd["constraints"])
    assert {"ikd_convergence.png", "ikd_offset_grid.png", "kd_error.png"} <= set(s["outputs"])


def test_demo_filmstrip_shows_a_face(demo_run):
    import matplotlib.image as mpimg

    out, s = demo_run
    png = next(p for p in s["outputs"] if p.startswith("filmstrip"))
    img = mpimg.imread(out / png)[..., :3]
    skin = (img[..., 0] > img[..., 2] + 0.1) & (img[..., 0] > 0.4)  # warm skin-coloured pixels
    assert 0.05 < skin.mean() < 0.6


def test_bad_rig_path_is_one_clear_error(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--rig", str(tmp_path / "missing.npz")]) == 2
    err = capsys.readouterr().err
    assert "missing.npz: file not found" in err and "Traceback" not in err


def test_a_clean_run_prints_progress_and_no_library_noise(tmp_path):
    """``kdfaces run`` in a fresh process: a progress bar, no Warp banner or VTK display warning, one summary line,
    and files created 0644 under umask 022."""
    import os
    import stat
    import subprocess
    import sys

    shot = Path(__file__).resolve().parent / "reference" / "shot.toml"
    env = {**os.environ, "KDFACES_PROGRESS_DELAY_S": "0"}
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-c", "import os, sys; os.umask(0o022); from kdfaces.cli import main; "
                           f"sys.exit(main(['run', {str(shot)!r}, '--out', {str(out)!r}, '--export', 'pc2']))"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout + proc.stderr
    assert "KD states" in proc.stderr  # the progress bar
    for noise in ("Warp", "CUDA", "bad X server", "Module kdfaces"):
        assert noise not in text, (noise, text)
    assert proc.stdout.strip().count("\n") == 0 and "peak memory" in proc.stdout
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in out.iterdir()}
    assert modes and set(modes.values()) == {0o644}, modes
    assert stat.S_IMODE(out.stat().st_mode) == 0o755
