"""Run the benchmarks in ``benchmarks/`` and write ``BENCHMARKS.md``.

Each module ``benchmarks/bench_*.py`` exposes ``BENCHMARKS``: a list of ``(name, function)``; each function takes
``repeats`` and returns a list of results ``{"name", "size", "median_s", "rate", "unit"}`` (``rate`` in ``unit``,
e.g. vertex-steps/s; ``size`` a short description such as "4.5k vertices").

    python scripts/bench.py [--only NAME ...] [--json] [--repeats N] [--out BENCHMARKS.md]
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


def discover():
    out = []
    for path in sorted((ROOT / "benchmarks").glob("bench_*.py")):
        spec = importlib.util.spec_from_file_location(path.stem, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        out.extend(mod.BENCHMARKS)
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


def merge_rows(path: Path, results: list[dict]) -> list[str]:
    """The table rows of ``path`` with every row of a benchmark name in ``results`` replaced by the new ones (in
    place of the first old row of that name; new names are appended)."""
    new_names = {r["name"] for r in results}
    rows = [line for line in path.read_text().splitlines() if line.startswith("| ") and not line.startswith("| bench")]
    out, placed = [], set()
    for line in rows:
        name = line.split("|")[1].strip()
        if name in new_names:
            if name not in placed:
                out += [_row(r) for r in results if r["name"] == name]
                placed.add(name)
            continue
        out.append(line)
    out += [_row(r) for r in results if r["name"] not in placed]
    return out


_TABLE = ["| benchmark | size | median [s] | rate | unit |", "|---|---|---:|---:|---|"]


def update_header(path: Path, results: list[dict]) -> list[str]:
    """The header of ``path`` (the lines above its table) with one line saying when and on what machine the
    benchmarks of ``results`` were re-measured (replacing an earlier such line for the same names): the machine
    line above stays the one the rest of the table was measured on."""
    names = ", ".join(sorted({r["name"] for r in results}))
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
    benches = [(n, f) for n, f in discover() if not args.only or any(n.startswith(p) for p in args.only)]
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
        write_markdown(args.out, results, rows=merge_rows(args.out, results),
                       header=update_header(args.out, results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
