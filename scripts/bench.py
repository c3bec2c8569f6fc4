"""Run the benchmarks in ``benchmarks/`` and write ``BENCHMARKS.md``.

Each module ``benchmarks/bench_*.py`` exposes ``BENCHMARKS``: a list of ``(name, function)``; each function takes
``repeats`` and returns a list of results ``{"name", "size", "median_s", "rate", "unit"}`` (``rate`` in ``unit``,
e.g. vertex-steps/s; ``size`` a short description such as "4.5k vertices").

``--update`` replaces, in ``--out``, the rows the run re-measured and keeps the others. A row is matched by its
benchmark name and, where a module declares ``ROW_KEYS`` (row name → size prefixes, e.g. ``{"face_kd_state":
["75k vertices, proxy"]}``), by the declared prefix its size starts with: a result whose size starts with a declared
prefix replaces the old rows of its name with that prefix (the longest one, where several match); a result with no
declared prefix replaces the old rows of its name that start with none of them. With no ``ROW_KEYS`` for a name,
every row of that name is replaced, so two modules can write rows of one name (the dense and the proxy
``face_kd_state``) and each module's ``--update`` leaves the other's rows alone.

    python scripts/bench.py [--only NAME ...] [--json] [--repeats N] [--out BENCHMARKS.md] [--update]
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import platform
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _modules() -> list:
    out = []
    for path in sorted((ROOT / "benchmarks").glob("bench_*.py")):
        spec = importlib.util.spec_from_file_location(path.stem, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        out.append(mod)
    return out


def discover(modules=None) -> list:
    """Every module's ``BENCHMARKS``: a list of ``(name, function)`` (``modules``: those of :func:`_modules`)."""
    return [b for mod in (_modules() if modules is None else modules) for b in mod.BENCHMARKS]


def row_keys(modules=None) -> dict[str, list[str]]:
    """Every module's ``ROW_KEYS`` merged: row name → the size prefixes that identify a configuration's rows (see
    :func:`merge_rows`)."""
    out: dict[str, list[str]] = {}
    for mod in _modules() if modules is None else modules:
        for name, prefixes in getattr(mod, "ROW_KEYS", {}).items():
            if isinstance(prefixes, str) or not all(isinstance(p, str) and p for p in prefixes):
                raise ValueError(f"{mod.__name__}.ROW_KEYS[{name!r}]: expected a list of non-empty size prefixes, "
                                 f"got {prefixes!r}")
            out.setdefault(name, []).extend(prefixes)
    return out


def machine() -> str:
    import numpy
    import warp

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {numpy.__version__}, "
            f"warp {warp.config.version}")


def _row(r: dict) -> str:
    rate = "" if r.get("rate") is None else f"{r['rate']:.4g}"
    return f"| {r['name']} | {r['size']} | {r['median_s']:.4g} | {rate} | {r.get('unit', '')} |"


def row_key(name: str, size: str, keys: dict[str, list[str]] | None) -> str | None:
    """The declared size prefix of the row ``(name, size)``: the longest of ``keys[name]`` that ``size`` starts
    with, or None (the row belongs to the name's rows without a declared prefix)."""
    hits = [k for k in (keys or {}).get(name, ()) if size.startswith(k)]
    return max(hits, key=len) if hits else None


def merge_rows(path: Path, results: list[dict], keys: dict[str, list[str]] | None = None) -> list[str]:
    """The table rows of ``path`` with the rows ``results`` re-measured replaced by the new ones.

    Rows are grouped by ``(name, row_key(name, size, keys))``: every old row of a group some result belongs to is
    dropped, and the group's new rows take the place of its first old row. A group with no old row goes after the
    last old row of its name, or at the end of the table when the name is new. ``keys``: row name → size prefixes
    (the modules' ``ROW_KEYS``, :func:`row_keys`); None or no entry for a name: one group, every row of that name.
    """
    groups: dict[tuple, list[dict]] = {}
    for r in results:
        groups.setdefault((r["name"], row_key(r["name"], r["size"], keys)), []).append(r)
    rows = [line for line in path.read_text().splitlines() if line.startswith("| ") and not line.startswith("| bench")]
    out, placed, last_of_name = [], set(), {}
    for line in rows:
        cells = line.split("|")
        name, size = cells[1].strip(), cells[2].strip() if len(cells) > 2 else ""
        group = (name, row_key(name, size, keys))
        if group in groups:
            if group not in placed:
                out += [_row(r) for r in groups[group]]
                placed.add(group)
        else:
            out.append(line)
        last_of_name[name] = len(out)
    for group, rs in groups.items():
        if group in placed:
            continue
        at = last_of_name.get(group[0], len(out))
        out[at:at] = [_row(r) for r in rs]
        for name, k in last_of_name.items():
            if k >= at:
                last_of_name[name] = k + len(rs)
    return out


def _labels(results: list[dict], keys: dict[str, list[str]] | None) -> str:
    """The re-measured rows' names for the header line: a name, or ``name (prefix)`` for a declared prefix."""
    out = set()
    for r in results:
        k = row_key(r["name"], r["size"], keys)
        out.add(r["name"] if k is None else f"{r['name']} ({k})")
    return ", ".join(sorted(out))


_TABLE = ["| benchmark | size | median [s] | rate | unit |", "|---|---|---:|---:|---|"]


def update_header(path: Path, results: list[dict], keys: dict[str, list[str]] | None = None) -> list[str]:
    """The header of ``path`` (the lines above its table) with one line saying when and on what machine the
    benchmarks of ``results`` were re-measured (replacing an earlier such line for the same names; a row with a
    declared prefix in ``keys`` is named ``name (prefix)``): the machine line above stays the one the rest of the
    table was measured on."""
    names = _labels(results, keys)
    tag = f"Re-measured with `--update` ({names}):"
    head = []
    for line in path.read_text().splitlines():
        if line.startswith("| benchmark"):
            break
        if not line.startswith(tag):
            head.append(line)
    while head and not head[-1].strip():
        head.pop()
    return head + [f"{tag} {datetime.date.today().isoformat()}, {machine()}.", ""]


def write_markdown(path: Path, results: list[dict], *, rows: list[str] | None = None,
                   header: list[str] | None = None) -> None:
    lines = header if header is not None else [
        "# Benchmarks",
        "",
        f"Written by `python scripts/bench.py` on {datetime.date.today().isoformat()}.",
        f"Machine: {machine()}.",
        "Medians over repeats; compare ratios within one run (the machine is shared and noisy).",
        "",
    ]
    lines = lines + _TABLE
    lines += rows if rows is not None else [_row(r) for r in results]
    tmp = path.with_suffix(".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", action="append", default=[],
                    help="run only the benchmarks with this name (prefix match; repeatable)")
    ap.add_argument("--json", action="store_true", help="print the results as a JSON list")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=ROOT / "BENCHMARKS.md")
    ap.add_argument("--update", action="store_true",
                    help="with --only: replace those benchmarks' rows in --out and keep the others")
    args = ap.parse_args(argv)
    modules = _modules()
    benches = [(n, f) for n, f in discover(modules) if not args.only or any(n.startswith(p) for p in args.only)]
    if not benches:
        print(f"bench: no benchmark named {args.only!r}", file=sys.stderr)
        return 2
    results = []
    for _name, fn in benches:
        for r in fn(args.repeats):
            results.append(r)
            if not args.json:
                print(f"{r['name']:40s} {r['size']:>18s} median {r['median_s'] * 1e3:10.3f} ms  "
                      f"{(r.get('rate') or 0):12.4g} {r.get('unit', '')}", flush=True)
    if args.json:
        print(json.dumps(results, indent=2))
    if not args.only:
        write_markdown(args.out, results)
    elif args.update and args.out.exists():
        keys = row_keys(modules)
        write_markdown(args.out, results, rows=merge_rows(args.out, results, keys),
                       header=update_header(args.out, results, keys))
    return 0


if __name__ == "__main__":
    sys.exit(main())
