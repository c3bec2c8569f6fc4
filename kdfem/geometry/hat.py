"""A procedural Christmas-style hat: a closed, thick-walled cone shell with a brim (trimesh, ``process=False``).

The hat is a surface of revolution of a closed profile polygon (brim band, outer cone, solid tip, inner cone),
then tilted back about the x axis and placed on the default head (y up, face looking +z). Its tip is long
(≈ 0.3 m) and thin enough to flop under the head's motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kdfaces.deprecation import renamed_attribute, renamed_kwargs
from kdfaces.errors import KDInputError

__all__ = ["HatParams", "hat_profile", "christmas_hat"]


@dataclass(frozen=True)
class HatParams:
    """Hat geometry. Lengths in metres, angles in radians.

    Attributes:
        height_m: cone length from the brim plane to the tip [m].
        radius_m: inner radius of the opening (sits on the head) [m].
        thickness_m: wall thickness of the cone [m].
        brim_width_m: how far the brim band sticks out beyond the cone wall [m].
        brim_height_m: height of the brim band [m].
        tilt: backward lean of the cone axis about +x [rad] (tip towards −z).
        base_center_m: centre of the opening on the default head (x, y, z) [m].
        segments: divisions around the axis; rings: divisions along the cone.

    The names without ``_m`` (``height``, ``radius``, ``thickness``, ``brim_width``, ``brim_height``,
    ``base_center``; keyword and attribute) still work for one release, with a :class:`DeprecationWarning`.
    """

    height_m: float = 0.30
    radius_m: float = 0.088
    thickness_m: float = 0.012
    brim_width_m: float = 0.012
    brim_height_m: float = 0.025
    tilt: float = 0.35
    base_center_m: tuple[float, float, float] = (0.0, 0.765, 0.055)
    segments: int = 48
    rings: int = 24

    def __post_init__(self):
        for name in ("height_m", "radius_m", "thickness_m", "brim_width_m", "brim_height_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise KDInputError(f"hat {name}: expected a positive length in metres, got {v}")
        if self.thickness_m >= self.radius_m:
            raise KDInputError(f"hat thickness_m: must be below the radius {self.radius_m} m, got {self.thickness_m}")
        if self.brim_height_m >= 0.5 * self.height_m:
            raise KDInputError(f"hat brim_height_m: must be below half the height {self.height_m} m")
        if self.segments < 8 or self.rings < 4:
            raise KDInputError("hat segments/rings: expected at least 8 segments and 4 rings")

    height = renamed_attribute("height_m")
    radius = renamed_attribute("radius_m")
    thickness = renamed_attribute("thickness_m")
    brim_width = renamed_attribute("brim_width_m")
    brim_height = renamed_attribute("brim_height_m")
    base_center = renamed_attribute("base_center_m")


HatParams.__init__ = renamed_kwargs(height="height_m", radius="radius_m", thickness="thickness_m",
                                    brim_width="brim_width_m", brim_height="brim_height_m",
                                    base_center="base_center_m")(HatParams.__init__)


def hat_profile(p: HatParams) -> np.ndarray:
    """Closed profile polygon (P, 2) of (radius, axial height) [m], counter-clockwise in the (r, s) half-plane.

    The first and last points lie on the axis (r = 0): the inner apex, and the outer apex (tip) above it.
    """
    H, r_in, t = p.height_m, p.radius_m, p.thickness_m
    r_out = r_in + t
    s_in_apex = H - 2.5 * t  # inner cone closes below the tip: the last 2.5 t are solid
    s = np.linspace(0.0, 1.0, p.rings + 1)
    # outer cone r_out(s) from the brim top up to the apex, slightly concave (a drooping Christmas hat)
    s_out = p.brim_height_m + (H - p.brim_height_m) * s
    r_cone_out = r_out * (1 - (s_out / H)) ** 1.15
    s_inn = s_in_apex * s
    r_cone_in = r_in * (1 - s_inn / s_in_apex) ** 1.15
    brim = [(r_in, 0.0), (r_out + p.brim_width_m, 0.0), (r_out + p.brim_width_m, p.brim_height_m)]
    outer = list(zip(r_cone_out, s_out))  # ends at (0, H)
    inner = list(zip(r_cone_in[::-1], s_inn[::-1]))  # starts at (0, s_in_apex), ends at (r_in, 0)
    prof = inner[:-1] + brim + outer  # inner apex → down the inside → brim → up the outside → tip
    return np.asarray(prof, dtype=np.float64)


def _revolve(profile: np.ndarray, segments: int):
    """Revolve a profile whose first and last points lie on the axis → (V, 3), (F, 3) closed triangle mesh."""
    ring = profile[1:-1]
    n, m = len(ring), segments
    th = 2 * np.pi * np.arange(m) / m
    x = ring[:, :1] * np.cos(th)[None]
    z = ring[:, :1] * np.sin(th)[None]
    y = np.broadcast_to(ring[:, 1:2], x.shape)
    verts = np.concatenate([[[0.0, profile[0, 1], 0.0]], np.stack([x, y, z], -1).reshape(-1, 3),
                            [[0.0, profile[-1, 1], 0.0]]])
    idx = 1 + np.arange(n * m).reshape(n, m)
    j = np.arange(m)
    jn = (j + 1) % m
    top = np.stack([np.zeros(m, np.int64), idx[0, jn], idx[0, j]], 1)
    a, b = idx[:-1][:, j], idx[:-1][:, jn]
    c, d = idx[1:][:, j], idx[1:][:, jn]
    quads = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    last = len(verts) - 1
    bot = np.stack([np.full(m, last), idx[-1, j], idx[-1, jn]], 1)
    return verts, np.concatenate([top, quads, bot]).astype(np.int64)


def christmas_hat(params: HatParams | None = None):
    """The hat surface as a ``trimesh.Trimesh`` (``process=False``), watertight, outward-oriented, in metres."""
    import trimesh

    p = params or HatParams()
    v, f = _revolve(hat_profile(p), p.segments)
    mesh = trimesh.Trimesh(v, f, process=False)
    if mesh.volume < 0:
        f = f[:, ::-1].copy()
    c, s = np.cos(p.tilt), np.sin(p.tilt)
    rot = np.array([[1.0, 0, 0], [0, c, s], [0, -s, c]])  # about +x, tip leans to −z
    v = v @ rot.T + np.asarray(p.base_center_m)
    mesh = trimesh.Trimesh(v, f, process=False)
    if not mesh.is_watertight or mesh.volume <= 0:
        raise KDInputError("hat: the generated surface is not closed; check the parameters")
    return mesh
