"""Articulated dynamics from existing engines: MuJoCo (``mujoco``) and Newton (``newton``, built on Warp).

Both get the same model (:class:`~kdfaces.articulated.model.ArticulatedModel`) replicated B times — B independent
worlds advanced by one engine call per step — and take generalized torques on the 3·J hinges; neither contains
any articulated-body algorithm of ours (no home-made solver). The KD windows of a batch are the B worlds.

- :class:`MuJoCoEngine`: one MJCF model holding B copies of the chain (bodies nested as the skeleton, each with
  hinges y, x, z about its pivot, no geometry, no contacts), ``mj_step`` with semi-implicit Euler; the torques go
  to ``qfrc_applied``. Built for a controller (``controller=``), it also runs On the Beat control in its own loop
  (:meth:`MuJoCoEngine.track`): everything that depends on the pose comes from MuJoCo's C pipeline each step.
- :class:`NewtonEngine`: a ``ModelBuilder`` chain of D6 joints (angular axes y, x, z) replicated into B worlds,
  ``SolverFeatherstone`` on the Warp CPU device; torques go to ``control.joint_f``.

``ENGINES`` names them; :func:`make_engine` builds one. The benchmark in ``benchmarks/bench_articulated.py``
measures both on the batched neck-chain KD.
"""

from __future__ import annotations

import contextlib

import numpy as np

from ..errors import KDInputError, SimulationBlowUpError
from .model import ArticulatedModel

__all__ = ["ENGINES", "DEFAULT_ENGINE", "MuJoCoEngine", "NewtonEngine", "make_engine"]

ENGINES = ("mujoco", "newton")
#: The engine kept as a dependency (the faster on the batched neck-chain KD, see BENCHMARKS.md).
DEFAULT_ENGINE = "mujoco"


def _fmt(v) -> str:
    return " ".join(f"{float(x):.12g}" for x in np.ravel(v))


class MuJoCoEngine:
    """B copies of ``model`` in one MuJoCo model; state is (q, q̇), each (B, J, 3) [rad, rad/s].

    With ``controller`` (an :class:`~kdfaces.articulated.OnTheBeat` of the same model) the model also carries what
    :meth:`track` needs: one motor per hinge, MuJoCo's gravity compensation (``gravcomp`` on every body, routed
    through the joints' actuators with ``actuatorgravcomp``) when the controller compensates gravity, and the
    torque limits as the joints' ``actuatorfrcrange``, which MuJoCo applies to the sum of control torque and
    gravity compensation, as :meth:`OnTheBeat.torques` clips it. Such an engine steps by :meth:`track` only."""

    name = "mujoco"

    def __init__(self, model: ArticulatedModel, batch: int, step_s: float, *, controller=None):
        import mujoco

        self.mujoco, self.model, self.batch, self.step_s = mujoco, model, int(batch), float(step_s)
        if controller is not None and controller.model is not model:
            raise KDInputError("MuJoCo engine: the controller drives another articulated model")
        self.controller = controller
        self.mj = mujoco.MjModel.from_xml_string(self.mjcf())
        self.data = mujoco.MjData(self.mj)
        if self.mj.nv != self.batch * model.dofs:
            raise KDInputError(f"MuJoCo model: {self.mj.nv} DOFs, expected {self.batch * model.dofs}")
        if controller is not None:
            m, D = self.mj, self.mj.nv
            self._diag = m.M_rowadr + m.M_rownnz - 1  # the diagonal of the sparse joint-space inertia M
            if (self._diag < 0).any() or m.nu != D or not np.array_equal(m.actuator_trnid[:, 0], np.arange(D)):
                raise KDInputError("MuJoCo engine: unexpected layout of the control model")
            self._body = m.jnt_bodyid[m.dof_jntid]  # each hinge's link
            self._limits = np.tile(model.torque_limits.ravel(), self.batch)
            self._limited = np.isfinite(self._limits).any()
            if controller.exact_coupling:
                self._inboard_layout()

    def _inboard_layout(self) -> None:
        """Where the joint-space inertia's in-board entries M_hg (g in-board of h) lie in MuJoCo's sparse M: row h
        (CSR, lower triangle) holds the columns of h's ancestor DOFs, then the diagonal. ``_inb_src`` indexes
        ``data.M``, ``_inb_dst`` the flat (B, D, D) matrix that :meth:`OnTheBeat.hinge_torques` takes; the columns
        must be exactly the controller's in-board hinges (eq. 8)."""
        m, B, D = self.mj, self.batch, self.model.dofs
        src, dst = [], []
        for i in range(m.nv):
            b, h = divmod(i, D)
            for k in range(m.M_rowadr[i], m.M_rowadr[i] + m.M_rownnz[i] - 1):
                g = int(m.M_colind[k]) - b * D
                if not 0 <= g < D:
                    raise KDInputError("MuJoCo engine: joint-space inertia couples two worlds")
                src.append(k)
                dst.append((b * D + h) * D + g)
        self._inb_src, self._inb_dst = np.array(src, dtype=np.int64), np.array(dst, dtype=np.int64)
        mask = np.zeros(B * D * D)
        mask[self._inb_dst] = 1.0
        if not np.array_equal(mask.reshape(B, D, D), np.broadcast_to(self.model.inboard_hinges(), (B, D, D))):
            raise KDInputError("MuJoCo engine: the joint-space inertia's in-board entries are not the chain's "
                               "in-board hinges")
        self._inb = np.zeros((B, D, D))

    def inboard_inertia(self) -> np.ndarray:
        """The in-board entries M_hg (B, D, D) [kg·m²] of MuJoCo's joint-space inertia at the current position
        stage (after ``mj_step1`` or ``mj_forward``; zero where g is not in-board of h): the coupling of
        ``OnTheBeat(coupling="exact")``, read from ``data.M`` (the sparse ``qM``)."""
        if getattr(self, "_inb_src", None) is None:
            self._inboard_layout()
        self._inb.reshape(-1)[self._inb_dst] = self.data.M[self._inb_src]
        return self._inb

    def mjcf(self) -> str:
        """The MJCF text of the replicated chain."""
        m, sk = self.model, self.model.skeleton
        children = {j: [k for k in range(m.num_joints) if sk.parents[k] == j] for j in range(-1, m.num_joints)}

        ctrl = self.controller
        axes = (("yaw", "0 1 0"), ("pitch", "1 0 0"), ("roll", "0 0 1"))
        gravcomp = ' gravcomp="1"' if ctrl is not None and ctrl.gravity_compensation else ""

        def joint(b: int, j: int, c: int) -> str:
            a, ax = axes[c]
            extra = ""
            if ctrl is not None:
                lim = m.torque_limits[j, c]
                extra = ' actuatorgravcomp="true"' + (f' actuatorfrclimited="true" actuatorfrcrange="{-lim:.17g} '
                                                      f'{lim:.17g}"' if np.isfinite(lim) else "")
            return (f'<joint name="w{b}_{sk.names[j]}_{a}" type="hinge" axis="{ax}" damping="0" armature="0" '
                    f'limited="false"{extra}/>')

        def body(j: int, b: int) -> str:
            par = sk.parents[j]
            pos = sk.positions[j] - (sk.positions[par] if par >= 0 else 0.0)
            I = m.inertias[j]
            full = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
            inner = "".join(body(k, b) for k in children[j])
            joints = "".join(joint(b, j, c) for c in range(3))
            return (f'<body name="w{b}_{sk.names[j]}" pos="{_fmt(pos)}"{gravcomp}>'
                    f'<inertial pos="{_fmt(m.coms[j] - sk.positions[j])}" mass="{m.masses[j]:.12g}" '
                    f'fullinertia="{_fmt(full)}"/>{joints}{inner}</body>')

        worlds = "".join(body(j, b) for b in range(self.batch) for j in children[-1])
        motors = ""
        if ctrl is not None:  # one motor per hinge, in DOF order (worlds, joints in skeleton order, y x z)
            motors = "<actuator>" + "".join(f'<motor joint="w{b}_{sk.names[j]}_{a}" gear="1"/>'
                                            for b in range(self.batch) for j in range(m.num_joints)
                                            for a, _ in axes) + "</actuator>"
        return (f'<mujoco model="{m.name}"><option timestep="{self.step_s:.12g}" gravity="{_fmt(m.gravity)}" '
                f'integrator="Euler"><flag contact="disable"/></option><worldbody>{worlds}</worldbody>{motors}'
                '</mujoco>')

    @contextlib.contextmanager
    def _watched(self, what: str):
        """Run MuJoCo steps with its warnings captured (MuJoCo's own handler would print them and append to
        MUJOCO_LOG.TXT in the working folder; the previous handler is restored after) and raise
        :class:`~kdfaces.errors.SimulationBlowUpError` when a step went unstable (MuJoCo then silently resets the
        state, which must never reach a KD result)."""
        mujoco = self.mujoco
        bad = int(mujoco.mjtWarning.mjWARN_BADQACC)
        before = int(self.data.warning[bad].number)
        messages: list[str] = []
        previous = mujoco.get_mju_user_warning()
        mujoco.set_mju_user_warning(messages.append)
        try:
            yield
        finally:
            mujoco.set_mju_user_warning(previous)
        if int(self.data.warning[bad].number) > before:
            first = messages[0] if messages else "NaN, Inf or huge acceleration"
            raise SimulationBlowUpError(f"articulated simulation ({what}, MuJoCo, step {self.step_s:g} s) went "
                                        f"unstable: {first} Use a smaller substep, or turn off parent-torque "
                                        "compensation on chains with a heavy end (e.g. the neck under the head)")

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
        if self.controller is not None:
            raise KDInputError("MuJoCo engine: built for a controller (gravity compensation and torque limits in "
                               "the model), it steps by track(); build one without controller= for step()")
        self.data.qfrc_applied[:] = np.asarray(tau, dtype=np.float64).ravel()
        if damping is not None:
            self.mj.dof_damping[:] = np.asarray(damping, dtype=np.float64).ravel()
        with self._watched("step"):
            self.mujoco.mj_step(self.mj, self.data)

    def track(self, targets, rates, settle_s, *, record=None, record_rates=None) -> None:
        """Advance every world ``len(targets)`` steps under the engine's On the Beat controller, step k pulling
        towards (θ̂, ω̂) = (``targets[k]``, ``rates[k]``), each (steps, B, J, 3) [rad, rad/s] (broadcast), in the
        time ``settle_s`` [s] (scalar, (J, 3) or (B, J, 3)); the angles (rates) after every step are written to
        ``record`` (``record_rates``), (steps, B, J, 3), when given.

        Each step splits MuJoCo's ``mj_step`` around the control (``mj_step1``, the torques, ``mj_step2``): the
        position stage computes the hinge axes (``xaxis``), the composite moments about them (the diagonal of the
        joint-space inertia M from the composite-rigid-body algorithm, equal to eq. 7) and the gravity
        compensation (``qfrc_gravcomp``) in C; :meth:`OnTheBeat.hinge_torques` adds eq. 4 and the parent-torque
        compensation of eq. 8–10 (a product with the 3J × 3J in-board coupling, the only per-step work left in NumPy; a
        pose-dependent gain and a coupling between hinges that no MuJoCo actuator expresses; with
        ``coupling="exact"`` the coupling is M's in-board entries, read from ``data.M``); the motors apply it,
        MuJoCo adds the gravity compensation and clamps the sum to the torque limits, and integrates the damping
        k_d implicitly. Same torques as :meth:`OnTheBeat.torques` with ``split_damping`` and :meth:`step`."""
        ctrl = self.controller
        if ctrl is None:
            raise KDInputError("MuJoCo engine: track() needs an engine built with controller=")
        m, d = self.mj, self.data
        B, D = self.batch, self.model.dofs
        shape = (B, self.model.num_joints, 3)
        targets = np.asarray(targets, dtype=np.float64)
        steps = len(targets)
        tq = np.broadcast_to(targets, (steps, *shape)).reshape(steps, B, D)
        tqd = np.broadcast_to(np.asarray(rates, dtype=np.float64), (steps, *shape)).reshape(steps, B, D)
        lam = ctrl.lambdas(settle_s, shape)
        local = ctrl.inertia == "local"
        q, qd = d.qpos.reshape(B, D), d.qvel.reshape(B, D)  # views into MjData
        axes = d.xaxis.reshape(B, D, 3)
        applied, damping, motors = d.qfrc_applied.reshape(B, D), m.dof_damping.reshape(B, D), d.ctrl.reshape(B, D)
        damper = d.qfrc_damper.reshape(B, D)
        with self._watched("On the Beat tracking"):
            self._track(steps, tq, tqd, lam, local, shape, q, qd, axes, applied, damping, motors, damper, record,
                        record_rates)

    def _track(self, steps, tq, tqd, lam, local, shape, q, qd, axes, applied, damping, motors, damper, record,
               record_rates) -> None:
        mujoco, m, d, ctrl = self.mujoco, self.mj, self.data, self.controller
        B, D = self.batch, self.model.dofs
        exact = ctrl.exact_coupling
        for k in range(steps):
            mujoco.mj_step1(m, d)
            moments = (self._local_moments() if local else d.M[self._diag]).reshape(B, D)
            inboard = self.inboard_inertia() if exact else None
            tau, kd = ctrl.hinge_torques(moments, axes, q, qd, tq[k], tqd[k], lam, inboard=inboard)
            motors[:] = tau
            # τ holds the damping −k_d·ω explicitly; mj_step1 already added the joints' damping at the previous
            # gains, −k_d'·ω (qfrc_damper): cancel it, and let the integrator apply −k_d·(ω_new − ω) implicitly
            # with the new gains, so the step sees −k_d·ω_new as in OnTheBeat.torques(split_damping=True)
            np.negative(damper, out=applied)
            damping[:] = kd
            mujoco.mj_step2(m, d)
            if self._limited:
                ctrl.clipped += int(np.count_nonzero(np.abs(d.qfrc_actuator) >= self._limits))
            if record is not None:
                record[k] = q.reshape(shape)
            if record_rates is not None:
                record_rates[k] = qd.reshape(shape)

    def _local_moments(self) -> np.ndarray:
        """Each hinge's moment about its axis of its own link only (On the Beat §6's "local" gains) from MuJoCo's
        link frames: s·I s + m‖(c − d) × s‖², I the link's inertia about its centre of mass c, d the pivot."""
        m, d, b = self.mj, self.data, self._body
        s = d.xaxis
        sR = np.einsum("ni,nij->nj", s, d.ximat[b].reshape(-1, 3, 3))  # s in the link's principal axes
        arm = np.cross(d.xipos[b] - d.xanchor[m.dof_jntid], s)
        return np.einsum("nj,nj->n", sR * sR, m.body_inertia[b]) + m.body_mass[b] * np.einsum("ni,ni->n", arm, arm)


class NewtonEngine:
    """B worlds of ``model`` in one Newton model (Featherstone, Warp CPU); state is (q, q̇), each (B, J, 3)."""

    name = "newton"

    def __init__(self, model: ArticulatedModel, batch: int, step_s: float, *, device: str = "cpu", controller=None):
        import newton
        import warp as wp

        self.newton, self.wp, self.model, self.batch, self.step_s = newton, wp, model, int(batch), float(step_s)
        self.controller = controller
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

    def track(self, targets, rates, settle_s, *, record=None, record_rates=None) -> None:
        """:meth:`MuJoCoEngine.track` with the controller's reference torques (:meth:`OnTheBeat.torques`, every
        term in NumPy) applied explicitly each step."""
        if self.controller is None:
            raise KDInputError("Newton engine: track() needs an engine built with controller=")
        shape = (self.batch, self.model.num_joints, 3)
        targets = np.asarray(targets, dtype=np.float64)
        tq = np.broadcast_to(targets, (len(targets), *shape))
        tqd = np.broadcast_to(np.asarray(rates, dtype=np.float64), tq.shape)
        for k in range(len(tq)):
            q, qd = self.state()
            self.step(self.controller.torques(q, qd, tq[k], tqd[k], settle_s))
            if record is not None or record_rates is not None:
                q, qd = self.state()
                if record is not None:
                    record[k] = q
                if record_rates is not None:
                    record_rates[k] = qd


def make_engine(name: str, model: ArticulatedModel, batch: int, step_s: float, *, controller=None):
    """An engine by name (:data:`ENGINES`) for ``batch`` worlds of ``model`` stepping ``step_s`` [s]; with
    ``controller`` (an :class:`~kdfaces.articulated.OnTheBeat`) it can :meth:`~MuJoCoEngine.track` targets."""
    if name == "mujoco":
        return MuJoCoEngine(model, batch, step_s, controller=controller)
    if name == "newton":
        try:
            return NewtonEngine(model, batch, step_s, controller=controller)
        except ImportError as e:
            raise KDInputError(f"engine 'newton': not installed ({e}); pip install newton, or use 'mujoco'") from None
    raise KDInputError(f"engine {name!r} unknown; expected one of {ENGINES}")
