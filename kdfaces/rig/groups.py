"""Named vertex groups of a blend-shape rig, derived from the shapes that move each region.

``lips`` are the vertices the lip shapes move, ``cheek_left`` those ``cheekSquintLeft`` moves, and so on: a vertex
belongs to a group when its largest displacement over the group's shapes is at least ``fraction`` of the largest
displacement of any vertex. This works on any ARKit-named rig without hand-painted masks.
"""

from __future__ import annotations

import numpy as np

from ..errors import KDInputError

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


def vertex_group(rig, spec, *, fraction: float = 0.25, where: str = "group") -> np.ndarray:
    """Vertex indices (G,) for ``spec``: a name in :data:`GROUP_SHAPES`, ``"shape:<name>"`` for one shape's
    region, ``"all"``, or an explicit list of indices."""
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
        shapes = (spec.split(":", 1)[1],)
    elif spec in GROUP_SHAPES:
        shapes = tuple(s for s in GROUP_SHAPES[spec] if s in rig.shape_names)
        if not shapes:
            raise KDInputError(f"{where}: rig {rig.name!r} has none of the shapes that define group {spec!r}")
    else:
        raise KDInputError(f"{where}: unknown group {spec!r}; expected one of {sorted(GROUP_SHAPES)}, 'all', "
                           "'shape:<name>' or a list of vertex indices")
    idx = rig.shape_indices(list(shapes), where=where)
    mag = np.linalg.norm(rig.deltas[idx].astype(np.float64), axis=2).max(axis=0)
    if mag.max() <= 0:
        raise KDInputError(f"{where}: the shapes of group {spec!r} move no vertex")
    return np.flatnonzero(mag >= fraction * mag.max())
