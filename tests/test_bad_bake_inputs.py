"""Bad bake arguments end in one line within seconds, before any work: Dask addresses that are empty, malformed, a
dashboard's web address, a closed port, or a port that speaks another protocol (within 5 s, no client left waiting
at exit); a chunk size beyond the take or beyond memory; more worker processes than memory holds."""

from __future__ import annotations

import http.server
import threading
import time
from pathlib import Path

import pytest

from kdfaces import KDInputError
from kdfaces.bake import plan_bake
from kdfaces.bake.cluster import WORKER_BASE_BYTES, check_scheduler_address
from kdfaces.cli import main

DEMO = Path(__file__).resolve().parents[1] / "kdfaces" / "shots" / "demo.toml"


@pytest.fixture(scope="module")
def web_port():
    """A loopback port served by a web server (not Dask)."""
    class Quiet(http.server.BaseHTTPRequestHandler):
        def log_message(self, *args):  # the test reads stderr
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield server.server_address[1]
    server.shutdown()


def _one_line(capsys, argv, expect, limit_s: float):
    capsys.readouterr()
    t0 = time.perf_counter()
    rc = main(argv)
    seconds = time.perf_counter() - t0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert rc == 2, err
    assert len(lines) == 1 and "Traceback" not in err, lines
    for text in (expect,) if isinstance(expect, str) else expect:
        assert text in lines[0], lines[0]
    assert seconds <= limit_s, seconds


@pytest.mark.parametrize("address, expect", [
    ("", "expected a Dask scheduler address such as tcp://host:8786"),
    ("   ", "expected a Dask scheduler address"),
    ("http://127.0.0.1:8787/status", "that is a web (dashboard) address"),
    ("garbage", "expected host:port with a port in 1..65535"),
    ("tcp://127.0.0.1", "expected host:port"),
    ("tcp://127.0.0.1:99999", "expected host:port"),
    ("ftp://127.0.0.1:21", "unknown scheme 'ftp'"),
    ("tcp://127.0.0.1:1", "cannot connect to a Dask scheduler there"),
])
def test_a_bad_scheduler_address_fails_within_5_s(tmp_path, capsys, address, expect):
    out = tmp_path / "out"
    # the address is checked (form, then Dask's handshake) before the shot is read
    _one_line(capsys, ["bake", str(DEMO), "--out", str(out), "--scheduler", address],
              (f"--scheduler {address!r}" if "connect" not in expect else "--scheduler", expect), 5.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_port_that_speaks_another_protocol_fails_within_5_s(tmp_path, capsys, web_port):
    from kdfaces import KDIOError
    from kdfaces.bake.cluster import _connect

    address = f"tcp://127.0.0.1:{web_port}"
    t0 = time.perf_counter()
    with pytest.raises(KDIOError, match="cannot connect to a Dask scheduler there"):
        _connect(address)
    assert time.perf_counter() - t0 <= 5.0
    out = tmp_path / "out"
    _one_line(capsys, ["bake", str(DEMO), "--out", str(out), "--scheduler", address], "no Dask scheduler answered",
              5.0)  # the address is tried before the shot is read


def test_addresses_of_the_right_form_pass_the_check():
    for a in ("tcp://127.0.0.1:8786", "127.0.0.1:8786", "tls://sched.example.org:8786", "inproc://1.2.3.4/5/6"):
        assert check_scheduler_address(a) == a


def test_the_bake_plan_is_checked_against_memory_before_anything_runs(tmp_path, capsys):
    giB = 1 << 30
    # a chunk longer than the take is the take
    assert plan_bake(151, 4800, 10 ** 9, 2, available_bytes=16 * giB) == (151, 1)
    # a chunk that does not fit memory names the flag and what fits
    with pytest.raises(KDInputError, match=r"--chunk-frames 100000: a task would hold .* give --chunk-frames \d"):
        plan_bake(10 ** 6, 27_000, 100_000, 1, available_bytes=8 * giB)
    # more workers than memory holds
    with pytest.raises(KDInputError, match=r"--workers 1000000: .* give --workers \d+ or fewer"):
        plan_bake(3810, 27_000, 32, 10 ** 6, available_bytes=8 * giB)
    k, n = plan_bake(3810, 27_000, 32, None, available_bytes=2 * WORKER_BASE_BYTES + (10 << 20))
    assert (k, n) == (32, 1)  # one per core, but only as many as fit
    # through the command: refused in one line before the solve or any worker starts
    out = tmp_path / "out"
    _one_line(capsys, ["bake", str(DEMO), "--out", str(out), "--workers", "1000000"], "--workers 1000000:", 30)
    assert sorted(p.name for p in tmp_path.iterdir()) == []
