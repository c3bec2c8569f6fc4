"""The kinematic pose x_K of every vertex of a dense rig in one Warp kernel (issue #29: the dense sample a proxy face
observes costs its shapes' nonzeros, not K × N).

A :class:`KinematicTrajectory` evaluates x_K with derivatives in numpy: a dense (T, K) × (K, 3N) product of the
shape weights with every shape's full delta array, then linear blend skinning. A face's shapes are sparse — on the
default head Loop-subdivided twice (75k vertices, 52 shapes) 24 % of the (shape, vertex) deltas are nonzero, and
most shapes move a tenth of the face — and a proxy face (:mod:`kdfaces.dynamics.proxy`) needs only the positions.
:class:`PoseSampler` holds each vertex's nonzero deltas (CSR by vertex, float32 as the rig stores them) and skin
weights, and one kernel per (vertex, time) evaluates the same formulas as the trajectory:

    y_i = x0_i + Σ_k w_k Δ_k,i                                  (blend shapes)
    x_i = Σ_j w_ij (R_j y_i + t_j) + (1 − Σ_j w_ij) y_i + r     (LBS, :func:`~kdfaces.rig.skeleton.skin`; root r)

in float64 (the float32 deltas widen exactly, as the trajectory's float64 copy of them does), from the inputs the
trajectory itself computes (:meth:`KinematicTrajectory.pose_inputs`: weights through in-betweens, joint
transforms, root motion). Only the order of the sums differs, so the two agree to float64 round-off (~1e-16 m).
A :class:`~kdfaces.ikd.corrections.CorrectedTrajectory` (IKD's x_K + f) is its base's pose plus f; any other
trajectory is evaluated by the trajectory itself (:meth:`PoseSampler.supports` says which).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import warp as wp

__all__ = ["PoseSampler", "pose_positions", "pose_base"]

wp.set_module_options({"enable_backward": False})


@wp.kernel
def pose_positions(
    lo: int,
    neutral: wp.array(dtype=wp.vec3d),
    shape_start: wp.array(dtype=wp.int32),
    shape_id: wp.array(dtype=wp.int32),
    shape_delta: wp.array(dtype=wp.vec3),
    weights: wp.array2d(dtype=wp.float64),
    skin_start: wp.array(dtype=wp.int32),
    skin_joint: wp.array(dtype=wp.int32),
    skin_weight: wp.array(dtype=wp.float64),
    rot: wp.array2d(dtype=wp.mat33d),
    trans: wp.array2d(dtype=wp.vec3d),
    root: wp.array(dtype=wp.vec3d),
    out: wp.array2d(dtype=wp.vec3d),
):
    """x_K of vertex ``lo + k`` at every time (a vertex's deltas are read from memory once, then from cache for
    the further times): blend shapes, LBS and root motion (module docstring)."""
    i = lo + wp.tid()
    s0 = shape_start[i]
    s1 = shape_start[i + 1]
    e = skin_start[i]
    f = skin_start[i + 1]
    for t in range(weights.shape[0]):
        y = neutral[i]
        for s in range(s0, s1):
            d = shape_delta[s]
            y = y + weights[t, shape_id[s]] * wp.vec3d(wp.float64(d[0]), wp.float64(d[1]), wp.float64(d[2]))
        x = y
        if f > e:
            acc = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
            total = wp.float64(0.0)
            for s in range(e, f):
                j = skin_joint[s]
                w = skin_weight[s]
                acc = acc + w * (rot[t, j] * y + trans[t, j])
                total = total + w
            x = acc + (wp.float64(1.0) - total) * y
        out[t, i] = x + root[t]


class PoseSampler:
    """x_K of every vertex of ``rig`` (a :class:`~kdfaces.rig.BlendshapeRig`, N vertices) from its sparse shapes
    and skin, on Warp ``device`` (module docstring). Holds the rig's nonzero deltas (float32) and skin weights
    there: about 16 bytes per nonzero (shape, vertex) pair."""

    def __init__(self, rig, device=None):
        self.rig = rig
        self.device = wp.get_device(device)
        d = np.asarray(rig.deltas, dtype=np.float32)  # (K, N, 3)
        n = rig.num_vertices
        nz = (d != 0).any(axis=2)  # (K, N): the pairs a shape moves
        by_vertex = sp.csr_matrix(nz.T.astype(np.int8))  # (N, K): each vertex's shapes, in shape order
        shape_id = by_vertex.indices.astype(np.int32)
        rows = np.repeat(np.arange(n), np.diff(by_vertex.indptr))
        dev = self.device
        self._neutral = wp.array(np.asarray(rig.neutral, dtype=np.float64), dtype=wp.vec3d, device=dev)
        self._shape_start = wp.array(by_vertex.indptr.astype(np.int32), dtype=wp.int32, device=dev)
        self._shape_id = wp.array(shape_id, dtype=wp.int32, device=dev)
        self._shape_delta = wp.array(np.ascontiguousarray(d[shape_id, rows]), dtype=wp.vec3, device=dev)
        skel = rig.skeleton
        if skel is not None:
            sw = sp.csr_matrix(np.asarray(skel.weights, dtype=np.float64))  # (N, J), its nonzeros only
            self._skin = (wp.array(sw.indptr.astype(np.int32), dtype=wp.int32, device=dev),
                          wp.array(sw.indices.astype(np.int32), dtype=wp.int32, device=dev),
                          wp.array(sw.data, dtype=wp.float64, device=dev))
        self._no_skin = (wp.zeros(n + 1, dtype=wp.int32, device=dev), wp.zeros(0, dtype=wp.int32, device=dev),
                         wp.zeros(0, dtype=wp.float64, device=dev))

    @property
    def num_vertices(self) -> int:
        """N, the rig's vertex count."""
        return self.rig.num_vertices

    def supports(self, trajectory) -> bool:
        """Whether :meth:`positions` evaluates ``trajectory`` here: a :class:`KinematicTrajectory` of this rig, or a
        :class:`~kdfaces.ikd.corrections.CorrectedTrajectory` (x_K + f) over a supported one."""
        return pose_base(trajectory, self.rig) is not None

    def launch(self, trajectory, times, out: np.ndarray, parts: int = 1) -> list:
        """The work of x_K at ``times`` (T,) [s] into ``out`` (T, N, 3) float64, split into ``parts`` callables over
        contiguous vertex ranges (for threads; each writes its own rows of ``out``). ``trajectory`` must be
        supported (:meth:`supports`); the host-side inputs (weights, joint transforms, IKD's f) are computed here,
        before the callables run, so the callables release the GIL for most of their time."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        n = self.num_vertices
        if out.shape != (len(t), n, 3) or out.dtype != np.float64 or not out.flags.c_contiguous:
            raise ValueError(f"out: expected a C-contiguous float64 array of shape {(len(t), n, 3)}")
        chain = pose_base(trajectory, self.rig)
        if chain is None:
            raise ValueError("trajectory: not one PoseSampler evaluates (see supports())")
        base, extra = chain
        weights, G, root = base.pose_inputs(t)
        dev = self.device
        T = len(t)
        w = wp.array(np.ascontiguousarray(weights, dtype=np.float64), dtype=wp.float64, device=dev)
        if G is None:
            skin = self._no_skin
            rot = wp.zeros((T, 0), dtype=wp.mat33d, device=dev)
            trans = wp.zeros((T, 0), dtype=wp.vec3d, device=dev)
        else:
            skin = self._skin
            rot = wp.array(np.ascontiguousarray(G[:, :, :3, :3]), dtype=wp.mat33d, device=dev)
            trans = wp.array(np.ascontiguousarray(G[:, :, :3, 3]), dtype=wp.vec3d, device=dev)
        r = wp.array(np.zeros((T, 3)) if root is None else np.ascontiguousarray(root, dtype=np.float64),
                     dtype=wp.vec3d, device=dev)
        dst = wp.array(out, dtype=wp.vec3d, device=dev, copy=False) if dev.is_cpu else \
            wp.empty((T, n), dtype=wp.vec3d, device=dev)
        # host arrays (T, N, 3) to add, innermost layer first (a layer with no f and no bump adds nothing)
        terms = [_terms(tr, t) for tr in reversed(extra) if tr.correction is not None or tr.bump is not None]
        bounds = np.linspace(0, n, max(1, int(parts)) + 1).astype(np.int64)

        def part(lo: int, hi: int):
            def run():
                if hi > lo:
                    wp.launch(pose_positions, dim=hi - lo, device=dev,
                              inputs=[lo, self._neutral, self._shape_start, self._shape_id, self._shape_delta, w,
                                      *skin, rot, trans, r, dst])
                    if not dev.is_cpu:
                        out[:, lo:hi] = dst.numpy()[:, lo:hi]
                    for term in terms:
                        out[:, lo:hi] += term[:, lo:hi]
            return run

        return [part(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]

    def positions(self, trajectory, times) -> np.ndarray:
        """x_K of every vertex at ``times`` (T,) [s] → (T, N, 3) [m] float64, on this thread; ``trajectory``
        supported (:meth:`supports`), else evaluated by the trajectory itself."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if not self.supports(trajectory):
            from .trajectory import scan_trajectory

            return np.array(scan_trajectory(trajectory, t, 0)[0])
        out = np.empty((len(t), self.num_vertices, 3))
        for run in self.launch(trajectory, t, out):
            run()
        return out


def pose_base(trajectory, rig=None):
    """``(base, corrections)`` when ``trajectory`` is a :class:`KinematicTrajectory` (of ``rig``, when given) under
    zero or more :class:`~kdfaces.ikd.corrections.CorrectedTrajectory` layers (outermost first), else None."""
    from ..ikd.corrections import CorrectedTrajectory
    from .trajectory import KinematicTrajectory

    extra = []
    while type(trajectory) is CorrectedTrajectory:  # not a restricted one: its rows are a subset
        extra.append(trajectory)
        trajectory = trajectory.base
    if isinstance(trajectory, KinematicTrajectory) and (rig is None or trajectory.rig is rig):
        return trajectory, extra
    return None


def _terms(trajectory, t: np.ndarray) -> np.ndarray:
    """What a corrected trajectory adds to its base's positions at ``t`` (its f and trial bump), (T, N, 3)."""
    acc = [np.zeros((len(t), *trajectory.state_shape))]
    trajectory.add_terms(acc, t, 0)
    return acc[0]
