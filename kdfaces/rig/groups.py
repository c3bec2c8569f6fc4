"""Named vertex groups of a blend-shape rig, derived from the shapes that move each region.

``lips`` are the vertices the lip shapes move, ``cheek_left`` those ``cheekSquintLeft`` moves, and so on: a vertex
belongs to a group when its largest displacement over the group's shapes is at least ``fraction`` of the largest
displacement of any vertex. The group's ARKit names find the rig's shapes as capture channels do
(:func:`kdfaces.rig.names.find_shapes`): by the shot's ``[animation.map]``, by canonical name (``AK_25_JawOpen`` is
``jawOpen``) or by side-split pair, so groups work on any rig without hand-painted masks.
"""

from __future__ import annotations

import difflib

import numpy as np

from ..errors import KDInputError
from .names import closest_shapes, find_shapes

__all__ = ["GROUP_SHAPES", "vertex_group"]

GROUP_SHAPES: dict[str, tuple[str, ...]] = {
    "lips": ("mouthFunnel", "mouthPucker", "mouthRollLower", "mouthRollUpper", "mouthPressLeft", "mouthPressRight"),
    "mouth": ("mouthSmileLeft", "mouthSmileRight", "mouthFunnel", "mouthPucker", "mouthStretchLeft",
              "mouthStretchRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
              "mouthUpperUpRight"),
    "jaw": ("jawOpen",),
    "cheeks": ("cheekPuff",),
    "cheek_left": ("cheekSquintLeft",),
    "cheek_right": ("cheekSquintRight",),
    "brows": ("browInnerUp", "browOuterUpLeft", "browOuterUpRight", "browDownLeft", "browDownRight"),
    "eyelids": ("eyeBlinkLeft", "eyeBlinkRight"),
    "nose": ("noseSneerLeft", "noseSneerRight"),
}


def _suggest(rig, spec: str, also=()) -> str:
    """``; use 'shape:<name>' … (the rig's shapes closest to …: a, b, c)`` for a group error."""
    close = closest_shapes(spec.split("_")[0], rig.shape_names, n=5, also=also)
    example = close[0] if close else (rig.shape_names[0] if rig.shape_names else "<name>")
    shown = f"; the rig's shapes closest to {spec!r}: {', '.join(close)}" if close else ""
    return (f"; use 'shape:<name>' for one of the rig's shapes (e.g. group = \"shape:{example}\") or map the "
            f"group's ARKit names in [animation.map]{shown}")


def vertex_group(rig, spec, *, fraction: float = 0.25, where: str = "group", channel_map: dict | None = None
                 ) -> np.ndarray:
    """Vertex indices (G,) int64 for ``spec``: a name in :data:`GROUP_SHAPES`, ``"shape:<name>"`` for one shape's
    region, ``"all"``, or an explicit list of indices.

    ``channel_map`` (a shot's ``[animation.map]``: channel → the rig's shape name or names) finds a group's shapes
    on a rig whose names are not ARKit's (``jawOpen = "JawDrop"`` makes ``jaw`` the vertices ``JawDrop`` moves).
    An unknown group, or one none of whose shapes the rig has, is a :class:`KDInputError` suggesting
    ``shape:<name>`` and naming the rig's closest shapes."""
    n = rig.num_vertices
    if isinstance(spec, list | tuple | np.ndarray) and not isinstance(spec, str):
        idx = np.asarray(spec, dtype=np.int64).reshape(-1)
        if len(idx) == 0 or idx.min() < 0 or idx.max() >= n or len(np.unique(idx)) != len(idx):
            raise KDInputError(f"{where}: expected distinct vertex indices in [0, {n})")
        return idx
    if not isinstance(spec, str):
        raise KDInputError(f"{where}: expected a group name or a list of vertex indices, got {spec!r}")
    if spec == "all":
        return np.arange(n)
    if spec.startswith("shape:"):
        idx = rig.shape_indices([spec.split(":", 1)[1]], where=where)
    elif spec in GROUP_SHAPES:
        idx = find_shapes(GROUP_SHAPES[spec], rig.shape_names, channel_map=channel_map, where=f"{where} {spec!r}")
        if not idx:
            raise KDInputError(f"{where}: rig {rig.name!r} has none of the shapes that define group {spec!r} "
                               f"({', '.join(GROUP_SHAPES[spec])}){_suggest(rig, spec, GROUP_SHAPES[spec])}")
    else:
        near = difflib.get_close_matches(spec, list(GROUP_SHAPES), n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise KDInputError(f"{where}: unknown group {spec!r}{hint}; expected one of {sorted(GROUP_SHAPES)}, 'all', "
                           f"'shape:<name>' or a list of vertex indices"
                           f"{_suggest(rig, spec, GROUP_SHAPES[near[0]] if near else ())}")
    mag = np.linalg.norm(rig.deltas[idx].astype(np.float64), axis=2).max(axis=0)
    if mag.max() <= 0:
        raise KDInputError(f"{where}: the shapes of group {spec!r} move no vertex")
    return np.flatnonzero(mag >= fraction * mag.max())
