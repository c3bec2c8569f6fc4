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
    (N, P) scipy CSR: each dense vertex of the moving region that is not rigid and not a proxy vertex gets the
    barycentric coordinates of its closest point on a proxy triangle in shape space (rest position and blend-shape
    displacements, :func:`~kdfaces.rig.proxy.embedding_matrix`; three non-negative nonzeros, rows summing to one,
    so a rigid motion of the deviation field — the head turn's lag — is carried exactly); a proxy vertex's row is the
    identity (its dense state is the proxy state itself); rigid vertices (eyes, teeth) and vertices outside the
    moving region get zero rows: they follow x_K exactly.

The dynamics of the proxy keep what matters: the dense model's settle-time map and gains read at the proxy's
vertices, lumped masses Wᵀm (the dense mass it stands for, so the total mass is kept), shape matching on ring
clusters of the proxy's own triangles, and the dense region's diameter (ε of §5.2 is the dense face's).

:class:`ProxyFaceSystem` is a :class:`~kdfaces.dynamics.FaceSystem` on the proxy (its region is the proxy's vertex
subset, so the bake, the kernels and the threads are the face system's own) whose ``observe`` returns the dense
states above; ``FaceSystem(model)`` builds one when ``model.embedding`` is set, so the KD protocol's users (windows,
IKD, the bake, the viewer) work unchanged.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import KDInputError
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
from .system import FaceSystem

__all__ = ["FaceProxy", "build_proxy", "embedding_matrix", "shape_features", "proxy_rig", "ProxyFaceSystem",
           "AUTO_PROXY_VERTICES", "DECIMATE_SHAPE_WEIGHT"]


class ProxyFaceSystem(FaceSystem):
    """A :class:`FaceSystem` on a proxy model (``model.embedding`` set: its region is the proxy's vertices, its
    clusters the proxy's) that observes the dense mesh: x_K + W (x_proxy − x_K,proxy) (module docstring).
    ``FaceSystem(model)`` returns one for such a model; the arguments are :class:`FaceSystem`'s."""

    def __init__(self, model, **kwargs):
        if getattr(model, "embedding", None) is None or model.region is None:
            raise KDInputError("proxy system: expected a FaceModel with a proxy (FaceModel.from_rig(rig, proxy=...))")
        super().__init__(model, **kwargs)
        W = sp.csr_matrix(model.embedding)
        inside = np.zeros(model.num_vertices, dtype=bool)
        inside[model.region] = True
        carried = np.flatnonzero((np.diff(W.indptr) > 0) & ~inside)  # dense rows that move with the proxy
        self._carried = carried.astype(np.int64)
        self._carry = sp.csr_matrix(W[carried])  # (E, P)
        self._deviating = np.union1d(model.region, carried).astype(np.int64)
        self._dense_views = (None, [])  # (trajectory, [(vertex part, its restricted view)]) for observe's threads

    @property
    def proxy_vertices(self) -> np.ndarray:
        """(P,) int64: the dense vertices the proxy simulates (sorted)."""
        return np.asarray(self.model.region, dtype=np.int64)

    def observe(self, state) -> np.ndarray:
        """Dense vertex positions of every member [m], (B, N, 3) float64: the proxy's vertices from the state, the
        carried vertices x_K + W (x_proxy − x_K,proxy), every other vertex x_K (float64, the trajectory's own
        values). One pass of x_K over the N vertices per member (blend + skin; with several threads each evaluates
        a contiguous part of the vertices, the rows of the same evaluation) and one sparse product."""
        self._check(state)
        positions = getattr(self, "_positions", None)  # the state in the region's order, however it is kept
        x = positions(state) if positions is not None else np.concatenate([ch.x.numpy() for ch in state.chunks])
        traj = state.bake.trajectory if state.bake is not None else state.trajectory
        t = state.start_times + state.steps * (state.bake.h if state.bake is not None else 0.0)
        region, carried = self.proxy_vertices, self._carried
        p = len(region)
        out = []
        for i in range(0, len(t), 32):
            xk = self._dense_kinematic(traj, t[i:i + 32])  # x_K of every vertex, (b, N, 3)
            xp = x[i:i + 32].astype(np.float64)
            if len(carried):
                d = xp - xk[:, region]
                b = len(d)
                xk[:, carried] += (self._carry @ d.transpose(1, 0, 2).reshape(p, 3 * b)).reshape(-1, b, 3) \
                    .transpose(1, 0, 2)
            xk[:, region] = xp
            out.append(xk)
        return out[0] if len(out) == 1 else np.concatenate(out)

    def _dense_kinematic(self, trajectory, times: np.ndarray) -> np.ndarray:
        """x_K of every vertex at ``times`` (b,) [s] → (b, N, 3) float64, split over the threads by vertices."""
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
