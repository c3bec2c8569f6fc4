"""Scenes built on the FEM hat: the floppy hat under the door (paper §4.4, Fig. 7-d)."""

from .door import DOOR_SHOT, DoorScene, DoorShot, build_door_scene, load_door_shot, run_door, walk_root_curve

__all__ = ["DOOR_SHOT", "DoorScene", "DoorShot", "build_door_scene", "load_door_shot", "run_door", "walk_root_curve"]
