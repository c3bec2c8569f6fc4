"""Files in and out: rig files (npz, OBJ folders, MakeHuman, glTF, FBX), Live Link Face captures, point caches (USD,
PC2), rig export, summary.json, and atomic writes."""

from .atomic import atomic_path, write_bytes_atomic
from .export import EXPORT_KINDS, export_chunks, export_rig, export_trajectory
from .fbx import load_fbx_rig
from .gltf import load_gltf, load_gltf_animation, load_gltf_rig, save_gltf
from .livelinkface import LiveLinkTake, livelinkface_animation, read_livelinkface
from .pointcache import PointCache, read_pc2, read_usd, write_pc2, write_pc2_chunks, write_usd, write_usd_chunks
from .rigfiles import (
    DEFAULT_RIG_PATH,
    load_default_rig,
    load_makehuman,
    load_npz,
    load_obj_folder,
    load_rig,
    read_obj,
    save_npz,
    save_obj_folder,
    write_obj,
)
from .summary import to_jsonable, write_summary

__all__ = [
    "atomic_path", "write_bytes_atomic", "EXPORT_KINDS", "export_rig", "export_trajectory", "export_chunks",
    "load_gltf",
    "load_fbx_rig", "load_gltf_animation", "load_gltf_rig", "save_gltf", "LiveLinkTake", "livelinkface_animation",
    "read_livelinkface", "PointCache", "read_pc2", "read_usd", "write_pc2", "write_pc2_chunks", "write_usd",
    "write_usd_chunks", "DEFAULT_RIG_PATH",
    "load_default_rig", "load_makehuman", "load_npz", "load_obj_folder", "load_rig", "read_obj", "save_npz",
    "save_obj_folder", "write_obj", "to_jsonable", "write_summary",
]
