"""The hat as a KD system (paper §3, §4.4): the protocol of :mod:`kdfaces.kd` for an attached FEM object.

Initial state at a window start t₀: the hat's **static equilibrium under gravity in the head's rest pose**
(computed once), carried rigidly by the head joint's transform G(t₀), with the head's rigid velocity
v = Ġ(t₀)·X_eq. It is exactly in equilibrium when the head's rotation leaves gravity's direction in the head frame
unchanged (yaw), and close to it for moderate pitch/roll; starting from the sagged shape (not the stress-free
rest shape) keeps the window from having to absorb the gravity sag transient.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.tetmesh import Embedding
from .attachment import head_motion
from .integrator import FEMState, ImplicitEuler, apply_frame, static_equilibrium
from .model import FEMModel

__all__ = ["HatSystem"]


@dataclass
class HatSystem:
    """A :class:`FEMModel` attached to the head joint of a face rig, as a KD system.

    ``tol`` [m]: Newton tolerance on the position update; ``threads``: batch members stepped in parallel threads.
    ``trajectory`` arguments of the protocol methods are a :class:`kdfaces.motion.trajectory.KinematicTrajectory` of a
    rig with a skeleton (or a :class:`kdfem.fem.attachment.HeadMotion`). ``observe`` returns node positions
    (B, N, 3) [m]; :meth:`surface` maps them to the embedded render surface.
    """

    model: FEMModel
    embedding: Embedding | None = None
    tol: float = 1e-6
    threads: int = 1

    def __post_init__(self):
        self.rest_equilibrium = static_equilibrium(self.model)  # (N, 3) [m], head in its rest pose
        self._steppers: dict[float, ImplicitEuler] = {}

    def stepper(self, h: float) -> ImplicitEuler:
        """The implicit-Euler stepper for step ``h`` [s] (its Newton matrix factored once and cached)."""
        key = round(float(h), 12)
        if key not in self._steppers:
            self._steppers[key] = ImplicitEuler(self.model, h, tol=self.tol, threads=self.threads)
        return self._steppers[key]

    def rigid(self, trajectory, times) -> np.ndarray:
        """The kinematic (rigidly carried) hat at ``times`` (T,) [s] → (T, N, 3) [m]."""
        G, _, _ = head_motion(trajectory).transforms(times)
        return apply_frame(G, self.rest_equilibrium)

    def initial_state(self, trajectory, times: np.ndarray) -> FEMState:
        G, dG, _ = head_motion(trajectory).transforms(times)
        x = apply_frame(G, self.rest_equilibrium)
        v = apply_frame(dG, self.rest_equilibrium)  # Ġ·X: rotation rate times X plus translation rate
        return FEMState(x=x, v=v)

    def step(self, state: FEMState, trajectory, times: np.ndarray, h: float) -> None:
        G1, dG1, _ = head_motion(trajectory).transforms(np.asarray(times, dtype=np.float64) + h)
        self.stepper(h).step(state, G1, dG1)

    def observe(self, state: FEMState) -> np.ndarray:
        return state.x.copy()

    def surface(self, x: np.ndarray) -> np.ndarray:
        """Render-surface positions (..., V, 3) [m] from node positions (..., N, 3) (needs ``embedding``)."""
        if self.embedding is None:
            return x
        return self.embedding.apply(self.model.mesh, x)
