"""Ctrl-C at random moments of ``kdfaces run --export usd``: an interrupted run never exits 0, never crashes the
interpreter, and never leaves a partial set of outputs (the folder appears whole, with every file its summary lists,
or not at all)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

SHOT = Path(__file__).resolve().parent / "reference" / "shot.toml"
RUNS = 20


def _interrupted_run(tmp: Path, delay_s: float) -> tuple[int, Path, float]:
    tmp.mkdir(parents=True)
    out = tmp / "out"
    proc = subprocess.Popen([sys.executable, "-X", "faulthandler", "-m", "kdfaces.cli", "run", str(SHOT), "--out",
                             str(out), "--export", "usd"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, "KDFACES_PROGRESS_DELAY_S": "1000"})
    try:  # a run that completes before the interrupt's moment is not waited for to the end of it
        proc.wait(timeout=delay_s)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    return proc.returncode, out, delay_s, err.decode(errors="replace")  # a crash's Python stacks


def test_ctrl_c_at_random_times_never_leaves_a_partial_run(tmp_path):
    delays = np.random.default_rng(2026).uniform(0.05, 9.0, size=RUNS)
    with ThreadPoolExecutor(2) as pool:
        results = list(pool.map(lambda k: _interrupted_run(tmp_path / f"run{k}", delays[k]), range(RUNS)))
    finished = 0
    for rc, out, delay, err in results:
        if rc in (-signal.SIGSEGV, -signal.SIGABRT, -signal.SIGBUS):  # a crash: its whole report, untruncated
            pytest.fail(f"signal {-rc} after an interrupt at {delay:.3f} s; stderr:\n{err}", pytrace=False)
        leftovers = [p.name for p in out.parent.iterdir() if p.name.startswith(".out.")]
        assert not leftovers, (delay, leftovers)
        if out.exists():  # the run completed before the interrupt: the whole set is there
            summary = json.loads((out / "summary.json").read_text())
            assert all((out / name).exists() for name in summary["outputs"]), (delay, summary["outputs"])
            assert any(name.endswith(".usdc") for name in summary["outputs"])
            finished += 1
        else:  # interrupted: no output and a non-zero status (130 from our handler; during interpreter start-up,
            # before any handler exists, Python's own KeyboardInterrupt exit)
            assert rc != 0, (delay, err)
            if delay > 2.0:  # well after start-up the handler is installed: our one line, no traceback, and status
                # 130 exactly (the entry point leaves without the interpreter's finalization, see kdfaces.cli.finish)
                assert rc == 130, (rc, delay, err)
                assert err.strip().splitlines()[-1:] == ["kdfaces: interrupted; nothing was written"], (delay, err)
    assert finished < RUNS  # the delays do reach into the runs


def test_the_command_modules_load_no_heavy_library_before_taking_over_ctrl_c():
    """``import kdfaces.cli`` / ``kdfem.cli`` (what the console scripts run before ``main`` installs its SIGINT
    handler) loads neither numpy nor Warp: an interrupt in that window can only land in pure-Python imports."""
    code = ("import sys, kdfaces.cli, kdfem.cli; heavy = sorted({'numpy', 'warp', 'scipy', 'pyvista', 'pxr'} & "
            "set(sys.modules)); print(heavy); sys.exit(1 if heavy else 0)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_an_interrupt_during_an_import_is_raised_after_it(tmp_path, monkeypatch):
    """The command's SIGINT handler never raises inside an import (in the Python half of a native module's
    initialisation a KeyboardInterrupt can crash the interpreter: VTK's modules import their dependencies through a
    Python loader while their C initialiser runs). It records the interrupt and sends it again; the
    KeyboardInterrupt comes after the module has been imported whole."""
    import importlib

    from kdfaces import cli

    name = "module_interrupted_while_imported"
    (tmp_path / f"{name}.py").write_text(
        "import os, signal, time\nos.kill(os.getpid(), signal.SIGINT)\n"
        "for _ in range(25):\n    time.sleep(0.002)  # the signal arrives in here\nWHOLE = True\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    previous = signal.signal(signal.SIGINT, cli._on_signal)
    cli._HANDLING.set()
    events = []
    try:
        try:
            importlib.import_module(name)
            events.append("imported")
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline:
                time.sleep(0.005)
            events.append("no interrupt")
        except KeyboardInterrupt:
            events.append("interrupt")
    finally:
        cli._HANDLING.clear()
        signal.signal(signal.SIGINT, previous)
        cli._INTERRUPTED.clear()
    assert events == ["imported", "interrupt"]
    assert sys.modules.pop(name).WHOLE
