"""``kdfaces bake`` on the command line: the same point cache as ``kdfaces run``, byte for byte; Ctrl-C leaves no
output folder but keeps the store, and the next run resumes from it; a rerun of a finished bake computes nothing."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from kdfaces.bake import BakeStore, default_store_path
from kdfaces.cli import main
from kdfaces.io import read_pc2, read_usd

DEMO = Path(__file__).resolve().parents[1] / "kdfaces" / "shots" / "demo.toml"
PLAIN = DEMO.read_text().split("[[constraints]]")[0].replace('name = "demo"', 'name = "plain"')


def test_bake_and_run_write_the_same_pc2_bytes(tmp_path):
    bake, run = tmp_path / "bake", tmp_path / "run"
    assert main(["bake", str(DEMO), "--out", str(bake), "--workers", "2", "--export", "pc2", "--export", "usd"]) == 0
    assert main(["run", str(DEMO), "--out", str(run), "--export", "pc2"]) == 0
    assert (bake / "demo.pc2").read_bytes() == (run / "demo.pc2").read_bytes()
    summary = json.loads((bake / "summary.json").read_text())
    assert summary["bake"]["workers"] == 2 and summary["bake"]["computed_chunks"] == summary["bake"]["chunks"] == 5
    assert summary["ikd"]["converged"]
    assert sorted(summary["outputs"]) == ["bake.zarr", "demo.pc2", "demo.usdc"]
    # the store inside the output is the run's final trajectory in float32, and the USD cache holds the same
    x = BakeStore.open(bake / "bake.zarr").read()
    assert np.array_equal(x, read_pc2(run / "demo.pc2").positions.astype(np.float32))
    assert np.array_equal(read_usd(bake / "demo.usdc").positions, x.astype(np.float64))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bake", "run"]  # no working store left beside it


def _complete(store: Path) -> int:
    try:
        return int(BakeStore.open(store).complete().sum())
    except Exception:  # not created yet
        return 0


def test_ctrl_c_keeps_the_store_and_the_next_bake_resumes(tmp_path, capsys):
    shot = tmp_path / "plain.toml"
    shot.write_text(PLAIN)
    out = tmp_path / "out"
    store = default_store_path(out)
    args = ["bake", str(shot), "--out", str(out), "--workers", "2", "--chunk-frames", "4", "--export", "pc2"]
    proc = subprocess.Popen([sys.executable, "-m", "kdfaces.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env={**os.environ, "KDFACES_PROGRESS_DELAY_S": "1000"})
    t0 = time.perf_counter()
    while _complete(store) < 3:
        assert proc.poll() is None and time.perf_counter() - t0 < 120, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    err = err.decode()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted; nothing was written" in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [".out.bake.zarr", "plain.toml"]  # the store, kept
    kept = _complete(store)
    assert 3 <= kept < 38 and f"{kept} of 38 chunks are kept in {store}" in err
    capsys.readouterr()
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())["bake"]
    assert (summary["skipped_chunks"], summary["computed_chunks"]) == (kept, 38 - kept)
    assert not store.exists() and BakeStore.open(out / "bake.zarr").complete().all()
    first = (out / "plain.pc2").read_bytes()
    # a rerun of a finished bake starts from the published store: nothing to compute, the same cache
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())["bake"]
    assert (summary["skipped_chunks"], summary["computed_chunks"], summary["workers"]) == (38, 0, 0)
    assert (out / "plain.pc2").read_bytes() == first


def test_bad_bake_options_are_one_line_before_any_work(tmp_path, capsys):
    out = tmp_path / "out"
    for extra, message in ((["--chunk-frames", "0"], "chunk_frames: expected a whole number ≥ 1, got 0"),
                           (["--workers", "-1"], "workers: expected a whole number ≥ 1, got -1")):
        capsys.readouterr()
        assert main(["bake", str(DEMO), "--out", str(out), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no output folder, no store
