"""Regenerate the reference images of the image tests (tests/reference/*.png).

Run after a deliberate change of the renderer's look (camera, lighting, colours, viewer layout), look at the
PNGs, and commit them:

    .venv/bin/python scripts/make_reference_images.py

Every reference of ``render_references`` is kinematic (rig + renderer only), so tuning the dynamics never
invalidates them; it is also what tests/test_render.py calls to compare a fresh render with the stored one.
``authoring_references`` (part of them) are the authoring viewers' (issue 26: target handles, the constraint
panel, the punch's fist target), also compared by tests/test_authoring_viewer.py and tests/test_punch_viewer.py; the
hat's is at frame 0, its state at rest, and the face's and the punch's are kinematic, so they do not depend on the
dynamics either.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

REFERENCE_DIR = Path(__file__).resolve().parents[1] / "tests" / "reference"
REFERENCE_SHOT = REFERENCE_DIR / "shot.toml"
SIZE = (200, 240)


def render_references() -> dict[str, np.ndarray]:
    """name → RGB image (H, W, 3) uint8 of each reference render."""
    from kdfaces.shots.shotfile import load_shot
    from kdfaces.viz.figures import FaceRenderer
    from kdfaces.viz.heatmap import HEAT_CMAP, deviation_mm, heat_clim
    from kdfaces.viz.markers import constraint_markers
    from kdfaces.viz.viewer import ShotViewer

    shot = load_shot(REFERENCE_SHOT)
    rig = shot.rig
    pose = shot.trajectory.positions([0.3])[0]  # jaw open, head turned 25°
    target = shot.constraints()[0]
    images = {}
    with FaceRenderer(rig.faces, rig.neutral, size=SIZE) as r:
        images["neutral"] = r.render(rig.neutral)
        images["pose_markers"] = r.render(pose, markers=constraint_markers(target, pose, max_points=40))
        dev = deviation_mm(pose, rig.neutral)
        images["heat"] = r.render(rig.neutral, dev, clim=heat_clim(dev), cmap=HEAT_CMAP)
    viewer = ShotViewer(shot, off_screen=True, size=(320, 240))
    try:
        viewer.set_mode("kinematic")
        viewer.set_frame(7)
        viewer.plotter.render()
        images["viewer_kinematic"] = np.asarray(viewer.plotter.screenshot(return_img=True))[..., :3].copy()
    finally:
        viewer.close()
    images.update(authoring_references())
    return images


def hat_target_image(viewer) -> np.ndarray:
    """``kdfem view`` (a :class:`kdfem.viewer.HatViewer`) at frame 0 with a tip target 3 cm above the tip, not solved:
    the RGB screenshot (H, W, 3) uint8."""
    viewer.clear_tip_target()
    viewer.set_frame(0)
    viewer.add_tip_target()
    viewer.offset_tip_target_mm(0.0, 30.0, 0.0)
    viewer._text.SetText(2, "")  # the status line shows wall-clock ms per KD state: not part of the reference
    viewer.plotter.render()
    return np.asarray(viewer.plotter.screenshot(return_img=True))[..., :3].copy()


def authoring_panel_image(viewer) -> np.ndarray:
    """``kdfaces view`` with an authoring session on (a copy of) the reference shot, kinematic mode at 0.8 s: the
    chin picked (a point target, its handle 3 mm below) and the constraint panel, not solved (RGB (H, W, 3))."""
    from kdfaces.rig.groups import vertex_group

    viewer.set_mode("kinematic")
    viewer.set_frame(20)
    jaw = vertex_group(viewer.shot.rig, "jaw")
    x = viewer.points
    front = jaw[x[jaw, 2] > np.percentile(x[jaw, 2], 90)]
    viewer.pick_vertex(int(front[np.argmin(x[front, 1])]))
    viewer.set_offset_mm(None, 0.0, -3.0, 0.0)
    viewer._text.SetText(2, "")  # the status line shows wall-clock ms per KD state: not part of the reference
    viewer.plotter.render()
    return np.asarray(viewer.plotter.screenshot(return_img=True))[..., :3].copy()


def punch_target_image(viewer) -> np.ndarray:
    """``kdfaces punch --view`` (a :class:`kdfaces.viz.punch_viewer.PunchViewer`) in kinematic mode at t_i with the fist
    target 5 cm above the punch's, not solved: the RGB screenshot (H, W, 3) uint8 (kinematic: no dynamics in it)."""
    viewer.reset_fist_target()
    viewer.set_mode("kinematic")
    viewer.set_frame(viewer.ti_frame)
    viewer.offset_fist_target_mm(0.0, 50.0, 0.0)
    viewer._text.SetText(2, "")  # the status line shows wall-clock ms per KD state: not part of the reference
    viewer.plotter.render()
    return np.asarray(viewer.plotter.screenshot(return_img=True))[..., :3].copy()


def authoring_references() -> dict[str, np.ndarray]:
    """name → RGB image (H, W, 3) uint8 of each authoring-viewer reference."""
    import shutil
    import tempfile

    from kdfaces.shots.authoring import AuthoringSession
    from kdfaces.viz.viewer import ShotViewer
    from kdfem.viewer import HatViewer

    images = {}
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copy(REFERENCE_SHOT, Path(tmp) / "shot.toml")
        session = AuthoringSession(Path(tmp) / "shot.toml")
        viewer = ShotViewer(session.shot, off_screen=True, size=(640, 480), widgets=False, session=session)
        try:
            images["authoring_panel"] = authoring_panel_image(viewer)
        finally:
            viewer.close()
    hat = HatViewer(off_screen=True, size=(320, 240))
    try:
        images["hat_tip_target"] = hat_target_image(hat)
    finally:
        hat.close()
    from kdfaces.viz.punch_viewer import PunchViewer

    punch = PunchViewer(off_screen=True, size=(320, 240), widgets=False)
    try:
        images["punch_fist_target"] = punch_target_image(punch)
    finally:
        punch.close()
    return images


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REFERENCE_DIR, help="folder for the PNGs (default tests/reference)")
    args = ap.parse_args(argv)
    from PIL import Image

    args.out.mkdir(parents=True, exist_ok=True)
    for name, img in render_references().items():
        Image.fromarray(img).save(args.out / f"{name}.png", optimize=True)
        print(f"wrote {args.out / name}.png {img.shape[1]}×{img.shape[0]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
