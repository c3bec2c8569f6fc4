"""The two articulated models the toolkit ships: the default rig's neck/head chain and the MakeHuman right arm.

Masses are stated segment masses (Winter, *Biomechanics and Motor Control of Human Movement*, 4th ed., Table 4.1,
for a 70 kg body: head and neck 8.1 %, upper arm 2.8 %, forearm 1.6 %, hand 0.6 %), placed at centres of mass and
with inertias from the geometry:

- neck chain: each joint's centre of mass and inertia come from its skinned vertices (the skin-weighted centroid,
  and the inertia of a solid ellipsoid with the weighted vertices' second moments, I = 0.6·m·(tr C·1 − C));
- arm: segments from the rig's joint positions, centre of mass at Winter's fraction of the length from the proximal
  joint, transverse radius of gyration from the same table, longitudinal inertia of a 4 cm (3 cm hand) cylinder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import KDInputError
from ..rig.skeleton import Skeleton
from .model import ArticulatedModel, segment_inertia

__all__ = ["NECK_MASSES_KG", "ARM_SEGMENTS", "ARM_PATH", "neck_chain_model", "arm_chain_model"]

#: Stated masses [kg] of the default rig's joints' links (head and neck, 8.1 % of 70 kg = 5.7 kg).
NECK_MASSES_KG = {"neck01": 0.35, "neck02": 0.35, "neck03": 0.35, "head": 4.35, "jaw": 0.3}
#: Per arm link: (mass [kg] for 70 kg, centre-of-mass fraction from the proximal joint, radius of gyration / length,
#: cylinder radius [m]) — Winter's Table 4.1; the clavicle/shoulder girdle link is a stated 0.5 kg.
ARM_SEGMENTS = {"clavicle": (0.5, 0.5, 0.3, 0.03), "upperarm": (1.96, 0.436, 0.322, 0.045),
                "forearm": (1.12, 0.430, 0.303, 0.035), "hand": (0.42, 0.506, 0.297, 0.03)}
#: The arm chain built by ``scripts/build_makehuman_arm.py``.
ARM_PATH = Path(__file__).resolve().parents[2] / "meshes" / "makehuman_arm.npz"


def neck_chain_model(rig, *, masses_kg: dict | None = None, torque_limit_nm: float = 40.0) -> ArticulatedModel:
    """The neck/head chain of a rig with a skeleton (default: the MakeHuman head): one link per joint, masses
    ``masses_kg`` (default :data:`NECK_MASSES_KG`), centres of mass and inertias from the skinned vertices; the
    head's top (the highest vertex) is the named point ``crown``."""
    sk = rig.skeleton
    if sk is None:
        raise KDInputError(f"rig {rig.name!r} has no skeleton")
    masses = dict(NECK_MASSES_KG if masses_kg is None else masses_kg)
    x = rig.neutral.astype(np.float64)
    W = sk.weights
    m, c, inertia = [], [], []
    for j, name in enumerate(sk.names):
        if name not in masses:
            raise KDInputError(f"neck chain: no mass for joint {name!r}; give masses_kg for {list(sk.names)}")
        w = W[:, j]
        if w.sum() <= 0:
            raise KDInputError(f"neck chain: joint {name!r} has no skinned vertices")
        com = (w @ x) / w.sum()
        d = x - com
        C = (d * w[:, None]).T @ d / w.sum()
        mass = float(masses[name])
        I = 0.6 * mass * (np.trace(C) * np.eye(3) - C) + 0.4 * mass * 0.01**2 * np.eye(3)  # floor: a 1 cm ball
        m.append(mass)
        c.append(com)
        inertia.append(0.5 * (I + I.T))
    crown = x[int(np.argmax(x[:, 1]))]
    return ArticulatedModel(sk, np.array(m), np.array(c), np.array(inertia), name=f"{rig.name} neck chain",
                            torque_limits=np.full((len(sk.names), 3), float(torque_limit_nm)),
                            points={"crown": ("head", crown)})


def arm_chain_model(path=None, *, body_kg: float = 70.0, torque_limit_nm: float = 80.0) -> ArticulatedModel:
    """The MakeHuman right arm (clavicle, upperarm, forearm, hand) from ``meshes/makehuman_arm.npz``, segment masses
    scaled to ``body_kg``; the named point ``fist`` is the middle of the middle finger."""
    p = Path(ARM_PATH if path is None else path)
    if not p.exists():
        raise KDInputError(f"{p}: arm chain not found; run scripts/build_makehuman_arm.py")
    with np.load(p) as d:
        names = tuple(str(n) for n in d["names"])
        pos, parents, ends, fist = d["positions"], d["parents"].astype(np.int64), d["ends"], d["fist"]
    sk = Skeleton(names=names, positions=pos.astype(np.float64), parents=parents, weights=np.zeros((0, len(names))))
    m, c, inertia = [], [], []
    for j, name in enumerate(names):
        frac_m, frac_c, gyr, radius = ARM_SEGMENTS[name]
        mass = frac_m * body_kg / 70.0
        m.append(mass)
        c.append(pos[j] + frac_c * (ends[j] - pos[j]))
        inertia.append(segment_inertia(mass, pos[j], ends[j], radius_m=radius, gyration=gyr))
    return ArticulatedModel(sk, np.array(m), np.array(c), np.array(inertia), name="MakeHuman right arm",
                            torque_limits=np.full((len(names), 3), float(torque_limit_nm)),
                            points={"fist": ("hand", np.asarray(fist, dtype=np.float64))})
