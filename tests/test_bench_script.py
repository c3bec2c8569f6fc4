"""``scripts/bench.py --update``: merging re-measured rows into BENCHMARKS.md without running a benchmark.

Rows are text, so every check is exact (no tolerance): which rows survive, in which order, with which content.
"""

from __future__ import annotations

import importlib.util
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_script", ROOT / "scripts" / "bench.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _result(name: str, size: str, value: float) -> dict:
    return {"name": name, "size": size, "median_s": value, "rate": value, "unit": "ms"}


def _table(tmp_path: Path, rows: list[tuple[str, str, float]]) -> Path:
    path = tmp_path / "BENCHMARKS.md"
    lines = ["# Benchmarks", "", "Machine: test.", "", "| benchmark | size | median [s] | rate | unit |",
             "|---|---|---:|---:|---|"]
    lines += [f"| {n} | {s} | {v:.4g} | {v:.4g} | ms |" for n, s, v in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def _cells(rows: list[str]) -> list[tuple[str, str, str]]:
    return [tuple(c.strip() for c in line.split("|")[1:4]) for line in rows]


DENSE = [("face_kd_state", "4.8k vertices, 1 core", 5.0), ("face_kd_state", "75.6k vertices, 2 cores", 41.0)]
PROXY = [("face_kd_state", "75k vertices, proxy, 1 core (4049 proxy vertices)", 8.0),
         ("face_kd_state", "75k vertices, proxy, 2 cores (4049 proxy vertices)", 7.0),
         ("face_kd_state", "19k vertices, proxy, batch 151 (6000 proxy vertices)", 7.5)]
KEYS = {"face_kd_state": ["75k vertices, proxy", "19k vertices, proxy"]}


def test_without_keys_every_row_of_a_name_is_replaced_in_place(bench, tmp_path):
    path = _table(tmp_path, [("a", "x", 1.0), ("b", "old 1", 2.0), ("c", "y", 3.0), ("b", "old 2", 4.0)])
    rows = bench.merge_rows(path, [_result("b", "new", 5.0), _result("d", "z", 6.0)])
    assert _cells(rows) == [("a", "x", "1"), ("b", "new", "5"), ("c", "y", "3"), ("d", "z", "6")]


def test_proxy_update_keeps_the_dense_rows(bench, tmp_path):
    path = _table(tmp_path, DENSE + PROXY[:2] + [("other", "q", 9.0)])
    new = [_result("face_kd_state", s, v + 1.0) for _, s, v in PROXY]
    rows = bench.merge_rows(path, new, KEYS)
    # the 75k proxy rows in place of the old ones; the 19k group (no old row) after the name's last row
    assert _cells(rows) == ([(n, s, f"{v:g}") for n, s, v in DENSE]
                            + [("face_kd_state", PROXY[0][1], "9"), ("face_kd_state", PROXY[1][1], "8"),
                               ("face_kd_state", PROXY[2][1], "8.5"), ("other", "q", "9")])


def test_dense_update_keeps_the_proxy_rows(bench, tmp_path):
    path = _table(tmp_path, DENSE + PROXY)
    new = [_result("face_kd_state", "4.8k vertices, 1 core", 6.0), _result("face_kd_state", "27k vertices, 1 core",
                                                                           25.0)]
    rows = bench.merge_rows(path, new, KEYS)
    # the dense group shrank to the two re-measured rows (the 75.6k row was not re-measured: gone, as before keys)
    assert _cells(rows) == ([("face_kd_state", "4.8k vertices, 1 core", "6"),
                             ("face_kd_state", "27k vertices, 1 core", "25")]
                            + [(n, s, f"{v:g}") for n, s, v in PROXY])


def test_the_longest_declared_prefix_wins(bench, tmp_path):
    keys = {"r": ["75k", "75k vertices, proxy"]}
    assert bench.row_key("r", "75k vertices, proxy, 1 core", keys) == "75k vertices, proxy"
    assert bench.row_key("r", "75k vertices, dense", keys) == "75k"
    assert bench.row_key("r", "19k vertices", keys) is None
    assert bench.row_key("s", "75k vertices, proxy", keys) is None
    path = _table(tmp_path, [("r", "75k vertices, dense", 1.0), ("r", "75k vertices, proxy, 1 core", 2.0)])
    rows = bench.merge_rows(path, [_result("r", "75k vertices, proxy, 2 cores", 3.0)], keys)
    assert _cells(rows) == [("r", "75k vertices, dense", "1"), ("r", "75k vertices, proxy, 2 cores", "3")]


def test_updating_the_proxy_rows_deletes_no_row_of_the_real_table(bench, tmp_path):
    real = (ROOT / "BENCHMARKS.md").read_text()
    path = tmp_path / "BENCHMARKS.md"
    path.write_text(real)
    old = [line for line in real.splitlines() if line.startswith("| ") and not line.startswith("| bench")]
    keys = bench.row_keys()
    assert keys["face_kd_state"] == KEYS["face_kd_state"]
    new = [_result("face_kd_state", s, v) for _, s, v in PROXY] + [
        _result("viewer_fps", "75k vertices, proxy (4049 proxy vertices), KD state alone", 0.01)]
    rows = bench.merge_rows(path, new, keys)
    cells = {line: tuple(c.strip() for c in line.split("|")[1:3]) for line in old}
    dense = [line for line in old if cells[line][0] in ("face_kd_state", "viewer_fps")
             and bench.row_key(*cells[line], keys) is None]
    assert len(dense) >= 10  # the dense face_kd_state and 27k viewer_fps rows are there to be kept
    survivors = [line for line in old if cells[line][0] not in ("face_kd_state", "viewer_fps") or line in dense]
    assert [r for r in rows if r in old] == survivors
    assert len(rows) == len(survivors) + len(new)


def test_header_names_keyed_rows_by_their_prefix(bench, tmp_path):
    path = _table(tmp_path, DENSE)
    bench.machine = lambda: "test machine"  # the fixture's module only: no warp import for one header line
    head = bench.update_header(path, [_result("face_kd_state", s, v) for _, s, v in PROXY], KEYS)
    assert head[-2].startswith("Re-measured with `--update` (face_kd_state (19k vertices, proxy), "
                               "face_kd_state (75k vertices, proxy)): ")
    assert head[-2].endswith(", test machine.")
    assert bench.update_header(path, [_result("a", "x", 1.0)])[-2].startswith("Re-measured with `--update` (a): ")


def test_bad_row_keys_name_the_module(bench):
    mod = types.SimpleNamespace(__name__="bench_bad", BENCHMARKS=[], ROW_KEYS={"r": "75k vertices"})
    with pytest.raises(ValueError, match=r"bench_bad\.ROW_KEYS\['r'\]"):
        bench.row_keys([mod])
