"""Off-screen render time per frame of the default face (plain shading and deviation heat map)."""

from __future__ import annotations

import statistics
import time

import numpy as np

from kdfaces import load_default_rig
from kdfaces.viz.figures import FaceRenderer


def bench_render(repeats: int):
    rig = load_default_rig()
    r = FaceRenderer(rig.faces, rig.neutral)
    smile = rig.blend(rig.weight_vector({"mouthSmileLeft": 1, "mouthSmileRight": 1}))
    dev = np.linalg.norm(smile - rig.neutral, axis=1) * 1e3
    out = []
    try:
        for name, kwargs in (("render_face", {}), ("render_heatmap", {"scalars": dev, "clim": (0, dev.max())})):
            r.render(smile, **kwargs)  # warm-up (first render builds the pipeline)
            times = []
            for i in range(max(3, repeats * 4)):
                pts = smile if i % 2 else rig.neutral
                t0 = time.perf_counter()
                r.render(pts, **kwargs)
                times.append(time.perf_counter() - t0)
            med = statistics.median(times)
            out.append({"name": name, "size": f"{rig.num_vertices} vertices, 360x420", "median_s": med,
                        "rate": 1.0 / med, "unit": "frames/s"})
    finally:
        r.close()
    return out


BENCHMARKS = [("render", bench_render)]
