"""W fitted to the face's own dynamics (issue #29): the proxy's embedding learnt from an excitation take.

The shape-space embedding (:func:`~kdfaces.rig.proxy.embedding_matrix`) carries a dense vertex with the closest point
of one proxy triangle. Where the deviation x − x_K changes fast over the skin (around the mouth it changes by ~10 mm
over a centimetre) three corners cannot reproduce it: on the demo that interpolation alone is ~1 ε off the dense KD
states at 19k and 75k vertices, twice the issue's ε/2.

Here each row of W is fitted instead, to the dynamics themselves: the carried vertices' and the proxy's own. The
dense model and the proxy model are both simulated (KD states, history-free) on an *excitation take*
(:func:`excitation_animation`: every blend shape eased in and out at seeded times, and the head turned and nodded),
and each dense vertex i gets the weights w over its :data:`FIT_NEIGHBOURS` candidate proxy vertices (its shape-space
triangle's corners first, or itself for a proxy vertex, then its nearest proxy vertices in shape space) that
minimise

    Σ_t ‖Σ_j w_j d_j(t) − D_i(t)‖² + λ s² ‖w − w₀‖²    subject to  Σ_j w_j = 1,

with d_j the *proxy's* deviation (what W multiplies at run time, so W also absorbs the proxy's own systematic
error: at its own vertices too, where the prior is the identity), D_i the dense deviation, w₀ the shape-space
barycentric weights (the prior: where the take says little, W stays the geometric embedding), s² the take's mean
square dense deviation (λ is dimensionless: :data:`FIT_DAMPING`) and the sum-to-one constraint carrying a uniform
deviation exactly. It is one (k+1)×(k+1) KKT system per vertex (k neighbours and the multiplier), batched in numpy.

In the linear regime a KD deviation is a sum of responses to each shape's and each joint's motion, so weights that
reproduce the responses to a take that moves every shape reproduce those of any take. The take shares nothing
with the demo or the captures tested: its own seed, its own timing. Measured in docs/dense-rigs.md.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import KDInputError
from .model import FaceModel

__all__ = ["excitation_animation", "fit_embedding", "fitted_embedding", "model_embedding", "EXCITATION_DURATION_S",
           "EXCITATION_FPS", "EXCITATION_SEED", "EXCITATION_STRIDE", "EXCITATION_HEAD_RAD", "FIT_NEIGHBOURS",
           "FIT_DAMPING"]

#: Length [s] and frame rate [1/s] of the excitation take: 52 ARKit shapes, three bumps each, overlapping.
EXCITATION_DURATION_S = 8.0
EXCITATION_FPS = 25.0
#: The take's random seed (the same take, the same W, the same bytes).
EXCITATION_SEED = 0
#: KD states of every this many frames of the take are fitted (67 of 201): KD is history-free, so fewer states of
#: the same take cost less, and every 3rd frame fits as well as every frame at 19k (0.379 ε either way).
EXCITATION_STRIDE = 3
#: The head's largest yaw [rad] in the take (pitch 0.6×, roll 0.2× of it): the demo turns 0.6 rad and nods 0.35.
EXCITATION_HEAD_RAD = 0.5
#: Candidate proxy vertices per row. On the 75k face's 4k proxy, largest error over the 60 s capture (every 3rd
#: frame) / the demo: 12 → 0.61 / 0.43 ε, 16 → 0.47 / 0.45 ε, 20 → 0.41 / 0.33 ε, 24 → 0.38 / 0.31 ε; on every
#: capture frame 16 left one frame at 0.51 ε. W's nonzeros grow with it, and so does the carry's cost (a 75k
#: state's carry on one thread, random columns: 1.9 ms with 3 per row, 5.6 ms with 16, 6.7 ms with 20).
FIT_NEIGHBOURS = 20
#: λ, the pull towards the shape-space weights relative to the take's mean square deviation (dimensionless). At
#: 75k with 12 candidates, on the capture: 1e-3 → 0.74 ε, 1e-4 → 0.61 ε; with 16 on capture / demo: 1e-4 → 0.47 /
#: 0.45 ε, 1e-5 → 0.48 / 0.46 ε (the weights' |w|₁ grows from 9 to 13: the proxy's noise amplified).
FIT_DAMPING = 1e-4


def excitation_animation(rig, *, duration_s: float = EXCITATION_DURATION_S, fps: float = EXCITATION_FPS,
                         seed: int = EXCITATION_SEED, bumps: int = 3):
    """The excitation take for ``rig`` (a :class:`~kdfaces.motion.trajectory.FaceAnimation`): each of its shapes
    eased up and down ``bumps`` times (rise and fall 0.12–0.35 s, hold 0.1–0.6 s, weight 0.3–0.8, at seeded times
    over ``duration_s`` [s]); the head chain, where the rig's skeleton has it, turned, nodded and rolled between
    seeded holds (:data:`EXCITATION_HEAD_RAD`). Sharp eased stops, as in the demo, excite the face's ringing."""
    from ..motion.curves import KeyframeCurve
    from ..motion.joints import JointDrive, SkeletonAnimation
    from ..motion.trajectory import FaceAnimation, ShapeTrack
    from ..rig.skeleton import HEAD_CHAIN_SPLIT

    rng = np.random.default_rng(seed)
    tracks = []
    for name in rig.shape_names:
        ts, vs = [0.0], [0.0]
        for s in np.sort(rng.uniform(0.2, duration_s - 1.0, bumps)):
            rise, hold, fall = rng.uniform(0.12, 0.35), rng.uniform(0.1, 0.6), rng.uniform(0.12, 0.35)
            a = rng.uniform(0.3, 0.8)
            if s < ts[-1] + 0.05:  # overlaps the previous bump: skipped (its draws kept, so the rest is the same)
                continue
            ts += [s, s + rise, s + rise + hold, min(s + rise + hold + fall, duration_s - 0.01)]
            vs += [0.0, a, a, 0.0]
        ts.append(duration_s)
        vs.append(0.0)
        tracks.append(ShapeTrack((name,), KeyframeCurve.eased(ts, np.array(vs)[:, None])))
    drives = ()
    skel = rig.skeleton
    shares = {j: f for j, f in HEAD_CHAIN_SPLIT.items() if skel is not None and j in skel.names}
    if shares:
        ht, hv, t = [0.0], [np.zeros(3)], 0.3
        scale = EXCITATION_HEAD_RAD * np.array([1.0, 0.6, 0.2])
        while t < duration_s - 0.6:  # turns of 0.25–0.5 s (the demo's: 0.25–0.35 s) between holds of 0.2–0.8 s
            ht.append(t)
            hv.append(hv[-1])
            t = min(t + rng.uniform(0.25, 0.5), duration_s - 0.3)
            ht.append(t)
            hv.append(rng.uniform(-1.0, 1.0, 3) * scale)
            t += rng.uniform(0.2, 0.8)
        ht.append(duration_s)
        hv.append(np.zeros(3))
        hv = np.array(hv)
        drives = (JointDrive(KeyframeCurve.eased(ht, hv), shares),)
    return FaceAnimation(tracks=tuple(tracks), skeleton=SkeletonAnimation(drives), start_s=0.0, end_s=duration_s,
                         fps=fps, name="excitation")


def _candidates(prior: sp.csr_matrix, rows: np.ndarray, near: np.ndarray, k: int):
    """Per row of ``rows``: ``k`` distinct proxy columns, the prior's own first, then ``near`` (n, m) in order;
    and the prior's weights on them (n, k)."""
    lens = np.diff(prior.indptr)[rows]
    width = int(lens.max()) if len(lens) else 0
    own = np.full((len(rows), width), -1, dtype=np.int64)
    val = np.zeros((len(rows), width))
    r = np.repeat(np.arange(len(rows)), lens)
    pos = np.arange(lens.sum()) - np.repeat(np.cumsum(lens) - lens, lens)
    src = np.repeat(prior.indptr[rows], lens) + pos
    own[r, pos], val[r, pos] = prior.indices[src], prior.data[src]
    pool = np.hstack([own, near])
    dup = pool < 0
    for j in range(1, pool.shape[1]):  # a column seen earlier in the row (columns: a few dozen, not vertices)
        dup[:, j] |= (pool[:, :j] == pool[:, j:j + 1]).any(axis=1)
    order = np.argsort(dup, axis=1, kind="stable")[:, :k]  # the distinct ones, in order
    cand = np.take_along_axis(pool, order, axis=1)
    if (np.take_along_axis(dup, order, axis=1)).any():
        raise KDInputError(f"proxy fit: fewer than {k} distinct candidate proxy vertices for some vertex")
    w0 = np.zeros((len(rows), k))
    w0[:, :width] = np.where(np.arange(width) < lens[:, None], val, 0.0)  # the prior's come first
    return cand, w0


def fit_embedding(prior, region, proxy_deviation, dense_deviation, features, *, neighbours: int = FIT_NEIGHBOURS,
                  damping: float = FIT_DAMPING) -> sp.csr_matrix:
    """W (N, P) CSR fitted to simulated deviations (module docstring).

    ``prior``: the shape-space W₀ (N, P) (its nonzero rows are the rows fitted, the proxy's own identity rows
    among them; the prior's weights the fit is pulled towards); ``region`` (P,): the proxy's dense vertex indices;
    ``proxy_deviation`` (T, P, 3) [m] and ``dense_deviation`` (T, N, 3) [m]: x − x_K of the proxy and of the dense
    model at the same T states; ``features`` (N, E): shape space for the neighbour search
    (:func:`~kdfaces.rig.proxy.shape_features`); ``neighbours``: candidates per row (k); ``damping``: λ."""
    from scipy.spatial import cKDTree

    prior = sp.csr_matrix(prior)
    prior.sort_indices()
    n, p = prior.shape
    region = np.asarray(region, dtype=np.int64)
    x = np.asarray(proxy_deviation, dtype=np.float64)
    y = np.asarray(dense_deviation, dtype=np.float64)
    if x.ndim != 3 or y.ndim != 3 or x.shape != (len(y), p, 3) or y.shape[1:] != (n, 3) or not len(y):
        raise KDInputError(f"proxy fit: expected deviations (T, {p}, 3) and (T, {n}, 3), got {x.shape}, {y.shape}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise KDInputError("proxy fit: the excitation take's deviations are not finite (the simulation blew up)")
    k = min(int(neighbours), p)
    rows = np.flatnonzero(np.diff(prior.indptr) > 0)  # the proxy's own rows too (prior: the identity)
    out_r, out_c, out_v = [], [], []
    if len(rows):
        f = np.asarray(features, dtype=np.float64)
        _, near = cKDTree(f[region]).query(f[rows], k=k)
        cand, w0 = _candidates(prior, rows, np.asarray(near).reshape(len(rows), k), k)
        s2 = float((y[:, rows] ** 2).sum(axis=2).mean()) or 1.0  # the take's mean square deviation [m²]
        lam = float(damping) * s2
        w = np.empty((len(rows), k))
        for c0 in range(0, len(rows), 2048):  # chunks of vertices, each one batched solve
            q = slice(c0, min(c0 + 2048, len(rows)))
            xc = x[:, cand[q]]  # (T, b, k, 3)
            g = np.einsum("tbjc,tblc->bjl", xc, xc) / len(y) + lam * np.eye(k)
            r = np.einsum("tbjc,tbc->bj", xc, y[:, rows[q]]) / len(y) + lam * w0[q]
            a = np.zeros((len(g), k + 1, k + 1))
            a[:, :k, :k], a[:, :k, k], a[:, k, :k] = g, 1.0, 1.0  # KKT: Σ w = 1
            rhs = np.concatenate([r, np.ones((len(g), 1))], axis=1)
            w[q] = np.linalg.solve(a, rhs[..., None])[:, :k, 0]
        out_r.append(np.repeat(rows, k))
        out_c.append(cand.ravel())
        out_v.append(w.ravel())
    if not out_r:
        return sp.csr_matrix((n, p))
    W = sp.csr_matrix((np.concatenate(out_v), (np.concatenate(out_r), np.concatenate(out_c))), shape=(n, p))
    W.sum_duplicates()
    return W


def fitted_embedding(rig, dense_model, proxy_model, features, *, threads: int | None = None) -> sp.csr_matrix:
    """W fitted on the excitation take (module docstring): ``dense_model`` and ``proxy_model`` (the proxy's
    :class:`~kdfaces.dynamics.FaceModel`, its ``embedding`` the prior) simulated at the proxy's automatic window,
    one step per frame, on every :data:`EXCITATION_STRIDE`-th frame; ``features`` (N, E) the shape space of the
    neighbour search."""
    from .. import defaults
    from ..kd import simulate_kd
    from ..motion.trajectory import KinematicTrajectory
    from ..window import automatic_window
    from .system import FaceSystem

    threads = defaults.THREADS if threads is None else threads
    traj = KinematicTrajectory(rig, excitation_animation(rig))
    times = traj.frame_times[::EXCITATION_STRIDE]
    h = 1.0 / traj.fps
    window_s = automatic_window(proxy_model, traj, step_s=h).window_s
    xk = traj.evaluate(times, order=0)[0]
    out = []
    for model in (dense_model, proxy_model):
        system = FaceSystem(model, threads=threads)
        try:
            out.append(simulate_kd(system, traj, times, window_s, step_s=h) - xk)
        finally:
            system.close()
    region = np.asarray(proxy_model.region, dtype=np.int64)
    return fit_embedding(proxy_model.embedding, region, out[1][:, region], out[0], features)


def model_embedding(rig, dense_model, proxy_model) -> sp.csr_matrix:
    """:func:`fitted_embedding` for :meth:`FaceModel.from_rig <kdfaces.dynamics.FaceModel.from_rig>`: the
    neighbour search in the shape space the proxy was built in (the rig's shapes and the dense model's settle-time
    map, :func:`~kdfaces.rig.proxy.shape_features`)."""
    from ..rig.proxy import settle_time_features, shape_features

    features = shape_features(rig.neutral, rig.deltas,
                              settle_time_features(dense_model.settle_time_s, rig.num_vertices))
    return fitted_embedding(rig, dense_model, proxy_model, features)


FaceModel.embedding_fit = staticmethod(model_embedding)
