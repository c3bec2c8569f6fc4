"""Modal window report stages (§5.3) for ~2k/5k/20k-tet hats: tetrahedralise, assemble, eigsh, verification sim
(linear, all DOFs, Newmark). Target: ≤ 10 s for the 5k-tet hat excluding tetrahedralisation."""

from __future__ import annotations

from pathlib import Path

from kdfem.modal.window import window_report

#: (edge_length_fac, envelope epsilon, coarsen, label): the hat benchmark's sizes (pytetwild's counts vary per run)
SIZES = ((0.06, 0.002, True, "~2k"), (0.09, 0.001, False, "~5k"), (0.02, 0.001, False, "~20k"))
#: tets are cached here (shared with the hat benchmark), so only the first run pays for pytetwild
CACHE = Path(__file__).resolve().parents[1] / "kd-out" / ".cache"
STAGES = ("tetrahedralise", "assemble", "eigsh", "verify linear")


def bench_modal(repeats: int = 1) -> list[dict]:
    import tempfile

    out = []
    for fac, eps, coarsen, label in SIZES:
        with tempfile.TemporaryDirectory() as tmp:
            run = window_report(None, out=tmp, edge_length_fac=fac, envelope_fac=eps, coarsen=coarsen, cache_dir=CACHE,
                                nonlinear=False, sweep=False, figures=False, progress=False)
        tets = run.result["tets"]
        size = f"{label}: {tets} tets"
        for stage in STAGES:
            s = run.timings[stage]
            name = stage if stage != "tetrahedralise" or s > 1.0 else "tetrahedralise (mesh cached by the hat bench)"
            out.append({"name": f"modal window: {name}", "size": size, "median_s": s, "rate": tets / s,
                        "unit": "tets/s"})
        rest = sum(run.timings[s] for s in STAGES[1:])
        out.append({"name": "modal window: total excl. tetrahedralise", "size": size, "median_s": rest,
                    "rate": tets / rest, "unit": "tets/s"})
    return out


BENCHMARKS = [("modal", bench_modal)]
