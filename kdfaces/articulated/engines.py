"""Articulated dynamics from existing engines: MuJoCo (``mujoco``) and Newton (``newton``, built on Warp).

Both get the same model (:class:`~kdfaces.articulated.model.ArticulatedModel`) replicated B times — B independent
worlds advanced by one engine call per step — and take generalized torques on the 3·J hinges; neither contains
any articulated-body algorithm of ours (no home-made solver). The KD windows of a batch are the B worlds.

- :class:`MuJoCoEngine`: one MJCF model holding B copies of the chain (bodies nested as the skeleton, each with
  hinges y, x, z about its pivot, no geometry, no contacts), ``mj_step`` with semi-implicit Euler; the torques go
  to ``qfrc_applied``.
- :class:`NewtonEngine`: a ``ModelBuilder`` chain of D6 joints (angular axes y, x, z) replicated into B worlds,
  ``SolverFeatherstone`` on the Warp CPU device; torques go to ``control.joint_f``.

``ENGINES`` names them; :func:`make_engine` builds one. The benchmark in ``benchmarks/bench_articulated.py``
measures both on the batched neck-chain KD.
"""

from __future__ import annotations

import numpy as np

from ..errors import KDInputError
from .model import ArticulatedModel

__all__ = ["ENGINES", "DEFAULT_ENGINE", "MuJoCoEngine", "NewtonEngine", "make_engine"]

ENGINES = ("mujoco", "newton")
#: The engine kept as a dependency (the faster on the batched neck-chain KD, see BENCHMARKS.md).
DEFAULT_ENGINE = "mujoco"


def _fmt(v) -> str:
    return " ".join(f"{float(x):.12g}" for x in np.ravel(v))


class MuJoCoEngine:
    """B copies of ``model`` in one MuJoCo model; state is (q, q̇), each (B, J, 3) [rad, rad/s]."""

    name = "mujoco"

    def __init__(self, model: ArticulatedModel, batch: int, step_s: float):
        import mujoco

        self.mujoco, self.model, self.batch, self.step_s = mujoco, model, int(batch), float(step_s)
        self.mj = mujoco.MjModel.from_xml_string(self.mjcf())
        self.data = mujoco.MjData(self.mj)
        if self.mj.nv != self.batch * model.dofs:
            raise KDInputError(f"MuJoCo model: {self.mj.nv} DOFs, expected {self.batch * model.dofs}")

    def mjcf(self) -> str:
        """The MJCF text of the replicated chain."""
        m, sk = self.model, self.model.skeleton
        children = {j: [k for k in range(m.num_joints) if sk.parents[k] == j] for j in range(-1, m.num_joints)}

        def body(j: int, b: int) -> str:
            par = sk.parents[j]
            pos = sk.positions[j] - (sk.positions[par] if par >= 0 else 0.0)
            I = m.inertias[j]
            full = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
            inner = "".join(body(k, b) for k in children[j])
            joints = "".join(f'<joint name="w{b}_{sk.names[j]}_{a}" type="hinge" axis="{ax}" damping="0" '
                             f'armature="0" limited="false"/>'
                             for a, ax in (("yaw", "0 1 0"), ("pitch", "1 0 0"), ("roll", "0 0 1")))
            return (f'<body name="w{b}_{sk.names[j]}" pos="{_fmt(pos)}">'
                    f'<inertial pos="{_fmt(m.coms[j] - sk.positions[j])}" mass="{m.masses[j]:.12g}" '
                    f'fullinertia="{_fmt(full)}"/>{joints}{inner}</body>')

        worlds = "".join(body(j, b) for b in range(self.batch) for j in children[-1])
        return (f'<mujoco model="{m.name}"><option timestep="{self.step_s:.12g}" gravity="{_fmt(m.gravity)}" '
                f'integrator="Euler"><flag contact="disable"/></option><worldbody>{worlds}</worldbody></mujoco>')

    def set_state(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Set every world's joint angles and rates, each (B, J, 3)."""
        self.data.qpos[:] = np.asarray(q, dtype=np.float64).ravel()
        self.data.qvel[:] = np.asarray(qd, dtype=np.float64).ravel()
        self.data.qacc_warmstart[:] = 0.0

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, q̇) of every world, each (B, J, 3)."""
        shape = (self.batch, self.model.num_joints, 3)
        return self.data.qpos.reshape(shape).copy(), self.data.qvel.reshape(shape).copy()

    #: joint damping is integrated implicitly (MuJoCo's Euler integrator)
    implicit_damping = True

    def step(self, tau: np.ndarray, damping: np.ndarray | None = None) -> None:
        """Advance every world by one step under hinge torques ``tau`` (B, J, 3) [N·m], with optional joint
        damping ``damping`` (B, J, 3) [N·m·s/rad] that MuJoCo integrates implicitly."""
        self.data.qfrc_applied[:] = np.asarray(tau, dtype=np.float64).ravel()
        if damping is not None:
            self.mj.dof_damping[:] = np.asarray(damping, dtype=np.float64).ravel()
        self.mujoco.mj_step(self.mj, self.data)


class NewtonEngine:
    """B worlds of ``model`` in one Newton model (Featherstone, Warp CPU); state is (q, q̇), each (B, J, 3)."""

    name = "newton"

    def __init__(self, model: ArticulatedModel, batch: int, step_s: float, *, device: str = "cpu"):
        import newton
        import warp as wp

        self.newton, self.wp, self.model, self.batch, self.step_s = newton, wp, model, int(batch), float(step_s)
        sk = model.skeleton
        one = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=tuple(float(g) for g in model.gravity))
        cfg = newton.ModelBuilder.JointDofConfig
        bodies, joints = [], []
        for j in range(model.num_joints):
            par = sk.parents[j]
            b = one.add_link(xform=wp.transform(wp.vec3(*sk.positions[j]), wp.quat_identity()),
                             com=wp.vec3(*(model.coms[j] - sk.positions[j])),
                             inertia=wp.mat33(*model.inertias[j].ravel()), mass=float(model.masses[j]),
                             label=sk.names[j])
            pos = sk.positions[j] - (sk.positions[par] if par >= 0 else 0.0)
            joints.append(one.add_joint_d6(bodies[par] if par >= 0 else -1, b,
                             angular_axes=[cfg(axis=newton.Axis.Y), cfg(axis=newton.Axis.X), cfg(axis=newton.Axis.Z)],
                             parent_xform=wp.transform(wp.vec3(*pos), wp.quat_identity()),
                             child_xform=wp.transform_identity(), label=f"{sk.names[j]}_joint"))
            bodies.append(b)
        one.add_articulation(joints, label=model.name)
        builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=tuple(float(g) for g in model.gravity))
        builder.replicate(one, self.batch)
        self.nm = builder.finalize(device=device)
        self.solver = newton.solvers.SolverFeatherstone(self.nm, angular_damping=0.0)
        self.s0, self.s1 = self.nm.state(), self.nm.state()
        self.control = self.nm.control()
        if self.nm.joint_dof_count != self.batch * model.dofs:
            raise KDInputError(f"Newton model: {self.nm.joint_dof_count} DOFs, expected {self.batch * model.dofs}")

    def set_state(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Set every world's joint angles and rates, each (B, J, 3)."""
        self.s0.joint_q.assign(np.asarray(q, dtype=np.float32).ravel())
        self.s0.joint_qd.assign(np.asarray(qd, dtype=np.float32).ravel())
        self.newton.eval_fk(self.nm, self.s0.joint_q, self.s0.joint_qd, self.s0)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, q̇) of every world, each (B, J, 3)."""
        shape = (self.batch, self.model.num_joints, 3)
        return (self.s0.joint_q.numpy().reshape(shape).astype(np.float64),
                self.s0.joint_qd.numpy().reshape(shape).astype(np.float64))

    #: Featherstone applies joint forces explicitly
    implicit_damping = False

    def step(self, tau: np.ndarray, damping: np.ndarray | None = None) -> None:
        """Advance every world by one step under hinge torques ``tau`` (B, J, 3) [N·m] (explicit; ``damping`` must
        be None)."""
        if damping is not None:
            raise KDInputError("Newton engine: implicit joint damping is not supported; apply it in tau")
        self.control.joint_f.assign(np.asarray(tau, dtype=np.float32).ravel())
        self.solver.step(self.s0, self.s1, self.control, None, self.step_s)
        self.s0, self.s1 = self.s1, self.s0


def make_engine(name: str, model: ArticulatedModel, batch: int, step_s: float):
    """An engine by name (:data:`ENGINES`) for ``batch`` worlds of ``model`` stepping ``step_s`` [s]."""
    if name == "mujoco":
        return MuJoCoEngine(model, batch, step_s)
    if name == "newton":
        try:
            return NewtonEngine(model, batch, step_s)
        except ImportError as e:
            raise KDInputError(f"engine 'newton': not installed ({e}); pip install newton, or use 'mujoco'") from None
    raise KDInputError(f"engine {name!r} unknown; expected one of {ENGINES}")
