"""Renders: reference images, heat maps, constraint silhouettes, movies and the render verb.

Image tolerances: a fresh render matches its stored reference when the mean absolute difference is below 2/255 per
channel and fewer than 0.5 % of pixels differ by more than 40/255 (anti-aliasing and driver round-off move a few
edge pixels; a changed camera, colour or shape moves thousands).
"""

import argparse
import importlib.util
import json
import struct
from pathlib import Path

import numpy as np
import pytest

from kdfaces import KDInputError
from kdfaces.errors import KDIOError
from kdfaces.viz.figures import FaceRenderer
from kdfaces.viz.heatmap import HEAT_CMAP, MIN_CLIM_MM, deviation_mm, heat_clim

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "tests" / "reference"
SHOT = REFERENCE / "shot.toml"
MEAN_TOL, PIXEL_TOL, PIXEL_FRACTION = 2.0, 40, 0.005


def image_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(mean absolute difference per channel [0-255], fraction of pixels off by more than PIXEL_TOL)."""
    assert a.shape == b.shape, (a.shape, b.shape)
    d = np.abs(a.astype(np.int16) - b.astype(np.int16))
    return float(d.mean()), float((d.max(axis=-1) > PIXEL_TOL).mean())


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def skin_fraction(img: np.ndarray) -> float:
    img = img[..., :3].astype(np.float64) / (255.0 if img.dtype == np.uint8 else 1.0)
    return float(((img[..., 0] > img[..., 2] + 0.1) & (img[..., 0] > 0.4)).mean())


@pytest.fixture(scope="module")
def run():
    from kdfaces.shots.run import run_shot

    return run_shot(SHOT)


@pytest.fixture(scope="module")
def rendered(run, tmp_path_factory):
    from kdfaces.shots.render import render_shot

    out = tmp_path_factory.mktemp("render")
    return out, render_shot(run, out, frames=3, exports=["pc2"], progress=False)


def test_reference_images():
    from PIL import Image

    spec = importlib.util.spec_from_file_location("make_reference_images", ROOT / "scripts" /
                                                  "make_reference_images.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    fresh = mod.render_references()
    assert sorted(fresh) == sorted(p.stem for p in REFERENCE.glob("*.png"))
    for name, img in fresh.items():
        ref = np.asarray(Image.open(REFERENCE / f"{name}.png").convert("RGB"))
        mean, frac = image_difference(img, ref)
        assert mean < MEAN_TOL and frac < PIXEL_FRACTION, f"{name}: mean diff {mean:.2f}, {100 * frac:.2f} % pixels"
    # the comparison is not blind: a render a few degrees off, or another pose, fails it
    neutral = np.asarray(Image.open(REFERENCE / "neutral.png").convert("RGB"))
    mean, frac = image_difference(fresh["pose_markers"], neutral)
    assert frac > 10 * PIXEL_FRACTION


def test_deviation_is_in_millimetres():
    x = np.zeros((2, 5, 3))
    y = x.copy()
    y[1, 2] = [0.003, 0.004, 0.0]  # 5 mm
    np.testing.assert_allclose(deviation_mm(y, x), [[0] * 5, [0, 0, 5.0, 0, 0]], atol=1e-12)
    assert heat_clim(np.zeros(10)) == (0.0, MIN_CLIM_MM)
    with pytest.raises(KDInputError, match="must be equal"):
        deviation_mm(x[:, :4], x)


class Translation:
    """x_K(t) = x0 + v·t: a rigid motion at constant velocity (a minimal trajectory for FaceSystem)."""

    def __init__(self, x0, v, end=0.6):
        self.x0, self.v, self.start, self.end = np.asarray(x0), np.asarray(v), 0.0, end
        self.num_vertices = len(x0)

    def evaluate(self, times, order=0):
        t = np.asarray(times, dtype=np.float64)[:, None, None]
        x = self.x0[None] + t * self.v
        out = [x, np.broadcast_to(self.v, x.shape).copy(), np.zeros_like(x)]
        return tuple(out[: order + 1]) if order else x

    def positions(self, times):
        return self.evaluate(times)


def test_heatmap_of_rigid_motion_is_uniformly_zero_coloured(default_rig):
    """KD of a constant-velocity translation (relative damping) stays on the kinematic pose, so its heat map is
    the zero colour everywhere; a deformation (jaw open) at the same colour range is not."""
    from kdfaces.dynamics import FaceModel, FaceSystem
    from kdfaces.kd import simulate_kd

    rig = default_rig
    traj = Translation(rig.neutral, np.array([0.3, 0.1, -0.2]))
    system = FaceSystem(FaceModel.from_rig(rig, settle_time_s=0.3, damping_ratio=0.3))
    t = np.array([0.4])
    kd = simulate_kd(system, traj, t, 0.4, step_s=0.04)[0]
    xk = traj.positions(t)[0]
    dev = deviation_mm(kd, xk)
    assert dev.max() < 1e-3  # float32 round-off: 1 µm
    clim = heat_clim(dev)
    jaw = rig.blend(rig.weight_vector({"jawOpen": 1.0}))
    with FaceRenderer(rig.faces, xk, size=(200, 240)) as r:
        heat = r.render(kd, dev, clim=clim, cmap=HEAT_CMAP)
        zero = r.render(kd, np.zeros(rig.num_vertices), clim=clim, cmap=HEAT_CMAP)
        mask = r.mask(kd)
        deformed = r.render(jaw, deviation_mm(jaw, rig.neutral), clim=clim, cmap=HEAT_CMAP)
    assert mask.mean() > 0.1
    diff = np.abs(heat.astype(np.int16) - zero.astype(np.int16)).max(axis=-1)
    assert diff[mask].max() <= 2
    # the zero colour is the map's lowest (light yellow, lit): no pixel of the face is reddish
    assert (heat[mask][:, 2].astype(int) > 0.5 * heat[mask][:, 0]).all()
    assert (np.abs(deformed.astype(np.int16) - zero.astype(np.int16)).max(axis=-1) > 40).mean() > 0.01


def test_ikd_frame_overlaps_its_target_silhouette(run):
    c = run.ikd_result.constraints[0]
    assert c.kind == "pose" and run.ikd_result.converged
    k = int(np.argmin(np.abs(run.times - c.time_s)))
    assert abs(run.times[k] - c.time_s) < 1e-9
    with FaceRenderer(run.shot.rig.faces, run.kinematic[0], size=(200, 240)) as r:
        target, ikd, kd = r.mask(c.target), r.mask(run.ikd[k]), r.mask(run.kd[k])
    assert 0.1 < target.mean() < 0.6
    assert iou(ikd, target) > 0.995
    assert iou(kd, target) < 0.95  # the 10° roll is visible: the test can tell the two apart


def test_render_shot_outputs(rendered, run):
    import imageio.v2 as iio
    from PIL import Image

    out, s = rendered
    assert s["outputs"] == ["filmstrip.png", "heatmap.png", "heatmap_ikd.png", "constraints.png", "movie.mp4",
                            "render-test.pc2"]
    assert 0.8 in [round(t, 9) for t in s["still_times_s"]]
    for name in ("filmstrip.png", "constraints.png"):
        assert 0.05 < skin_fraction(np.asarray(Image.open(out / name).convert("RGB"))) < 0.6, name
    heat = np.asarray(Image.open(out / "heatmap.png").convert("RGB")).astype(int)
    red = (heat[..., 0] > 150) & (heat[..., 1] < 60) & (heat[..., 2] < 60)
    assert red[:, -120:].any()  # the colour bar's dark red end
    reader = iio.get_reader(out / "movie.mp4")
    frames = [f for f in reader]
    reader.close()
    assert len(frames) == len(run.times) and frames[0].shape[1] > 2 * frames[0].shape[0]
    assert s["render_s_per_movie_frame_median"] > 0
    # the PC2 cache holds the final (IKD) trajectory
    data = (out / "render-test.pc2").read_bytes()
    _, _, n, start, _, f = struct.unpack("<12siiffi", data[:32])
    pts = np.frombuffer(data[32:], dtype="<f4").reshape(f, n, 3)
    np.testing.assert_allclose(pts, run.ikd, atol=1e-6)  # one sample per frame, the first at scene frame 1
    assert start == 1.0


def test_movie_mp4_roundtrip_and_gif_fallback(tmp_path, monkeypatch):
    import imageio.v2 as iio
    from PIL import Image

    from kdfaces.viz import movie

    rng = np.random.default_rng(0)
    base = np.kron(rng.integers(0, 255, (6, 8, 3)), np.ones((16, 16, 1))).astype(np.uint8)  # 96×128 blocks
    frames = [np.roll(base, 8 * k, axis=1) for k in range(5)]
    p = movie.write_movie(tmp_path / "m.mp4", frames, fps=10)
    assert p.suffix == ".mp4"
    reader = iio.get_reader(p)
    back = [f for f in reader]
    reader.close()
    assert len(back) == 5
    for a, b in zip(frames, back):  # H.264 is lossy: mean error of a few levels on flat blocks
        assert np.abs(a.astype(int) - b.astype(int)).mean() < 8

    def broken(*_a, **_k):
        raise movie.MovieWriterUnavailable("no ffmpeg here")

    monkeypatch.setattr(movie, "_write_mp4", broken)
    g = movie.write_movie(tmp_path / "fallback.mp4", frames, fps=10)
    assert g == tmp_path / "fallback.gif" and not (tmp_path / "fallback.mp4").exists()
    with Image.open(g) as im:
        assert im.n_frames == 5
    assert sorted(q.name for q in tmp_path.iterdir()) == ["fallback.gif", "m.mp4"]  # no temporary files left


def test_bad_inputs_give_one_clear_error(tmp_path, default_rig):
    from kdfaces.viz.movie import write_movie

    rig = default_rig
    with pytest.raises(KDInputError, match=r"points: expected vertex positions of shape \(\.\.\., 4774, 3\)"):
        with FaceRenderer(rig.faces, rig.neutral, size=(64, 64)) as r:
            r.render(rig.neutral[:100])
    with pytest.raises(KDInputError, match="frames differ in size"):
        write_movie(tmp_path / "x.mp4", [np.zeros((8, 8, 3), np.uint8), np.zeros((8, 10, 3), np.uint8)], fps=5)
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(KDIOError, match="cannot write here"):
        write_movie(blocker / "m.gif", [np.zeros((8, 8, 3), np.uint8)], fps=5)
    assert list(tmp_path.iterdir()) == [blocker]


def test_render_verb(tmp_path):
    from kdfaces.shots.render import add_render_parser

    ap = argparse.ArgumentParser()
    add_render_parser(ap.add_subparsers())
    out = tmp_path / "out"
    args = ap.parse_args(["render", str(SHOT), "--out", str(out), "--frames", "2", "--no-movie"])
    s = args.func(args)
    assert json.loads((out / "summary.json").read_text())["outputs"] == s["outputs"]
    assert "movie.mp4" not in s["outputs"] and all((out / p).exists() for p in s["outputs"])
    args = ap.parse_args(["render", str(tmp_path / "none.toml"), "--out", str(out)])
    with pytest.raises(KDInputError, match="none.toml: file not found"):
        args.func(args)
