"""Renders measured on the face region (issue 25): a full-body avatar is framed by its moving region, its heat maps'
colour range is measured there, and a pose constraint's markers sit where the pose moves the face.

The avatar is the default head with a large static torso below it (1.35 m tall, 0.44 m wide; no shape moves it and
no joint skins it, so it lies outside :func:`kdfaces.rig.region.moving_region`). ``meshes/makehuman_body.npz`` (a
real MakeHuman full body) is used in its place when it exists.

What is measured is the rendered image: the filmstrip's panels are drawn with the region's vertices pure green and
the rest blue (the render's part colours, swapped for the test), and the rows holding green pixels are the face's
height. The acceptance is that the face fills at least half the panel height; framed as before (the whole mesh)
the same face is a quarter of it, so the measure tells the two apart.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from kdfaces import KDInputError

ROOT = Path(__file__).resolve().parents[1]
BODY = ROOT / "meshes" / "makehuman_body.npz"
GREEN, BLUE = (0.0, 0.85, 0.0), (0.1, 0.2, 0.9)
SHOT_TOML = """
name = "body-region"

[rig]
source = "{rig}"

[animation]
source = "keys"
end_s = 0.48

[[animation.tracks]]
shapes = ["jawOpen"]
times_s = [0.0, 0.2, 0.4]
values = [[0], [1], [0]]

[animation.head]
times_s = [0.0, 0.2, 0.4]
yaw_deg = [0, 15, 0]

[dynamics]
settle_time_s = 0.2
damping_ratio = 0.3
window_s = 0.24

[[constraints]]
time_s = 0.32
kind = "pose"
target = {{ weights = {{ jawOpen = 0.8 }} }}
width_s = 0.15
label = "jaw open"

[solver]
update = "secant"
max_iterations = 4
"""


def _torso(top_y: float, bottom_y: float, half_x: float, half_z: float, centre_z: float, *, segments=24, rings=12):
    """A closed elliptic cylinder (vertices (V, 3) [m], triangles (F, 3)) from ``bottom_y`` to ``top_y`` [m]."""
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ys = np.linspace(top_y, bottom_y, rings)
    ring = np.stack([half_x * np.cos(a), np.zeros_like(a), centre_z + half_z * np.sin(a)], axis=1)
    v = np.concatenate([ring + [0.0, y, 0.0] for y in ys] + [[[0.0, top_y, centre_z], [0.0, bottom_y, centre_z]]])
    faces = []
    for r in range(rings - 1):
        for s in range(segments):
            i, j = r * segments + s, r * segments + (s + 1) % segments
            faces += [(i, i + segments, j), (j, i + segments, j + segments)]
    top, bottom = len(v) - 2, len(v) - 1
    last = (rings - 1) * segments
    for s in range(segments):
        faces += [(top, s, (s + 1) % segments), (bottom, last + (s + 1) % segments, last + s)]
    return v, np.asarray(faces, dtype=np.int64)


def body_like_rig(head):
    """The default head ``head`` on a static torso: one rig, the torso's vertices after the head's."""
    from kdfaces.rig import BlendshapeRig, Skeleton

    lo, hi = head.neutral.min(axis=0), head.neutral.max(axis=0)
    tv, tf = _torso(lo[1] - 0.01, lo[1] - 1.36, 0.22, 0.13, 0.5 * (lo[2] + hi[2]))
    n, m = head.num_vertices, len(tv)
    s = head.skeleton
    skeleton = Skeleton(s.names, s.positions, s.parents, np.concatenate([s.weights, np.zeros((m, len(s.names)))]))
    parts = np.concatenate([head.vertex_parts, np.full(m, len(head.part_names))])
    return BlendshapeRig.create(np.concatenate([head.neutral, tv]),
                                np.concatenate([head.deltas, np.zeros((head.num_shapes, m, 3), np.float32)], axis=1),
                                np.concatenate([head.faces, tf + n]), head.shape_names, skeleton=skeleton,
                                name="body-like", part_names=(*head.part_names, "torso"), vertex_parts=parts,
                                check_units=False)


@pytest.fixture(scope="module")
def body_run(tmp_path_factory, default_rig):
    from kdfaces.io.rigfiles import save_npz
    from kdfaces.shots.run import run_shot
    from kdfaces.shots.shotfile import load_shot

    folder = tmp_path_factory.mktemp("body")
    rig_path = BODY if BODY.exists() else save_npz(body_like_rig(default_rig), folder / "body.npz")
    (folder / "shot.toml").write_text(SHOT_TOML.format(rig=rig_path.as_posix()))
    with warnings.catch_warnings():  # a 1.7 m avatar in metres: the units check is another part of issue 25
        warnings.simplefilter("ignore", UserWarning)
        shot = load_shot(folder / "shot.toml")
    return run_shot(shot)


@pytest.fixture(scope="module")
def region(body_run):
    from kdfaces.rig.region import moving_region

    r = moving_region(body_run.shot.rig)
    assert 0 < len(r) < 0.9 * body_run.shot.rig.num_vertices  # the torso (or the body) is outside it
    return r


def region_colours(rig, region) -> np.ndarray:
    c = np.tile(np.asarray(BLUE), (rig.num_vertices, 1))
    c[region] = GREEN
    return c


def green_rows(img: np.ndarray) -> float:
    """The fraction of the image height spanned by rows that hold green (region) pixels."""
    x = img[..., :3].astype(np.int16)
    green = (x[..., 1] > x[..., 0] + 40) & (x[..., 1] > x[..., 2] + 40)
    rows = np.flatnonzero(green.sum(axis=1) >= 2)
    return 0.0 if not len(rows) else (rows[-1] - rows[0] + 1) / img.shape[0]


def test_filmstrip_face_fills_half_the_height(body_run, region, tmp_path, monkeypatch):
    from PIL import Image

    import kdfaces.shots.render as render_mod
    import kdfaces.viz.figures as figures
    import kdfaces.viz.markers as markers_mod
    from kdfaces.viz.figures import FaceRenderer

    rig = body_run.shot.rig
    colours = region_colours(rig, region)
    monkeypatch.setattr(render_mod, "part_colors", lambda _rig: colours)
    panels, marker_sets = [], []
    grid = figures.image_grid

    def keep_panels(images, *a, **k):  # the filmstrip's panels, as the figure receives them
        panels.extend(img for row in images.values() for img in row)
        return grid(images, *a, **k)

    draw = markers_mod.constraint_markers

    def keep_markers(c, x, *a, **k):
        out = draw(c, x, *a, **k)
        marker_sets.append((c, out))
        return out

    monkeypatch.setattr(figures, "image_grid", keep_panels)
    monkeypatch.setattr(markers_mod, "constraint_markers", keep_markers)
    summary = render_mod.render_shot(body_run, tmp_path, frames=3, movie=False)
    assert summary["outputs"][0] == "filmstrip.png" and "constraints.png" in summary["outputs"]
    assert len(panels) == 3 * len(summary["still_times_s"]) >= 3  # kinematic | KD | IKD per still
    fill = [green_rows(p) for p in panels]
    assert min(fill) >= 0.5, fill
    strip = np.asarray(Image.open(tmp_path / "filmstrip.png").convert("RGB"))
    assert green_rows(strip) > 0  # the written PNG shows the green face
    # framed as before, on the whole mesh, the same face is far smaller: the measure tells the framings apart
    with FaceRenderer(rig.faces, body_run.kinematic[0], colors=colours) as whole:
        assert green_rows(whole.render(body_run.kinematic[0])) < 0.35
    # the constraint panel's pose markers (before and after IKD) all sit on region vertices
    assert len(marker_sets) == 2
    inside = set(region.tolist())
    for c, ms in marker_sets:
        for m in ms:
            assert len(m.points) > 0
        target = ms[0].points
        d = np.linalg.norm(c.target[:, None, :] - target[None], axis=2)
        assert set(np.argmin(d, axis=0).tolist()) <= inside
        assert d.min(axis=0).max() == 0.0  # marker points are target points, not interpolations


def test_pose_markers_lie_where_the_pose_moves_the_face(body_run, region):
    from kdfaces.viz.markers import MARKER_MOTION_FRACTION, constraint_markers, marker_members

    rig = body_run.shot.rig
    c = body_run.ikd_result.constraints[0]
    assert c.kind == "pose"
    xk = body_run.shot.trajectory.positions([c.time_s])[0]
    members = marker_members(c, focus=region, moved_from=xk)
    disp = np.linalg.norm(c.target - xk, axis=1)
    inside = np.zeros(rig.num_vertices, bool)
    inside[region] = True
    assert inside[members].all()
    # exactly the region's vertices the jaw pose moves by ≥ the fraction of its largest displacement
    expect = np.flatnonzero(inside & (disp >= MARKER_MOTION_FRACTION * disp[inside].max()))
    np.testing.assert_array_equal(members, expect)
    assert disp[members].min() > 1e-4  # the jaw opens by millimetres there (not round-off)
    target, reached = constraint_markers(c, xk, focus=region, moved_from=xk, max_points=40)
    assert 1 < len(target.points) <= 40
    np.testing.assert_array_equal(target.points, c.target[members][
        np.unique(np.linspace(0, len(members) - 1, min(len(members), 40)).round().astype(int))])
    # without the region the evenly thinned markers of a pose spread over the whole body (torso included)
    spread = constraint_markers(c, xk, max_points=40)[0].points
    nearest = np.argmin(np.linalg.norm(c.target[:, None] - spread[None], axis=2), axis=0)
    assert (~inside[nearest]).any()
    with pytest.raises(KDInputError, match="markers focus: vertex indices must lie in"):
        marker_members(c, focus=[rig.num_vertices])


def test_heat_clim_is_measured_on_the_region():
    from kdfaces.viz.heatmap import MIN_CLIM_MM, heat_clim

    n, r = 1000, 4  # a face of 0.4 % of the vertices: fewer than the 0.5 % above the 99.5th percentile
    dev = np.zeros((2, n))
    dev[:, :r] = np.linspace(1.0, 5.0, r)  # the face deviates 1–5 mm, the body not at all
    focus = np.arange(r)
    assert heat_clim(dev)[1] == MIN_CLIM_MM  # over every vertex the 99.5th percentile is the still body's 0
    assert heat_clim(dev, focus=focus)[1] == pytest.approx(np.percentile(dev[:, :r], 99.5), rel=1e-12)
    mask = np.zeros(n, bool)
    mask[:r] = True
    assert heat_clim(dev, focus=mask) == heat_clim(dev, focus=focus)
    with pytest.raises(KDInputError, match="focus: no vertices"):
        heat_clim(dev, focus=[])


def test_viewer_opens_on_the_region(body_run, region):
    from kdfaces.viz.figures import framing
    from kdfaces.viz.viewer import ShotViewer

    rig = body_run.shot.rig
    v = ShotViewer(body_run.shot, off_screen=True, size=(160, 120), widgets=False)
    try:
        np.testing.assert_array_equal(v.focus, region)
        centre, position = framing(rig.neutral, region, (0.35, 0.15, 1.0), distance=3.0)
        np.testing.assert_allclose(v.plotter.camera.focal_point, centre, atol=1e-9)
        np.testing.assert_allclose(v.plotter.camera.position, position, atol=1e-9)
        lo, hi = rig.neutral[region].min(axis=0), rig.neutral[region].max(axis=0)
        np.testing.assert_allclose(centre, 0.5 * (lo + hi), atol=1e-12)
        # the camera is as far from the region as the default head's camera is from the whole head
        assert np.linalg.norm(position - centre) == pytest.approx(1.5 * np.linalg.norm(hi - lo), rel=1e-12)
    finally:
        v.close()


def test_default_head_region_is_the_whole_head(default_rig):
    """On the default head the region is every vertex, so renders keep the whole-mesh framing (the reference
    images of tests/test_render.py and tests/test_viewer.py stay as they are)."""
    from kdfaces.viz.figures import check_focus, rig_focus

    assert rig_focus(default_rig) is None
    n = default_rig.num_vertices
    np.testing.assert_array_equal(check_focus(np.arange(n)[::-1], n), np.arange(n))
    with pytest.raises(KDInputError, match=r"focus: expected vertex indices"):
        check_focus(np.array([0.5, 1.0]), n)
