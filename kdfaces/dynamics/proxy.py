"""Face KD on a proxy, the dense mesh embedded (issue #29).

A production face rig has 20k–100k vertices; its dynamics (paper §4.5: per-vertex PD tracking plus shape matching)
vary smoothly over the skin, so they are simulated on a *proxy* of a few thousand of its vertices and the dense mesh
is carried along:

    x_dense(t) = x_K,dense(t) + W (x_proxy(t) − x_K,proxy(t))

The proxy
    is a subset of the dense rig's vertices (sorted indices ``vertices`` (P,)), picked by edge-collapse decimation
    of the moving region's non-rigid surface (libigl ``decimate``: shortest edge first) with every surviving vertex
    snapped back to the dense vertex it was born from, and the decimated triangles as its own connectivity. Because
    the proxy's vertices *are* dense vertices, its kinematic trajectory is the dense trajectory's rows
    (:func:`~kdfaces.motion.trajectory.restrict_trajectory`): the same blend + skin values, and a corrected
    trajectory (IKD's x_K + f on dense vertices) reaches the proxy with no extra mapping.
W
    (N, P) scipy CSR, rows summing to one (a uniform deviation is carried exactly): a proxy vertex's row starts
    as the identity (its dense state the proxy state itself); rigid vertices (eyes, teeth) and vertices outside the
    moving region get zero rows: they follow x_K exactly; every other vertex of the moving region starts from the
    barycentric coordinates of its closest point on a proxy triangle in shape space (rest position, blend-shape
    displacements and the settle-time map, :func:`~kdfaces.rig.proxy.embedding_matrix`; three non-negative
    nonzeros). By default every nonzero row, the proxy's own included, is then fitted to the dense and proxy KD
    states of an excitation take (:mod:`kdfaces.dynamics.proxy_fit`; twenty weights, some negative), which
    halves the largest error.

The dynamics of the proxy keep what matters: the dense model's settle-time map and gains read at the proxy's
vertices, lumped masses (the dense mass each stands for, so the total mass is kept), shape matching (Müller et al.
2005) on the dense model's own clusters restricted to the proxy's vertices (those keeping three or more; a proxy
vertex none of them holds tracks x_K by PD alone: ``kdfaces.dynamics.model._proxy_clusters``), and the dense
region's diameter (ε of §5.2 is the dense face's).

:class:`ProxyFaceSystem` is a :class:`~kdfaces.dynamics.FaceSystem` on the proxy (its region is the proxy's vertex
subset, so the bake, the kernels and the threads are the face system's own) whose ``observe`` returns the dense
states above; ``FaceSystem(model)`` builds one when ``model.embedding`` is set, so the KD protocol's users (windows,
IKD, the bake, the viewer) work unchanged.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import warp as wp

from ..errors import KDInputError
from ..motion.pose import PoseSampler, pose_base
from ..motion.trajectory import restrict_trajectory, scan_trajectory
from ..rig.proxy import (
    AUTO_PROXY_VERTICES,
    DECIMATE_SHAPE_WEIGHT,
    FaceProxy,
    build_proxy,
    embedding_matrix,
    proxy_rig,
    shape_features,
)
from .carry import CARRY_BLOCK_ROWS, carry_kernel, padded_rows
from .system import FaceSystem

__all__ = ["FaceProxy", "build_proxy", "embedding_matrix", "shape_features", "proxy_rig", "ProxyFaceSystem",
           "AUTO_PROXY_VERTICES", "DECIMATE_SHAPE_WEIGHT"]


class ProxyFaceSystem(FaceSystem):
    """A :class:`FaceSystem` on a proxy model (``model.embedding`` set: its region is the proxy's vertices, its
    clusters the proxy's) that observes the dense mesh: x_K + W (x_proxy − x_K,proxy) (module docstring).
    ``FaceSystem(model)`` returns one for such a model; the arguments are :class:`FaceSystem`'s.

    The dense x_K comes from :class:`~kdfaces.motion.pose.PoseSampler` (the rig's sparse shapes and skin in one
    Warp kernel) for a kinematic trajectory of the rig and IKD's corrections of one, else from the trajectory
    itself. A single state with two threads or more (the scrub path) steps on the calling thread while a worker
    computes the dense x_K at the state's end time (it does not depend on the steps); a batch steps on every
    thread (split by members), then splits the dense x_K and the embedding by vertices."""

    split_one_state = False  # one state: its steps on one thread, the dense pose on another

    def __init__(self, model, **kwargs):
        if getattr(model, "embedding", None) is None or model.region is None:
            raise KDInputError("proxy system: expected a FaceModel with a proxy (FaceModel.from_rig(rig, proxy=...))")
        super().__init__(model, **kwargs)
        W = sp.csr_matrix(model.embedding)
        W.sort_indices()
        region = np.asarray(model.region, dtype=np.int64)
        # a proxy vertex whose row is the identity (W's prior) is the proxy's state itself; every other row with
        # nonzeros (the carried vertices, and proxy vertices whose rows are fitted) is x_K + W (x_proxy − x_K,proxy)
        own = W[region]  # (P, P): row j is proxy vertex j's
        self._identity = (np.diff(own.indptr) == 1) & (own.diagonal() == 1.0)
        fixed = np.zeros(model.num_vertices, dtype=bool)
        fixed[region[self._identity]] = True
        carried = np.flatnonzero((np.diff(W.indptr) > 0) & ~fixed)
        self._carried = carried.astype(np.int64)
        cols, vals = padded_rows(W[carried])  # (E, width): the carried rows of W at a fixed width
        self._deviating = np.union1d(model.region, carried).astype(np.int64)
        d = self.device
        narrow = len(region) <= np.iinfo(np.uint16).max + 1
        self._carry_kernel = carry_kernel(cols.shape[1], narrow)
        wp.load_module(self._carry_kernel.module, device=d)  # here, not on the first launch from two threads
        self._carry = (wp.array(self._carried.astype(np.int32), dtype=wp.int32, device=d),
                       wp.array(cols.astype(np.uint16 if narrow else np.int32), dtype=wp.uint16 if narrow else wp.int32,
                                device=d),
                       wp.array(vals.astype(np.float32), dtype=wp.float32, device=d))
        self._sampler = None  # the PoseSampler of the last rig observed
        self._dense_views = (None, [])  # (trajectory, [(vertex part, its restricted view)]): the generic x_K

    @property
    def proxy_vertices(self) -> np.ndarray:
        """(P,) int64: the dense vertices the proxy simulates (sorted)."""
        return np.asarray(self.model.region, dtype=np.int64)

    def run_windows(self, trajectory, t0, n: int, step_s: float, progress=None) -> np.ndarray:
        """The KD protocol's batch (:func:`~kdfaces.kd.step_windows`), with a single state's dense x_K computed on
        a worker while the calling thread steps it (class docstring); the same values as without the overlap."""
        from ..kd import step_states, step_windows

        t0 = np.atleast_1d(np.asarray(t0, dtype=np.float64))
        sampler = self._pose_sampler(trajectory)
        if self._workers is None or len(t0) != 1 or n == 0 or sampler is None:
            return step_windows(self, trajectory, t0, n, step_s, progress)
        times = t0 + n * step_s
        xk = np.empty((1, self.model.num_vertices, 3))
        pose = sampler.launch(trajectory, times, xk)[0]  # host inputs now: the worker then runs the kernel only
        box = []
        self._workers.run([lambda: box.append(step_states(self, trajectory, t0, n, step_s, progress)), pose])
        return self._observe(box[0], (trajectory, times, xk))

    def observe(self, state) -> np.ndarray:
        """Dense vertex positions of every member [m], (B, N, 3) float64: the carried vertices (and proxy
        vertices whose rows W fits) x_K + W (x_proxy − x_K,proxy), proxy vertices with identity rows the state
        itself, every other vertex x_K (float64). One pass of x_K over
        the N vertices per member and one pass over the carried vertices' rows of W, each split over the threads
        by vertices (every vertex's arithmetic is the same however it is split)."""
        return self._observe(state, None)

    def _observe(self, state, kinematic) -> np.ndarray:
        """:meth:`observe`, with ``kinematic`` = (trajectory, times, x_K (1, N, 3)) computed beforehand (used when
        they are the state's trajectory and times, else computed here)."""
        self._check(state)
        positions = getattr(self, "_positions", None)  # the state in the region's order, however it is kept
        x = positions(state) if positions is not None else np.concatenate([ch.x.numpy() for ch in state.chunks])
        traj = state.bake.trajectory if state.bake is not None else state.trajectory
        t = state.start_times + state.steps * (state.bake.h if state.bake is not None else 0.0)
        region = self.proxy_vertices
        out = []
        for i in range(0, len(t), 32):
            if kinematic is not None and kinematic[0] is traj and np.array_equal(kinematic[1], t[i:i + 32]):
                xk = kinematic[2]
            else:
                xk = self._dense_kinematic(traj, t[i:i + 32])  # x_K of every vertex, (b, N, 3)
            xp = x[i:i + 32].astype(np.float64)
            if len(self._carried):
                self._embed(xp - xk[:, region], xk)
            xk[:, region[self._identity]] = xp[:, self._identity]
            out.append(xk)
        return out[0] if len(out) == 1 else np.concatenate(out)

    def _parts(self, runs) -> None:
        """Run the callables ``runs`` on the threads (one each), or in turn on this one."""
        if len(runs) > 1 and self._workers is not None:
            self._workers.run(runs)
        else:
            for run in runs:
                run()

    def _embed(self, deviation: np.ndarray, xk: np.ndarray) -> None:
        """Carried rows of ``xk`` (b, N, 3) float64 (x_K) += W ``deviation`` (b, P, 3) [m] (x_proxy − x_K,proxy)."""
        d = self.device
        dev_w = wp.array(deviation.astype(np.float32), dtype=wp.vec3, device=d)
        xk_w = wp.array(xk, dtype=wp.vec3d, device=d, copy=False) if d.is_cpu else wp.array(xk, dtype=wp.vec3d,
                                                                                             device=d)
        blocks = -(-len(self._carried) // CARRY_BLOCK_ROWS)
        bounds = np.linspace(0, blocks, self.threads + 1).astype(np.int64)

        def part(lo: int, hi: int):  # blocks lo..hi-1 of CARRY_BLOCK_ROWS rows
            def run():
                if hi > lo:
                    wp.launch(self._carry_kernel, dim=hi - lo, inputs=[lo * CARRY_BLOCK_ROWS, *self._carry, dev_w,
                                                                       xk_w], device=d)
            return run

        self._parts([part(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])])
        if not d.is_cpu:
            xk[:] = xk_w.numpy()

    def _pose_sampler(self, trajectory):
        """The :class:`PoseSampler` of ``trajectory``'s rig when it evaluates it (kept for the next call), else
        None."""
        chain = pose_base(trajectory)
        if chain is None or chain[0].rig.num_vertices != self.model.num_vertices:
            return None
        rig = chain[0].rig
        if self._sampler is None or self._sampler.rig is not rig:
            self._sampler = PoseSampler(rig, self.device)
        return self._sampler

    def _dense_kinematic(self, trajectory, times: np.ndarray) -> np.ndarray:
        """x_K of every vertex at ``times`` (b,) [s] → (b, N, 3) float64, split over the threads by vertices."""
        sampler = self._pose_sampler(trajectory)
        if sampler is not None:
            out = np.empty((len(times), self.model.num_vertices, 3))
            self._parts(sampler.launch(trajectory, times, out, self.threads if self._workers is not None else 1))
            return out
        workers = getattr(self, "_workers", None)
        if workers is None or self.threads < 2:
            return np.array(scan_trajectory(trajectory, times, 0)[0])
        if self._dense_views[0] is not trajectory:
            parts = np.array_split(np.arange(self.model.num_vertices), self.threads)
            self._dense_views = (trajectory, [(q, restrict_trajectory(trajectory, q)) for q in parts])
        out = np.empty((len(times), self.model.num_vertices, 3))

        def task(q, view):
            def run():
                out[:, q[0]:q[-1] + 1] = scan_trajectory(view, times, 0)[0]
            return run

        workers.run([task(q, view) for q, view in self._dense_views[1]])
        return out

    def simulated_kinematic(self, trajectory, times):
        """``(rows, x)``: the dense vertices whose state differs from x_K (the proxy's and the carried ones) (S,)
        int64, and x_K there at ``times`` (T,) [s], (T, S, 3) [m] (see :meth:`FaceSystem.simulated_kinematic`)."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        rows = self._deviating
        return rows, scan_trajectory(restrict_trajectory(trajectory, rows), t, 0)[0]


FaceSystem.proxy_system = ProxyFaceSystem
