"""Issue 25's acceptance on a production-like avatar: the whole MakeHuman body, written by Blender as a centimetre
FBX with a studio's shape names (``AK_01_BrowDownLeft`` … ``AK_52_TongueOut``), run from a shot file that names only
the rig file and a Live Link Face take (no units key: the file says cm; no map: the names canonicalise).

The baseline is the same face cut out on its own (:func:`avatar_fixtures.cut_out_face`, metres, ARKit names, the
same take). The body simulates its moving region (the face plus a two-ring margin into the neck and shoulders), the
cut-out face every vertex of its own mesh, so the two differ at the boundary only:

- the automatic window (§5.2) is a log of v0/ε, and ε is 0.1 % of the region's diameter (0.59 m against the cut-out's
  0.51 m), so the windows agree to a few per cent, within the acceptance's 10 %;
- the largest KD deviation happens on the jaw and lips, far from the boundary: within the acceptance's 20 %.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from avatar_fixtures import cut_out_face, load_body, studio_avatar, write_avatar_fbx, write_livelink_take

from kdfaces.rig.blendshapes import RigUnitsWarning

bpy_missing = None
try:  # Blender writes the FBX (tests/fbx_fixtures.py runs it in a subprocess)
    import importlib.util

    if importlib.util.find_spec("bpy") is None:
        bpy_missing = "bpy (Blender as a Python module, the 'blender' extra) is not installed: it writes the FBX"
except (ImportError, ValueError):
    bpy_missing = "bpy is not importable"

pytestmark = pytest.mark.skipif(bpy_missing is not None, reason=bpy_missing or "")

TAKE_S = 4.0
SHOT = """
[rig]
source = "{rig}"

[animation]
source = "{take}"
"""
IKD_SHOT = SHOT + """
[dynamics]
window_s = 0.3

[[constraints]]
time_s = 2.0
kind = "pose"
group = "jaw"
target = {{ weights = {{ AK_25_JawOpen = 0.6 }} }}
width_s = 0.3
label = "jaw, in the rig's own names"

[solver]
max_iterations = 12
"""


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from kdfaces.io.rigfiles import save_npz

    folder = tmp_path_factory.mktemp("avatar")
    body = load_body()
    fbx = write_avatar_fbx(studio_avatar(body), folder / "avatar.fbx")
    face = save_npz(cut_out_face(body), folder / "face.npz")
    take = write_livelink_take(folder / "take.csv", TAKE_S, fps=30, seed=3)
    return folder, fbx, face, take


def _shot(folder, name, rig, take, template=SHOT):
    from kdfaces.shots.shotfile import load_shot

    path = folder / f"{name}.toml"
    path.write_text(template.format(rig=rig.as_posix(), take=take.as_posix()))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RigUnitsWarning)  # no units warning: the file says cm, the face is a head
        return load_shot(path)


@pytest.fixture(scope="module")
def runs(files):
    from kdfaces.shots.run import run_shot

    folder, fbx, face, take = files
    body_shot = _shot(folder, "body", fbx, take)
    face_shot = _shot(folder, "face", face, take)
    return run_shot(body_shot), run_shot(face_shot)


def test_the_avatar_loads_in_metres_with_its_own_names(runs):
    body_run, face_run = runs
    rig = body_run.shot.rig
    assert rig.source_unit_m == pytest.approx(0.01)
    assert "AK_25_JawOpen" in rig.shape_names  # the rig keeps its own names
    height = np.ptp(rig.neutral[:, 1])
    assert 1.5 < height < 2.0, height  # metres, y up
    # every capture channel found a shape through the canonical names: nothing was mapped by hand
    trajectory = body_run.shot.trajectory
    assert not trajectory.skipped_channels
    assert sum(how == "name" for how in trajectory.channel_resolution.values()) == 52


def test_the_automatic_window_is_the_cut_out_faces(runs):
    body_run, face_run = runs
    assert body_run.window_auto_s == pytest.approx(face_run.window_auto_s, rel=0.10)


def test_the_faces_largest_deviation_matches_the_cut_out_face(runs):
    body_run, face_run = runs
    body_max, face_max = float(body_run.deviation_m.max()), float(face_run.deviation_m.max())
    assert face_max > 1e-3  # visible secondary motion (millimetres), not a frozen face
    assert body_max == pytest.approx(face_max, rel=0.20)


def test_ikd_on_the_jaw_group_with_the_rigs_own_names_converges(files):
    from kdfaces.shots.run import run_shot

    folder, fbx, face, take = files
    run = run_shot(_shot(folder, "ikd", fbx, take, IKD_SHOT))
    assert run.ikd_result is not None and run.ikd_result.converged, run.ikd_result.reason
    assert float(np.max(run.check_errors)) <= run.shot.solver_options()["tolerance_m"] * 1.0001


def test_the_filmstrip_shows_the_face_at_half_the_image_height(runs, tmp_path, monkeypatch):
    from test_render_region import green_rows, region_colours

    import kdfaces.shots.render as render_mod
    import kdfaces.viz.figures as figures
    from kdfaces.rig.region import moving_region

    body_run, _ = runs
    rig = body_run.shot.rig
    monkeypatch.setattr(render_mod, "part_colors", lambda _rig: region_colours(rig, moving_region(rig)))
    panels = []
    grid = figures.image_grid

    def keep_panels(images, *a, **k):
        panels.extend(img for row in images.values() for img in row)
        return grid(images, *a, **k)

    monkeypatch.setattr(figures, "image_grid", keep_panels)
    render_mod.render_shot(body_run, tmp_path, frames=3, movie=False)
    fill = [green_rows(p) for p in panels]
    assert fill and min(fill) >= 0.5, fill
