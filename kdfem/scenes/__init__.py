"""Scenes built on the FEM hat: the floppy hat under the door (paper §4.4, Fig. 7-d), and a head that follows
through a sharp turn on the skeletal KD neck (issue 16)."""

from .door import (
           DOOR_MAX_STEPS,
           DOOR_SHOT,
           DoorScene,
           DoorShot,
           build_door_scene,
           check_door_work,
           load_door_shot,
           run_door,
           walk_root_curve,
)
from .follow import FOLLOW_SETTLE_S, run_follow

__all__ = ["DOOR_SHOT", "DOOR_MAX_STEPS", "DoorScene", "DoorShot", "build_door_scene", "check_door_work",
           "load_door_shot", "run_door", "walk_root_curve", "FOLLOW_SETTLE_S", "run_follow"]
