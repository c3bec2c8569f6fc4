"""The `kdfaces demo` command end to end: summary.json keys and a filmstrip that shows a face."""

import json
from pathlib import Path

import numpy as np
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
    assert {"ikd_convergence.png", "kd_error.png", "heatmap.png"} <= set(s["outputs"])
    assert "ikd_offset_grid.png" not in s["outputs"] and "offset_grid" not in ikd  # moved to kdfem demo
    assert {"movie.mp4", "movie.gif"} & set(s["outputs"])
    seams = {c["label"]: c["seam_ratio"] for c in ikd["constraints"]}
    assert all(0.0 <= v <= 1.0 for v in seams.values())
    assert seams["chin"] < 0.35  # 1.0 with the correction on the jaw only (a tear at its boundary)
    for c in ikd["constraints"]:  # the mesh's floor under each smooth lift's seam ratio; none for the pose lift
        assert (c["seam_ratio_bound"] is None) == (c["kind"] == "pose")
        assert c["seam_ratio_bound"] is None or 0.0 < c["seam_ratio_bound"] <= c["seam_ratio"]
        assert (c["gradient_ratio"] is None) == (c["kind"] == "pose")  # 1: a linear ramp over the falloff
        assert c["gradient_ratio"] is None or c["gradient_ratio"] > 0.0
    assert ikd["lift_factorizations"] == 3  # chin, lips, brows: once each (the pose lifts as before)


def test_demo_movie_shows_the_kd_motion(demo_run):
    """The movie has every shot frame, and its KD panel (coloured by |x_KD − x_K|) is hot on some frames and quiet
    on others, while the kinematic panel never is."""
    import imageio.v2 as imageio

    out, s = demo_run
    path = out / next(p for p in s["outputs"] if p.startswith("movie."))
    frames = [np.asarray(f)[..., :3] for f in imageio.get_reader(path)]
    assert len(frames) == s["frames"]
    width = (frames[0].shape[1] - 2 * 4) // 3  # three panels, 4 px gaps
    def hot(img):  # orange to dark red of the heat map: little blue for its red (skin keeps B ≈ 0.6 R)
        r, b = img[..., 0].astype(float), img[..., 2].astype(float)
        return int(((r > 100) & (b < 0.4 * r)).sum())
    body = slice(30, frames[0].shape[0] - 16)  # below the label, above the timeline bar
    kin = [hot(f[body, :width]) for f in frames]
    kd = [hot(f[body, width + 4: 2 * width + 4]) for f in frames]
    assert max(kin) < 20  # (a few pixels of compression noise at most)
    assert max(kd) > 200 and min(kd) < 20


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
