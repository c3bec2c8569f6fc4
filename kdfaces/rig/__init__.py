"""Rigs: blend-shape meshes, ARKit names, vertex groups, the neck/head skeleton (FK, LBS) and single poses;
production-size test rigs by subdivision."""

from .blendshapes import BlendshapeRig
from .groups import GROUP_SHAPES, vertex_group
from .names import ARKIT_NAMES, alias_key, canonical_name, match_names, resolve_channels
from .parts import connected_pieces, part_vertices, rigid_pieces
from .poses import kinematic_pose, rig_pose
from .region import moving_region, region_diameter, region_mask
from .skeleton import HEAD_CHAIN_SPLIT, Skeleton, joint_transforms, skin
from .subdivide import refine_faces, subdivide_rig
from .subset import subset_rig

__all__ = [
    "BlendshapeRig", "GROUP_SHAPES", "vertex_group", "ARKIT_NAMES", "alias_key", "canonical_name", "match_names",
    "kinematic_pose", "rig_pose", "HEAD_CHAIN_SPLIT", "Skeleton", "joint_transforms", "skin", "resolve_channels",
    "connected_pieces", "part_vertices", "rigid_pieces",
    "subdivide_rig", "refine_faces", "moving_region", "region_mask", "region_diameter", "subset_rig",
]
