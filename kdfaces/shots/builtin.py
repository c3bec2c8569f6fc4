"""The built-in shots: the demo animation (~6 s at 25 fps of expressions and a head turn/nod with sharp stops)
and the path of its shot file ``demo.toml`` (which holds the demo's dynamics and constraints)."""

from __future__ import annotations

from pathlib import Path

from ..motion.curves import KeyframeCurve
from ..motion.joints import JointDrive, SkeletonAnimation
from ..motion.trajectory import FaceAnimation, ShapeTrack

__all__ = ["demo_animation", "DEMO_FPS", "DEMO_DURATION_S", "DEMO_SHOT"]

DEMO_FPS = 25.0


DEMO_DURATION_S = 6.0


#: The demo shot file.
DEMO_SHOT = Path(__file__).resolve().parent / "demo.toml"


#: Hermite keys with zero tangents: smooth starts and stops, short transitions give sharp accelerations.
_ease = KeyframeCurve.eased


def demo_animation() -> FaceAnimation:
    """Expressions (jaw open, blink, smile, brow raise) and a quick head turn and nod, each stopping sharply."""
    tracks = (
        ShapeTrack(("jawOpen",), _ease([0.0, 0.5, 0.8, 1.4, 1.7], [0, 0, 0.7, 0.7, 0])),
        ShapeTrack(("eyeBlinkLeft", "eyeBlinkRight"),
                   _ease([0.0, 1.0, 1.1, 1.25, 4.8, 4.9, 5.05], [[0, 0], [0, 0], [1, 1], [0, 0], [0, 0], [1, 1],
                                                                   [0, 0]])),
        ShapeTrack(("mouthSmileLeft", "mouthSmileRight"),
                   _ease([0.0, 2.0, 2.35, 3.2, 3.6], [[0, 0], [0, 0], [1, 1], [1, 1], [0, 0]])),
        ShapeTrack(("browInnerUp", "browOuterUpLeft", "browOuterUpRight"),
                   _ease([0.0, 3.6, 3.85, 4.4, 4.7], [[0] * 3, [0] * 3, [1] * 3, [1] * 3, [0] * 3])),
    )
    # yaw, pitch, roll [rad] of the whole head, shared by the neck chain
    head = _ease(
        [0.0, 0.3, 0.65, 1.8, 2.15, 4.7, 5.0, 5.25, 5.5, 6.0],
        [[0, 0, 0], [0, 0, 0], [0.6, 0, 0.05], [0.6, 0, 0.05], [0, 0, 0], [0, 0, 0], [0, 0.35, 0],
         [0, -0.1, 0], [0, 0, 0], [0, 0, 0]],
    )
    return FaceAnimation(tracks=tracks, skeleton=SkeletonAnimation((JointDrive(head),)), start_s=0.0,
                         end_s=DEMO_DURATION_S, fps=DEMO_FPS, name="demo")
