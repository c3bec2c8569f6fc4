"""Production-size rigs: loading an OBJ folder (the 19k-vertex centimetre rig of ``scripts/build_production_rig.py``
× 53 shapes), and the peak resident memory of baking a 10 s, 30 Hz stretch of the real Live Link Face capture on the
19k and 27k rigs with ``kdfaces run`` (a fresh process each, so the peak is the bake's own), and the viewer's frame
rate on that capture: the 27k rig (dense) and the default head Loop-subdivided twice (75k vertices, on its proxy)."""

from __future__ import annotations

import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TAKE = Path(os.environ.get("KDFACES_SHARED_DATA", ROOT.parent / "shared" / "data")) / "livelinkface" / "alex_rom_3.csv"
BAKE_SHOT = """name = "bake"
[rig]
source = "{rig}"
units = "cm"
[animation]
source = "{take}"
start_s = 70.0
end_s = 80.0
fps = 30
[dynamics]
settle_time_s = {{ stiff_s = 0.2, loose_s = 0.45 }}
damping_ratio = 0.3
"""
_MEASURE = """
import json, sys, time
from kdfaces.cli import main
from kdfaces.resources import peak_rss_bytes
t0 = time.perf_counter()
rc = main(["run", sys.argv[1], "--out", sys.argv[2]])
wall = time.perf_counter() - t0
print(json.dumps({"rc": rc, "wall_s": wall, "peak_bytes": peak_rss_bytes(),
                  "summary": json.load(open(sys.argv[2] + "/summary.json")) if rc == 0 else None}))
"""


def _builder():
    spec = importlib.util.spec_from_file_location("build_production_rig", ROOT / "scripts" / "build_production_rig.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.build_production_rig


def bench_obj_folder_load(repeats: int):
    from kdfaces.io.rigfiles import load_rig

    with tempfile.TemporaryDirectory() as tmp:
        info = _builder()(Path(tmp) / "rig")
        walls = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            rig = load_rig(Path(tmp) / "rig", units="cm")  # no cache: every repeat parses all 54 OBJ files
            walls.append(time.perf_counter() - t0)
    size = f"{rig.num_vertices / 1e3:.1f}k vertices × {len(rig.shape_names)} shapes, cm OBJ folder"
    assert info["vertices"] == rig.num_vertices
    return [{"name": "production_obj_folder_load", "size": size, "median_s": statistics.median(walls),
             "rate": (len(rig.shape_names) + 1) / statistics.median(walls), "unit": "OBJ files/s"}]


def bench_bake_peak_memory(repeats: int):
    if not TAKE.exists():
        return [{"name": f"production_bake_peak_rss skipped (capture not present at {TAKE})", "size": "-",
                 "median_s": float("nan"), "rate": None, "unit": "-"}]
    out = []
    for target in (None, 27_000):
        with tempfile.TemporaryDirectory() as tmp:
            info = _builder()(Path(tmp) / "rig", target_vertices=target)
            shot = Path(tmp) / "bake.toml"
            shot.write_text(BAKE_SHOT.format(rig=Path(tmp) / "rig", take=TAKE))
            runs = []
            for k in range(max(1, min(repeats, 2))):  # each bake takes a while; the peak hardly varies
                proc = subprocess.run([sys.executable, "-c", _MEASURE, str(shot), str(Path(tmp) / f"out{k}")],
                                      capture_output=True, text=True,
                                      env={**os.environ, "KDFACES_CACHE": str(Path(tmp) / "cache"),
                                           "KDFACES_PROGRESS_DELAY_S": "1000"})
                if proc.returncode != 0:
                    raise RuntimeError(proc.stderr[-1000:])
                runs.append(json.loads(proc.stdout.strip().splitlines()[-1]))
            s = runs[0]["summary"]
            size = (f"{info['vertices'] / 1e3:.1f}k vertices, {s['frames']} frames (10 s at 30 Hz), "
                    f"δ = {s['kd']['window_s']:.3f} s")
            out.append({"name": "production_bake_peak_rss", "size": size,
                        "median_s": statistics.median(r["wall_s"] for r in runs),
                        "rate": max(r["peak_bytes"] for r in runs) / 2**30, "unit": "GiB peak RSS (whole run)"})
    return out


def _viewer_rows(rig, tmp: Path, repeats: int, label) -> list[dict]:
    """``viewer_fps`` rows of :class:`~kdfaces.viz.viewer.ShotViewer` on ``rig`` (a rig path, or a loaded rig) over
    the capture's 10 s stretch (``BAKE_SHOT``), two threads, off-screen 960×720: the KD state alone (``last_ms``)
    and the whole update (KD + redraw) of each of 60 consecutive frames; ``label(viewer)`` begins the rows' size."""
    from kdfaces.shots.shotfile import load_shot
    from kdfaces.viz.viewer import ShotViewer

    path = tmp / "view.toml"
    path.write_text(BAKE_SHOT.format(rig=rig if isinstance(rig, Path) else "unused", take=TAKE))
    shot = load_shot(path, cache_dir=tmp / "cache", rig=None if isinstance(rig, Path) else rig)
    viewer = ShotViewer(shot, off_screen=True, threads=2)
    try:
        head = label(viewer)
        kd_ms, update_s = [], []
        for _ in range(max(1, repeats)):
            viewer.set_frame(0)
            for _ in range(60):
                t0 = time.perf_counter()
                viewer.step_frame(1)
                update_s.append(time.perf_counter() - t0)
                kd_ms.append(viewer.last_ms)
    finally:
        viewer.close()
    size = f"{head}, 2 threads, δ = {viewer.window_s:.3f} s, 960×720 off-screen"
    kd_s = statistics.median(kd_ms) / 1e3
    upd = statistics.median(update_s)
    return [{"name": "viewer_fps", "size": size + ", KD state alone", "median_s": kd_s, "rate": 1.0 / kd_s,
             "unit": "KD states/s"},
            {"name": "viewer_fps", "size": size + ", whole update (KD + redraw)", "median_s": upd, "rate": 1.0 / upd,
             "unit": "frames/s"}]


def _skipped(name: str) -> list[dict]:
    return [{"name": f"{name} skipped (capture not present at {TAKE})", "size": "-", "median_s": float("nan"),
             "rate": None, "unit": "-"}]


def bench_viewer_fps(repeats: int):
    """``kdfaces view`` on the 27k rig (two threads, off-screen, the shot's automatic window): frames per second of
    the KD states alone (``last_ms``) and of whole viewer updates (KD state + redraw, software OpenGL here), while
    stepping through 60 consecutive frames of the capture."""
    if not TAKE.exists():
        return _skipped("viewer_fps")
    with tempfile.TemporaryDirectory() as tmp:
        info = _builder()(Path(tmp) / "rig", target_vertices=27_000)
        return _viewer_rows(Path(tmp) / "rig", Path(tmp), repeats, lambda v: f"{info['vertices'] / 1e3:.1f}k vertices")


def bench_viewer_fps_75k(repeats: int):
    """The viewer as :func:`bench_viewer_fps` (the same capture stretch, dynamics, threads and window size) on the
    default head Loop-subdivided twice (75,571 vertices), whose face model is a proxy (``FaceModel.from_rig(rig,
    proxy="auto")``, the shot's default, as ``bench_proxy.py``): the dense mesh is drawn, the proxy simulated."""
    if not TAKE.exists():
        return _skipped("viewer_fps")
    from kdfaces import load_default_rig
    from kdfaces.rig import subdivide_rig

    def label(viewer) -> str:
        model = viewer.system.model
        if not model.proxy:
            raise RuntimeError(f"viewer_fps_75k: expected a proxy face model on {model.num_vertices} vertices")
        return f"75k vertices, proxy ({model.num_simulated} proxy vertices)"

    rig = subdivide_rig(load_default_rig(), 2)
    with tempfile.TemporaryDirectory() as tmp:
        return _viewer_rows(rig, Path(tmp), repeats, label)


#: ``viewer_fps`` rows of the 75k proxy face are their own configuration (``scripts/bench.py --update``): updating
#: one of the two viewer benchmarks leaves the other's rows in place.
ROW_KEYS = {"viewer_fps": ["75k vertices, proxy"]}

BENCHMARKS = [("production_obj_folder_load", bench_obj_folder_load),
              ("production_bake_peak_rss", bench_bake_peak_memory),
              ("viewer_fps", bench_viewer_fps),
              ("viewer_fps_75k", bench_viewer_fps_75k)]
