"""Scenes built on the FEM hat: the floppy hat under the door (paper §4.4, Fig. 7-d), a head that follows through a
sharp turn on the skeletal KD neck (issue 16), and the Fig. 9 analog: IKD of the hat tip through the head posture
over a grid of targets (:mod:`kdfem.scenes.offset_grid`)."""

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
from .offset_grid import HAT_GRID_SPAN_M, HAT_GRID_TIME_S, HAT_GRID_UPDATES, hat_offset_grid, hat_tip_problem

__all__ = ["DOOR_SHOT", "DOOR_MAX_STEPS", "DoorScene", "DoorShot", "build_door_scene", "check_door_work",
           "load_door_shot", "run_door", "walk_root_curve", "FOLLOW_SETTLE_S", "run_follow", "hat_offset_grid",
           "hat_tip_problem", "HAT_GRID_SPAN_M", "HAT_GRID_TIME_S", "HAT_GRID_UPDATES"]
