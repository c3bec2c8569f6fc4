"""Modal window report stages (§5.3) for ~2k/5k/20k-tet hats: tetrahedralise, assemble, eigsh, verification sim
(linear, all DOFs, Newmark). Target: ≤ 10 s for the 5k-tet hat excluding tetrahedralisation."""

from __future__ import annotations

from kdfem.window_cli import window_report

SIZES = ((0.12, "~2k"), (0.09, "~5k"), (0.05, "~20k"))  # pytetwild edge_length_fac → tet count class (varies)
STAGES = ("tetrahedralise", "assemble", "eigsh", "verify linear")


def bench_modal(repeats: int = 1) -> list[dict]:
    import tempfile

    out = []
    for fac, label in SIZES:
        with tempfile.TemporaryDirectory() as tmp:
            run = window_report(None, out=tmp, edge_length_fac=fac, nonlinear=False, sweep=False, figures=False,
                                progress=False)
        tets = run.result["tets"]
        size = f"{label}: {tets} tets"
        for stage in STAGES:
            s = run.timings[stage]
            out.append({"name": f"modal window: {stage}", "size": size, "median_s": s, "rate": tets / s,
                        "unit": "tets/s"})
        rest = sum(run.timings[s] for s in STAGES[1:])
        out.append({"name": "modal window: total excl. tetrahedralise", "size": size, "median_s": rest,
                    "rate": tets / rest, "unit": "tets/s"})
    return out


BENCHMARKS = [("modal", bench_modal)]
