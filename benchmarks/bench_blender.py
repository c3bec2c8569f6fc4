"""KD on Blender's timeline: the median wall time of ``scene.frame_set`` on random frames of the demo's shape-key
animation (glTF, 25 fps, 151 frames) with KD enabled, measured in ``bpy`` 4.5 (a fresh Blender in a subprocess,
the built extension installed), on the 4.8k default head (target ≤ 15 ms) and the 27k production rig (target
≤ 50 ms, two cores). Each frame change is the whole update: the history-free KD state of that frame (automatic
window, 2 threads), the KD shape key rewritten, Blender's own shape-key evaluation. The size column also gives the
median KD state alone (the panel's ms)."""

from __future__ import annotations

import importlib.util
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_MS = {"default head": 15.0, "27k production rig": 50.0}


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def bench_blender_frame_update(repeats: int):
    from kdfaces import demo_animation, export_rig, load_default_rig

    sys.path.insert(0, str(ROOT / "tests"))
    checks = _load("blender_kd_checks", ROOT / "tests" / "blender_kd_checks.py")
    build = _load("build_blender_extension", ROOT / "scripts" / "build_blender_extension.py")
    production = _load("build_production_rig", ROOT / "scripts" / "build_production_rig.py")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        zip_path = build.build_extension(tmp / "dist")
        rigs = {"default head": load_default_rig(),
                "27k production rig": production.production_rig(target_vertices=27_000)}
        for label, rig in rigs.items():
            gltf = export_rig(rig, tmp / label.replace(" ", "_"), formats=("gltf",), animation=demo_animation())[0]
            res, _ = checks.run_blender(zip_path, gltf, tmp / f"run_{label.replace(' ', '_')}", frames=[37],
                                        window_s=0.4, bench_frames=max(10, 20 * repeats))
            ms = statistics.median(res["frame_set_ms"])
            kd_ms = statistics.median(res["kd_ms"])
            size = (f"{res['vertices'] / 1e3:.1f}k vertices ({label}), δ auto = {res['auto_status'][1]:.3f} s, "
                    f"2 threads; KD state alone {kd_ms:.1f} ms; target ≤ {TARGET_MS[label]:.0f} ms")
            rows.append({"name": "blender_frame_update", "size": size, "median_s": ms / 1e3, "rate": 1e3 / ms,
                         "unit": "frame changes/s"})
    return rows


BENCHMARKS = [("blender_frame_update", bench_blender_frame_update)]
