"""FaceSystem: the face dynamics behind the KD protocol of :mod:`kdfaces.kd` (initial_state / step / observe).

The kinematic trajectory is baked once per simulate call on the step grid (``prepare``), into Warp arrays of
x_K, ẋ_K. Each step is then, on the CPU, one launch of the fused :func:`~kdfaces.dynamics.kernels.face_step` per
thread (cluster rotations, then goals and the implicit PD step, looping inside the kernel), recorded once per state
so that a step costs a few microseconds of Python; on a GPU, two launches over (member, cluster) and
(member, vertex).

Threads: ``threads`` − 1 persistent workers, started once, share each step with the calling thread; a pair of
barriers per step hands them their part (no pool submit per step, and CPU launches release the GIL). A batch of
several members is split by members; a single state (the scrub path) is split by vertices into parts along a
bandwidth-reducing (reverse Cuthill–McKee) order of the cluster graph, so the parts meet along a short seam whose
clusters both fit.

Region: the system simulates the model's region only (:attr:`FaceModel.region`, R of the rig's N vertices): masses,
gains, clusters, the bake and the state are over those R vertices, so a step costs the same on a full-body avatar as
on its face cut out alone. The bake and the initial states evaluate x_K over the region only
(:func:`~kdfaces.motion.trajectory.restrict_trajectory`: a kinematic trajectory blends and skins those rows alone), so
the per-step work does not depend on N either. :meth:`FaceSystem.observe` returns every vertex, (B, N, 3): the vertices
outside the region are x_K at each member's time, evaluated (for those vertices only) once per observed state (they
follow x_K exactly, paper §4.5).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import warp as wp

from .. import defaults
from ..errors import KDInputError, SimulationBlowUpError, check_count
from ..motion.trajectory import restrict_trajectory, scan_trajectory
from ..resources import init_warp
from .clusters import Clusters
from .kernels import cluster_frames, face_step, track_step
from .model import FaceModel
from .workers import Workers

__all__ = ["FaceSystem", "FaceState", "TrajectoryBake", "KERNEL_PATHS"]

#: How a step is launched: "fused" (one :func:`~kdfaces.dynamics.kernels.face_step` per thread and step, the CPU
#: path) or "parallel" (a launch over (member, cluster), then one over (member, vertex), the GPU path).
KERNEL_PATHS = ("fused", "parallel")

_GRID_TOL = 1e-9
_OFF0, _OFF1 = object(), object()  # placeholders for the step's row offsets in launch specs
#: η added to the normalised A_pq before svd3 (see :func:`~kdfaces.dynamics.kernels.polar_svd`).
ROTATION_REGULARIZATION = 1e-4


class TrajectoryBake:
    """x_K, ẋ_K of a trajectory sampled on a step grid, as float32 Warp arrays ``xk``, ``vk`` of shape (R, V) vec3:
    R rows of the V simulated vertices (``vertices``, sorted indices into the trajectory's N, or None: all N).

    ``trajectory`` is the full trajectory (N vertices; its ``version`` identifies the bake); the rows are evaluated
    on ``source``, the trajectory over ``vertices`` (default :func:`~kdfaces.motion.trajectory.restrict_trajectory`
    of the two), so a bake costs V's vertices, not N's.

    Member b at step k reads row ``rows[b] + k·stride``. Shared grid (``member_times`` and ``member_grid`` None):
    row r is the time ``origin + (j_lo + r)·h``, read by every window that starts on that grid (``origin`` defaults
    to the shot start; frame times with h = 1/fps lie on it), stride 1, and kept across simulate calls (a sweep over
    windows bakes once). Otherwise each member has its own rows, interleaved time-major (stride B): member b's row at
    step k is the time ``member_times[b] + k·h``, or with ``member_grid`` (grid indices (B,), int64) the grid time
    ``origin + (member_grid[b] + k)·h`` — the very float64 values, computed the same way, that a shared-grid bake
    holds at those grid points, so a few windows far apart bake their own rows only and read the same x_K bits.
    Rows are appended on demand by :meth:`ensure`.
    """

    def __init__(self, trajectory, h: float, device, *, j_lo: int = 0, member_times: np.ndarray | None = None,
                 member_grid: np.ndarray | None = None, origin: float | None = None,
                 vertices: np.ndarray | None = None, source=None, capacity: int = 0, order: np.ndarray | None = None):
        self.trajectory, self.h, self.device = trajectory, float(h), device
        self.vertices = vertices
        # the rows' vertex order in memory: column k holds the source's vertex order[k] (a system's locality order,
        # see FaceSystem); None: the source's order. xk_np / vk_np give the source's order either way.
        self.order = None if order is None else np.asarray(order, dtype=np.int64)
        self._where = None if order is None else np.argsort(self.order)  # source vertex → column
        self.source = restrict_trajectory(trajectory, vertices) if source is None else source
        self.origin = float(getattr(trajectory, "start", 0.0)) if origin is None else float(origin)
        self.version = getattr(trajectory, "version", None)
        if member_times is not None and member_grid is not None:
            raise KDInputError("bake: give member_times or member_grid, not both")
        self.member_times = member_times
        self.member_grid = None if member_grid is None else np.asarray(member_grid, dtype=np.int64)
        self.j_lo = int(j_lo)
        members = member_times if member_times is not None else self.member_grid
        self.stride = 1 if members is None else len(members)
        self.num_rows = 0
        n = trajectory.num_vertices if vertices is None else len(vertices)
        # host copies with spare capacity (``capacity`` rows allocated up front, uninitialised: a bake that knows its
        # span never reallocates); rows [0, num_rows) are valid, and no kernel reads past them (ensure)
        cap = max(0, int(capacity))
        self._x = np.empty((cap, n, 3), np.float32)
        self._v = np.empty_like(self._x)
        self.xk = wp.empty((cap, n), dtype=wp.vec3, device=device)
        self.vk = wp.empty((cap, n), dtype=wp.vec3, device=device)
        self._lo, self._hi = np.full(3, np.inf), np.full(3, -np.inf)
        self.radius = self.extent = self._vmax = 0.0
        self._readers: list[weakref.ref] = []  # the states that read this bake: while one lives, rows stay put

    @property
    def xk_np(self) -> np.ndarray:
        """Baked x_K [m], shape (R, V, 3), float32 (host), the V vertices in ``vertices`` order."""
        x = self._x[: self.num_rows]
        return x if self._where is None else x[:, self._where]

    @property
    def vk_np(self) -> np.ndarray:
        """Baked ẋ_K [m/s], shape (R, V, 3), float32 (host), the V vertices in ``vertices`` order."""
        v = self._v[: self.num_rows]
        return v if self._where is None else v[:, self._where]

    @staticmethod
    def grid_origin(trajectory, start_times: np.ndarray, h: float) -> float:
        """The grid the first window start lies on: the shot start shifted by that start's phase (a fraction of h),
        so frames of a shot whose frame interval is not a multiple of h still share one grid per phase."""
        start = float(getattr(trajectory, "start", 0.0))
        rel = (float(start_times[0]) - start) / h
        phase = rel - np.floor(rel)
        return start if min(phase, 1.0 - phase) < 1e-9 * max(1.0, abs(rel)) else start + phase * h

    @staticmethod
    def grid_index(trajectory, start_times: np.ndarray, h: float, origin: float | None = None) -> np.ndarray | None:
        """Grid indices j with start_times = origin + j·h (default origin the shot start), or None when some time is
        off that grid."""
        origin = float(getattr(trajectory, "start", 0.0)) if origin is None else float(origin)
        j = np.round((start_times - origin) / h)
        scale = max(1.0, float(np.abs(start_times).max()))
        return j.astype(np.int64) if np.allclose(origin + j * h, start_times, rtol=0, atol=_GRID_TOL * scale) \
            else None

    def times(self, r: np.ndarray) -> np.ndarray:
        """The time [s] of bake rows ``r``."""
        if self.member_grid is not None:  # the shared grid's own arithmetic: origin + (integer index)·h
            return self.origin + (self.member_grid[r % self.stride] + r // self.stride) * self.h
        if self.member_times is None:
            return self.origin + (self.j_lo + r) * self.h
        return self.member_times[r % self.stride] + (r // self.stride) * self.h

    @property
    def nbytes(self) -> int:
        """Memory held: device arrays and host copies [bytes]."""
        return 2 * (self._x.nbytes + self._v.nbytes)

    def prepended(self, j_lo: int) -> TrajectoryBake:
        """A new shared-grid bake starting at grid index ``j_lo`` < ``self.j_lo``, reusing this one's rows (states
        that read this bake keep it)."""
        new = TrajectoryBake(self.trajectory, self.h, self.device, j_lo=j_lo, origin=self.origin,
                             vertices=self.vertices, source=self.source, order=self.order)
        new.ensure(np.zeros(1, np.int32), self.j_lo - j_lo - 1)
        new._append(self._x[: self.num_rows], self._v[: self.num_rows])
        return new

    def _append(self, x: np.ndarray, v: np.ndarray) -> None:
        r0, r1 = self.num_rows, self.num_rows + len(x)
        if r1 > len(self._x):  # grow geometrically, so appending a row at a time stays O(rows appended)
            cap = max(r1, 2 * len(self._x))
            xh, vh = np.empty((cap, *x.shape[1:]), np.float32), np.empty((cap, *x.shape[1:]), np.float32)
            xh[:r0], vh[:r0] = self._x[:r0], self._v[:r0]
            self._x, self._v = xh, vh
            xk, vk = (wp.empty((cap, x.shape[1]), dtype=wp.vec3, device=self.device) for _ in range(2))
            if r0:
                wp.copy(xk, self.xk, count=r0 * x.shape[1])
                wp.copy(vk, self.vk, count=r0 * x.shape[1])
            self.xk, self.vk = xk, vk
        self._x[r0:r1] = x  # rows from num_rows on are spare until it moves past them
        self._v[r0:r1] = v
        flat = np.ascontiguousarray(self._x[r0:r1].reshape(-1, 3).T)  # (3, rows·N): reduced along rows, ~15× faster
        lo, hi = flat.min(axis=1), flat.max(axis=1)
        vh = self._v[r0:r1]  # max |v| as max(max v, −min v): no |v| temporary (np.maximum propagates NaN)
        vmax = float(np.maximum(vh.max(), -vh.min())) if r1 > r0 else 0.0
        if not (np.isfinite(lo).all() and np.isfinite(hi).all() and np.isfinite(vmax)):  # NaN and ±inf propagate
            bad = ~(np.isfinite(x).all(axis=(1, 2)) & np.isfinite(v).all(axis=(1, 2)))
            if bad.any():
                t = self.times(np.arange(r0, r1))[np.argmax(bad)]
                raise KDInputError(f"trajectory: x_K or its velocity is not finite at t = {t:.6g} s")
        self.xk[r0:r1].assign(self._x[r0:r1])
        self.vk[r0:r1].assign(self._v[r0:r1])
        self.num_rows = r1
        self._lo, self._hi = np.minimum(self._lo, lo), np.maximum(self._hi, hi)
        self._vmax = max(self._vmax, vmax)
        self.radius = float(np.abs(np.concatenate([self._lo, self._hi])).max())
        # how far the trajectory reaches: its extent, or where its fastest vertex gets in a second
        self.extent = max(float((self._hi - self._lo).max()), self._vmax * 1.0)

    def add_reader(self, state) -> None:
        """Note that ``state`` reads this bake (held weakly: a state that is gone no longer counts)."""
        self._readers = [r for r in self._readers if r() is not None] + [weakref.ref(state)]

    def read(self) -> bool:
        """Whether a state that reads this bake is still alive."""
        self._readers = [r for r in self._readers if r() is not None]
        return bool(self._readers)

    def slide(self, j_lo: int, capacity: int) -> bool:
        """Restart this shared-grid bake at grid index ``j_lo`` (>= ``self.j_lo``) in its own buffers, when no state
        reads it and they hold ``capacity`` rows: the rows from ``j_lo`` on move to the front (the grid times they
        hold stay theirs, so their x_K bits are what a new bake would evaluate), the rest are dropped, and the
        trajectory's extent is measured on the kept rows again, as a new bake's would be. A stream of chunks then
        reuses one buffer for the whole take. False (nothing changed) when a state still reads it, or it is too
        small."""
        if self.read() or self.member_times is not None or self.member_grid is not None or len(self._x) < capacity:
            return False
        a = min(max(0, int(j_lo) - self.j_lo), self.num_rows)
        kept_x, kept_v = self._x[a:self.num_rows].copy(), self._v[a:self.num_rows].copy()
        self.j_lo, self.num_rows = int(j_lo), 0
        self._lo, self._hi = np.full(3, np.inf), np.full(3, -np.inf)
        self.radius = self.extent = self._vmax = 0.0
        if len(kept_x):
            self._append(kept_x, kept_v)
        return True

    def ensure(self, rows: np.ndarray, steps: int) -> None:
        """Bake every row that members at ``rows`` read during steps 0..``steps``."""
        need = int(rows.max()) + steps * self.stride + 1
        if need <= self.num_rows:
            return
        x, v = self.source.evaluate(self.times(np.arange(self.num_rows, need)), order=1)  # the V rows only
        if self.order is not None:  # the same values, in the memory order
            x, v = x[:, self.order], v[:, self.order]
        self._append(x, v)


@dataclass
class _Partition:
    """The mesh split into parts for threads sharing one state (see :func:`~kdfaces.dynamics.kernels.face_step`).

    Part p fits the clusters ``clusters[cluster_offsets[p]:cluster_offsets[p + 1]]`` (global ids; their position
    in this list is their slot) and advances the vertices ``vertices[vertex_offsets[p]:vertex_offsets[p + 1]]``;
    the vertex in slot s reads the cluster slots ``slot_clusters[slot_offsets[s]:slot_offsets[s + 1]]``.
    """

    parts: int
    cluster_offsets: wp.array
    clusters: wp.array
    vertex_offsets: wp.array
    vertices: wp.array
    slot_offsets: wp.array
    slot_clusters: wp.array
    slots: int  # total cluster slots (seam clusters counted once per part)
    no_cluster_offsets: wp.array  # zeros: no part fits a cluster (shape matching off)


@dataclass
class _Chunk:
    members: slice
    rows: wp.array | None
    x: wp.array
    x_next: wp.array | None  # the fused path's second position buffer (x at t + h is written here, then swapped)
    v: wp.array
    rot: wp.array
    quat: wp.array
    cen: wp.array
    cen0: wp.array
    partition: _Partition | None = None
    launches: dict = field(default_factory=dict)  # (part, parity) → (bake/row arrays read, recorded wp.Launch)


@dataclass
class FaceState:
    """A batch of B face states.

    Attributes:
        start_times: window start time of each member [s], shape (B,), float64.
        steps: steps taken since the start.
        bake: the baked trajectory the members read (None until the first step when not prepared).
        rows: each member's bake row at its window start, shape (B,), int32.
        chunks: slices of the batch, each with positions x [m] and velocities v [m/s], shape (b, N) vec3 float32,
            per-cluster rotations (b, S) mat33 and their quaternions (b, S) quat (the warm start of the iterative
            rotation fit; identity at the window start), and centroids (b, S) vec3 [m] (S cluster slots); N here
            is R, the simulated vertices of the model's region.
        tasks: (chunk index, part) pairs, one per thread, that make up one step.
        trajectory: the trajectory the state started on (observe reads x_K there for vertices outside the region).
    """

    start_times: np.ndarray
    bake: TrajectoryBake | None
    rows: np.ndarray | None
    chunks: list = field(default_factory=list)
    steps: int = 0
    tasks: list = field(default_factory=list)
    trajectory: object = None


class FaceSystem:
    """Shape-matching face dynamics (paper §4.5) implementing the KD protocol.

    Args:
        model: the static :class:`FaceModel`.
        device: Warp device ("cpu" or "cuda:0").
        threads: CPU threads per step (the calling thread and ``threads`` − 1 persistent workers); a single state
            is split by vertices, a batch by members.
        check_every: steps between blow-up checks (NaN/inf, or a vertex farther than ``blowup_factor`` face
            diameters, or extents of the baked trajectory, beyond its reach); the final state is always checked.
        max_bake_bytes: the shared trajectory bake kept across calls stays within this many bytes; a call whose
            windows would grow it further starts a new bake at its own windows (bounded memory on long takes).
        kernels: "fused" or "parallel" (:data:`KERNEL_PATHS`); default fused on the CPU, parallel on a GPU. Both
            compute the same step (the tests hold them to float32 round-off of each other).
    """

    #: The class FaceSystem(model) builds for a model with a proxy (``model.embedding``, #29):
    #: :class:`~kdfaces.dynamics.proxy.ProxyFaceSystem`, registered by its module (the package imports it).
    proxy_system: type | None = None
    #: Whether a single state (the scrub path) is split by vertices over the threads; a subclass that keeps the
    #: other threads busy with work of its own meanwhile (the proxy's dense pose) steps it on one.
    split_one_state: bool = True

    def __new__(cls, model=None, *args, **kwargs):
        if cls is FaceSystem and getattr(model, "embedding", None) is not None and FaceSystem.proxy_system:
            cls = FaceSystem.proxy_system
        return super().__new__(cls)

    def __init__(self, model: FaceModel, *, device="cpu", threads: int = defaults.THREADS, check_every: int = 16,
                 blowup_factor: float = 10.0, max_bake_bytes: int = 512 << 20, kernels: str | None = None):
        init_warp()  # quietly, unless the user started Warp first
        self.model = model
        self.device = wp.get_device(device)
        self.threads = check_count(threads, "threads")
        self.check_every = max(1, int(check_every))
        self.blowup_factor = float(blowup_factor)
        self.max_bake_bytes = int(max_bake_bytes)
        if kernels is None:
            kernels = "fused" if self.device.is_cpu else "parallel"
        if kernels not in KERNEL_PATHS:
            raise KDInputError(f"kernels: expected one of {KERNEL_PATHS}, got {kernels!r}")
        self.kernels = kernels
        region = model.region
        self._region = None if region is None else np.asarray(region, dtype=np.int64)
        self._num_sim = model.num_simulated
        sim = slice(None) if region is None else self._region
        c = model.clusters if region is None else Clusters.from_matrix(  # renumbered into the region: 0..R-1
            sp.csr_matrix((np.ones(len(model.clusters.members), np.float32), model.clusters.members,
                           model.clusters.offsets), shape=(model.clusters.num_clusters, model.num_vertices))[:, sim])
        # the simulated vertices and the clusters in a locality order in memory (a subclass that reads the state's
        # arrays itself keeps the region's order): column k of the state and of the bake is region vertex
        # self._order[k]. The same arithmetic in the same sequence, so the same bits; only the cache misses change.
        self._order = _locality_order(c) if type(self).observe is FaceSystem.observe else None
        if self._order is not None:
            c = _renumbered(c, self._order)
        self._clusters = c
        ordered = np.arange(self._num_sim) if self._order is None else self._order
        sim = ordered if region is None else self._region[ordered]
        d = self.device
        self._offsets = wp.array(c.offsets, dtype=wp.int32, device=d)
        self._members = wp.array(c.members, dtype=wp.int32, device=d)
        self._voff = wp.array(c.vertex_offsets, dtype=wp.int32, device=d)
        self._vcl = wp.array(c.vertex_clusters, dtype=wp.int32, device=d)
        self._mass = wp.array(model.mass[sim].astype(np.float32), dtype=float, device=d)
        self._kp = wp.array(model.kp[sim].astype(np.float32), dtype=float, device=d)
        self._kd = wp.array(model.kd[sim].astype(np.float32), dtype=float, device=d)
        self._rigid_sim = model.rigid_mask[slice(None) if region is None else self._region]  # region order
        self._rigid = wp.array(model.rigid_mask[sim].astype(np.int32), dtype=wp.int32, device=d)
        # the vertices observe() takes from x_K: outside the region, and the region's rigid ones
        self._kinematic_rows = None if region is None else np.setdiff1d(
            np.arange(model.num_vertices), self._region[~self._rigid_sim]).astype(np.int64)
        self._views = (None, None, None)  # (trajectory, its region view, its observe view), the last one asked for
        self._voff_none = wp.zeros(self._num_sim + 1, dtype=wp.int32, device=d)  # no goals when α = 0
        self._partitions: dict[int, _Partition] = {}
        self._bake: TrajectoryBake | None = None  # the shared-grid bake, reused across calls
        self._sparse: TrajectoryBake | None = None  # the last bake of sparse windows' own grid rows (member_grid)
        self._pending = None  # (trajectory, start times, (bake, rows)) from the last prepare
        self._workers = None
        if self.threads > 1 and self.device.is_cpu:
            self._workers = Workers(self.threads - 1)
            weakref.finalize(self, self._workers.close)

    @property
    def num_simulated(self) -> int:
        """R, the vertices one step advances (the model's region; the rest follow x_K)."""
        return self._num_sim

    def close(self) -> None:
        """Stop the worker threads (they also stop when the system is garbage-collected)."""
        if self._workers is not None:
            self._workers.close()
            self._workers = None

    # --- KD protocol -------------------------------------------------------------------------------------------
    def prepare(self, trajectory, start_times, steps: int, step_s: float) -> None:
        """Bake x_K, ẋ_K for windows starting at ``start_times`` (B,) [s] and running ``steps`` steps of
        ``step_s`` [s].

        Windows on the shot's frame grid share one bake, reused by later calls with a trajectory of the same
        content (``trajectory.version``) and step; a new bake of a few windows far apart bakes their own rows only
        (the same grid times, so the same x_K; see :meth:`_bake_for`).
        """
        self._check_trajectory(trajectory)
        t0 = np.atleast_1d(np.asarray(start_times, dtype=np.float64))
        self._pending = (trajectory, t0, self._bake_for(trajectory, t0, float(step_s), steps))
        bake, rows = self._pending[2]
        bake.ensure(rows, steps)

    def _bake_for(self, trajectory, t0: np.ndarray, h: float, steps: int = 0):
        """(bake, rows): the shared bake when every start lies on one grid (reused, extended or restarted), else a
        bake of the members' own rows.

        A new bake of windows far apart (IKD: a few constraint windows spread over the shot, and a new f at every
        sweep, so nothing is reused) bakes only the rows the windows read, each distinct start its own rows on the
        grid (``member_grid``), when those U·(steps + 1) rows are at most half of the span j_lo..j_hi the shared
        bake would fill: the same grid times, evaluated the same way, so the kernels read the same x_K."""
        origin = TrajectoryBake.grid_origin(trajectory, t0, h)
        j = TrajectoryBake.grid_index(trajectory, t0, h, origin)
        if j is None:
            bake = TrajectoryBake(trajectory, h, self.device, member_times=t0, vertices=self._region,
                                  source=self._view(trajectory), order=self._order)
            return bake, np.arange(len(t0), dtype=np.int32)
        old = self._bake
        version = getattr(trajectory, "version", None)  # content, not identity: an edited correction is new content
        lo, hi = int(j.min()), int(j.max()) + steps + 1
        row_bytes = 4 * 3 * 4 * self._num_sim  # x_K, ẋ_K of the region; device and host

        def same_grid(bake):
            return (bake is not None and version is not None and bake.version == version and bake.h == h
                    and abs(bake.origin - origin) <= _GRID_TOL * max(1.0, abs(origin)))

        if (not same_grid(old)
                or (max(hi, old.j_lo + old.num_rows) - min(lo, old.j_lo)) * row_bytes > self.max_bake_bytes):
            starts = np.unique(j)
            if 2 * len(starts) * (steps + 1) <= hi - lo:  # sparse windows: their own rows on the grid
                if not same_grid(old):
                    self._bake = None  # stale content: freed, as a restart would
                sparse = self._sparse
                if not (same_grid(sparse) and np.isin(starts, sparse.member_grid).all()):
                    sparse = self._sparse = TrajectoryBake(trajectory, h, self.device, member_grid=starts,
                                                           origin=origin, vertices=self._region,
                                                           source=self._view(trajectory), order=self._order)
                return sparse, np.searchsorted(sparse.member_grid, j).astype(np.int32)
            # a new grid, or one that would outgrow the budget: start afresh at these windows (the old one is freed),
            # with room for the budget's rows (a stream of chunks restarts every few and never grows a bake), the
            # rows it shares with the old bake copied from there (the same grid times: the same x_K bits)
            if not same_grid(self._sparse):
                self._sparse = None
            keep = same_grid(old) and old.j_lo <= lo < old.j_lo + old.num_rows
            cap = max(hi - lo, min(self.max_bake_bytes // row_bytes, 4 * (hi - lo)))
            if keep and old.slide(lo, cap):  # no state reads it any more: its own buffers, no new allocation
                if self._pending is not None and self._pending[2][0] is old:
                    self._pending = None  # its rows moved
                return old, (j - old.j_lo).astype(np.int32)
            self._bake = new = TrajectoryBake(trajectory, h, self.device, j_lo=lo, origin=origin,
                                              vertices=self._region, source=self._view(trajectory), capacity=cap,
                                              order=self._order)
            if keep:  # the old bake's rows as they lie in memory (the same order)
                a = lo - old.j_lo
                b = min(a + cap, old.num_rows)
                new._append(old._x[a:b], old._v[a:b])
            old = new
        elif lo < old.j_lo:
            self._bake = old = old.prepended(lo)
        return old, (j - old.j_lo).astype(np.int32)

    def memory_bytes(self, num_members: int, grid_rows: int) -> int:
        """Estimated memory [bytes] of a batch of ``num_members`` states reading ``grid_rows`` baked rows: per member
        positions and velocities (R vec3, the region) and per-cluster rotations, quaternions and centroids, and the
        (N, 3) float64 every vertex that observe() returns; per row x_K and ẋ_K of the region on the device and on
        the host."""
        n, r, c = self.model.num_vertices, self._num_sim, self.model.clusters.num_clusters
        member = 2 * 12 * r + (36 + 16 + 12 + 12) * c + 8 * 3 * n
        return int(num_members) * member + int(grid_rows) * 4 * 12 * r

    def copy_state(self, state: FaceState) -> FaceState:
        """An independent copy of ``state`` (same bake, its own arrays)."""
        chunks = [_Chunk(members=ch.members, rows=ch.rows, x=wp.clone(ch.x),
                         x_next=None if ch.x_next is None else wp.empty_like(ch.x_next), v=wp.clone(ch.v),
                         rot=wp.clone(ch.rot), quat=wp.clone(ch.quat), cen=wp.clone(ch.cen), cen0=wp.clone(ch.cen0),
                         partition=ch.partition)
                  for ch in state.chunks]
        copy = FaceState(start_times=state.start_times.copy(), bake=state.bake,
                         rows=None if state.rows is None else state.rows.copy(), chunks=chunks, steps=state.steps,
                         tasks=list(state.tasks), trajectory=state.trajectory)
        if copy.bake is not None:
            copy.bake.add_reader(copy)
        return copy

    def initial_state(self, trajectory, times) -> FaceState:
        """States at ``times`` (B,) [s] on the kinematic trajectory: x = x_K(t), v = ẋ_K(t)."""
        t0 = np.atleast_1d(np.asarray(times, dtype=np.float64))
        pending = self._pending
        if pending is not None and pending[0] is trajectory and np.array_equal(pending[1], t0):
            bake, rows = pending[2]
            bake.ensure(rows, 0)
            x0, v0 = bake._x[: bake.num_rows][rows], bake._v[: bake.num_rows][rows]  # in memory order
        else:  # not prepared: bake on the first step, when h is known
            self._check_trajectory(trajectory)
            bake = rows = None
            x0, v0 = self._view(trajectory).evaluate(t0, order=1)  # the region's rows only
            if self._order is not None:
                x0, v0 = x0[:, self._order], v0[:, self._order]
            x0, v0 = x0.astype(np.float32), v0.astype(np.float32)
        B = len(t0)
        fused = self.kernels == "fused"
        threads = self.threads if self._workers is not None else 1
        # one state and several threads: split its vertices; a batch: split its members
        parts = threads if (fused and B == 1 and threads > 1 and self.split_one_state) else 1
        partition = self._partition(parts) if fused else None
        slots = partition.slots if fused else self._clusters.num_clusters
        d = self.device
        state = FaceState(start_times=t0, bake=bake, rows=rows, trajectory=trajectory)
        if bake is not None:
            bake.add_reader(state)
        for p in np.array_split(np.arange(B), min(threads if parts == 1 else 1, B)):
            x = wp.array(x0[p], dtype=wp.vec3, device=d)
            state.chunks.append(_Chunk(
                members=slice(int(p[0]), int(p[-1]) + 1),
                rows=None if rows is None else wp.array(rows[p], dtype=wp.int32, device=d),
                x=x, x_next=wp.empty_like(x) if fused else None,
                v=wp.array(v0[p], dtype=wp.vec3, device=d),
                rot=wp.zeros((len(p), slots), dtype=wp.mat33, device=d),
                quat=wp.array(np.tile(np.array([0, 0, 0, 1], np.float32), (len(p), slots, 1)), dtype=wp.quat,
                              device=d),
                cen=wp.zeros((len(p), slots), dtype=wp.vec3, device=d),
                cen0=wp.zeros((len(p), slots), dtype=wp.vec3, device=d),
                partition=partition,
            ))
        state.tasks = [(k, part) for k in range(len(state.chunks)) for part in range(parts)]
        return state

    def step(self, state: FaceState, trajectory, times, step_s: float) -> None:
        """Advance every member from ``times[b]`` to ``times[b] + step_s`` [s] (in place)."""
        h = step_s
        if state.bake is None:
            state.bake, state.rows = self._bake_for(trajectory, state.start_times, float(h))
            state.bake.add_reader(state)
            for ch in state.chunks:
                ch.rows = wp.array(state.rows[ch.members], dtype=wp.int32, device=self.device)
        bake = state.bake
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if abs(h - bake.h) > _GRID_TOL * bake.h:
            self._one_off_step(state, trajectory, t, h)
            return
        expect = state.start_times[0] + state.steps * bake.h
        if abs(t[0] - expect) > 1e-6 * max(1.0, abs(expect)):
            raise KDInputError(f"times: step expected to start at {expect:.9g} s, got {t[0]:.9g} s")
        bake.ensure(state.rows, state.steps + 1)
        off0, off1 = state.steps * bake.stride, (state.steps + 1) * bake.stride
        if self.kernels == "fused":
            parity = state.steps % 2
            tasks = [self._fused_launch(state.chunks[k], part, parity, bake, off0, off1) for k, part in state.tasks]
        else:
            tasks = [self._parallel_launches(state.chunks[k], bake, off0, off1) for k, _ in state.tasks]
        self._run(state, tasks)
        state.steps += 1
        if state.steps % self.check_every == 0:
            self._check(state)

    def _run(self, state: FaceState, tasks) -> None:
        """Run one step's tasks (on the workers when there are several), then swap the fused path's buffers."""
        if len(tasks) == 1 or self._workers is None:  # (a state made before close() steps on one thread)
            for task in tasks:
                task()
        else:
            self._workers.run(tasks)
        if self.kernels == "fused":
            for ch in state.chunks:
                ch.x, ch.x_next = ch.x_next, ch.x

    def _one_off_step(self, state: FaceState, trajectory, t: np.ndarray, h: float) -> None:
        """A step of another length than the state's grid (a final partial step of :func:`~kdfaces.kd.simulate_full`
        to a time between grid points): the same kernels on a two-row bake of x_K at t and t + h. The state leaves
        its grid, so it takes no further regular steps."""
        if not (0.0 < h):
            raise KDInputError(f"step_s: expected a positive number of seconds, got {h}")
        bake = TrajectoryBake(trajectory, h, self.device, member_times=np.broadcast_to(t, (len(state.start_times),)),
                              vertices=self._region, source=self._view(trajectory), order=self._order)
        bake.ensure(np.arange(bake.stride, dtype=np.int32), 1)
        tasks = []
        for k, part in state.tasks:
            ch = state.chunks[k]
            rows = wp.array(np.arange(ch.members.start, ch.members.stop, dtype=np.int32), dtype=wp.int32,
                            device=self.device)
            if self.kernels == "fused":
                inputs = self._fused_inputs(ch, part, bake, rows)
                inputs[7] = bake.stride  # off1: the members' rows at t + h

                def task(inputs=inputs, b=ch.x.shape[0]):
                    wp.launch(face_step, dim=b, inputs=inputs, device=self.device)
            else:
                def task(ch=ch, rows=rows):
                    for kernel, dim, inputs, outputs in self._launch_specs(ch, bake, rows=rows):
                        inputs = [0 if a is _OFF0 else bake.stride if a is _OFF1 else a for a in inputs]
                        wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=self.device)
            tasks.append(task)
        self._run(state, tasks)
        state.bake, state.rows, state.start_times, state.steps = bake, None, t + h, 0  # off the grid from here
        bake.add_reader(state)
        self._check(state)

    def observe_kinematic(self, trajectory, times) -> np.ndarray:
        """Vertex positions of the kinematic trajectory at ``times`` (T,) [s] → (T, N, 3) [m], float64."""
        return np.asarray(trajectory.evaluate(np.atleast_1d(np.asarray(times, dtype=np.float64)), order=0)[0])

    def simulated_kinematic(self, trajectory, times):
        """The vertices :meth:`observe` takes from the state, and x_K there: ``(rows, x)`` with ``rows`` the region's
        non-rigid vertices (S,) (indices into N, int64) and ``x`` x_K at ``times`` (T,) [s] on those rows, (T, S, 3)
        [m], float64, a one-off pass over the region's rows (no sample cache: the values are those of the full
        trajectory's scan at ``times``, which groups the times the same way). Every other vertex observe()
        returns is x_K itself (outside the region and rigid, paper §4.5), so ‖x_KD − x_K‖ is zero there and a
        deviation needs these rows only. None without a region (observe widens the state at every vertex)."""
        if self._region is None:
            return None
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        free = ~self._rigid_sim
        return self._region[free], scan_trajectory(self._view(trajectory), t, 0)[0][:, free]

    def observe(self, state: FaceState) -> np.ndarray:
        """Vertex positions of every member [m], shape (B, N, 3), float64. Rigid vertices, and with a region every
        vertex outside it, are the trajectory's own float64 positions at each member's time (they follow it
        exactly; the state holds rigid ones in float32 and outside ones not at all), evaluated once here (with a
        region, for those vertices only)."""
        self._check(state)
        x = self._positions(state)  # float32 (B, R, 3), region order
        rigid = self._rigid_sim
        if self._region is None:
            x = x.astype(np.float64)
        else:
            traj = state.bake.trajectory if state.bake is not None else state.trajectory
            t = state.start_times + state.steps * (state.bake.h if state.bake is not None else 0.0)
            full = np.empty((len(x), self.model.num_vertices, 3))
            full[:, self._region] = x  # widened exactly; the region's rigid rows are overwritten next
            rows = self._kinematic_rows
            if len(rows):
                view = self._view(traj, observe=True)
                for i in range(0, len(t), 32):
                    full[i:i + 32, rows] = scan_trajectory(view, t[i:i + 32], 0)[0]
            return full
        if rigid.any() and state.bake is not None:
            t = state.start_times + state.steps * state.bake.h
            for i in range(0, len(t), 32):
                x[i:i + 32, rigid] = scan_trajectory(state.bake.trajectory, t[i:i + 32], 0)[0][:, rigid]
        return x

    # --- internals ---------------------------------------------------------------------------------------------
    def _positions(self, state: FaceState) -> np.ndarray:
        """The state's positions [m], (B, R, 3) float32, the R simulated vertices in the region's order."""
        x = np.concatenate([ch.x.numpy() for ch in state.chunks])
        if self._order is None:
            return x
        out = np.empty_like(x)
        out[:, self._order] = x
        return out

    def _view(self, trajectory, observe: bool = False):
        """``trajectory`` over the region (``observe``: over the vertices observe() takes from x_K), through
        :func:`~kdfaces.motion.trajectory.restrict_trajectory`; the trajectory itself without a region. The views
        of the last trajectory are kept (a kinematic trajectory's view keeps its sample cache across calls, and
        every view reads its trajectory live, so none goes stale)."""
        if self._region is None:
            return trajectory
        last, region_view, observe_view = self._views
        if last is not trajectory:
            region_view = observe_view = None
        if observe:
            if observe_view is None:
                observe_view = restrict_trajectory(trajectory, self._kinematic_rows)
            view = observe_view
        else:
            if region_view is None:
                region_view = restrict_trajectory(trajectory, self._region)
            view = region_view
        self._views = (trajectory, region_view, observe_view)
        return view

    def _check_trajectory(self, trajectory) -> None:
        n = getattr(trajectory, "num_vertices", None)
        if n != self.model.num_vertices:
            raise KDInputError(f"trajectory: has {n} vertices, the face model has {self.model.num_vertices}")

    def _partition(self, parts: int) -> _Partition:
        """The mesh in ``parts`` parts of equal vertex count (cached): contiguous pieces of the reverse
        Cuthill–McKee order of the graph "shares a cluster", so each part's seam (clusters fitted twice) is short."""
        if parts in self._partitions:
            return self._partitions[parts]
        from scipy.sparse.csgraph import reverse_cuthill_mckee

        c = self._clusters
        n, nc = c.num_vertices, c.num_clusters
        if parts == 1:
            order = np.arange(n)
        else:
            m = sp.csr_matrix((np.ones(len(c.members), np.float32), c.members, c.offsets), shape=(nc, n))
            graph = sp.csr_matrix(m.T @ m + sp.identity(n, dtype=np.float32, format="csr"))
            order = np.asarray(reverse_cuthill_mckee(graph, symmetric_mode=True))
        vo, vc = c.vertex_offsets, c.vertex_clusters
        cl_off, cls, v_off, verts, s_off, s_cl = [0], [], [0], [], [np.zeros(1, np.int64)], []
        for piece in np.array_split(order, parts):
            piece = np.sort(piece)
            counts = (vo[piece + 1] - vo[piece]).astype(np.int64)
            mine = vc[np.repeat(vo[piece], counts) + _ranges(counts)]
            own = np.unique(mine)
            s_cl.append(cl_off[-1] + np.searchsorted(own, mine))
            s_off.append(s_off[-1][-1] + np.cumsum(counts))
            cls.append(own)
            cl_off.append(cl_off[-1] + len(own))
            verts.append(piece)
            v_off.append(v_off[-1] + len(piece))
        d = self.device

        def arr(a):
            return wp.array(np.concatenate([np.asarray(x, dtype=np.int64).ravel() for x in a]).astype(np.int32),
                            dtype=wp.int32, device=d)

        part = _Partition(parts=parts, cluster_offsets=arr([cl_off]), clusters=arr(cls), vertex_offsets=arr([v_off]),
                          vertices=arr(verts), slot_offsets=arr(s_off), slot_clusters=arr(s_cl),
                          slots=int(cl_off[-1]), no_cluster_offsets=wp.zeros(parts + 1, dtype=wp.int32, device=d))
        self._partitions[parts] = part
        return part

    def _fused_launch(self, ch: _Chunk, part: int, parity: int, bake: TrajectoryBake, off0: int, off1: int):
        """The step of ``part`` of chunk ``ch`` as a callable: its recorded face_step launch with the row offsets
        set (recorded once per chunk, part and buffer parity, and again if the bake grew)."""
        key = (bake.xk, bake.vk, ch.rows)  # the arrays themselves (ids could be reused after a bake grows)
        rec = ch.launches.get((part, parity))
        if rec is None or any(a is not b for a, b in zip(rec[0], key, strict=True)):
            cmd = wp.launch(face_step, dim=ch.x.shape[0], inputs=self._fused_inputs(ch, part, bake, ch.rows),
                            device=self.device, record_cmd=True)
            rec = ch.launches[(part, parity)] = (key, cmd)
        cmd = rec[1]
        cmd.set_param_at_index_from_ctype(_FUSED_OFF0, off0)
        cmd.set_param_at_index_from_ctype(_FUSED_OFF0 + 1, off1)
        return cmd.launch

    def _fused_inputs(self, ch: _Chunk, part: int, bake: TrajectoryBake, rows) -> list:
        """face_step's arguments for ``part`` of chunk ``ch`` reading ``bake`` at ``rows`` (row offsets 0)."""
        m, pa = self.model, ch.partition
        alpha_on = m.shape_matching_alpha > 0 and self._clusters.num_clusters > 0
        return [ch.x, ch.x_next, ch.v, bake.xk, bake.vk, rows, 0, 0, part,
                pa.cluster_offsets if alpha_on else pa.no_cluster_offsets, pa.clusters, self._offsets,
                self._members, self._mass, int(m.rotation == "iterative"), ROTATION_REGULARIZATION,
                m.rotation_iterations, pa.vertex_offsets, pa.vertices,
                pa.slot_offsets if alpha_on else self._voff_none, pa.slot_clusters, self._kp, self._kd, self._rigid,
                float(m.shape_matching_alpha), float(bake.h), int(m.damping_mode == "relative"), ch.quat, ch.rot,
                ch.cen, ch.cen0]

    def _parallel_launches(self, ch: _Chunk, bake: TrajectoryBake, off0: int, off1: int):
        """The step of chunk ``ch`` on the parallel path, as a callable of its launches."""

        def run():
            for kernel, dim, inputs, outputs in self._launch_specs(ch, bake):
                inputs = [off0 if a is _OFF0 else off1 if a is _OFF1 else a for a in inputs]
                wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=self.device)

        return run

    def _launch_specs(self, ch: _Chunk, bake: TrajectoryBake, rows=None) -> list:
        """(kernel, dim, inputs, outputs) of one step; the row offsets are the placeholders _OFF0 and _OFF1."""
        m = self.model
        b = ch.x.shape[0]
        rows = ch.rows if rows is None else rows
        specs = []
        if m.shape_matching_alpha > 0 and self._clusters.num_clusters:
            specs.append((cluster_frames, (b, self._clusters.num_clusters),
                          [ch.x, bake.xk, rows, _OFF0, self._offsets, self._members, self._mass,
                           int(m.rotation == "iterative"), ROTATION_REGULARIZATION, m.rotation_iterations, ch.quat],
                          [ch.rot, ch.cen, ch.cen0]))
            voff = self._voff
        else:
            voff = self._voff_none
        specs.append((track_step, (b, self._num_sim),
                      [bake.xk, bake.vk, rows, _OFF0, _OFF1, voff, self._vcl, ch.rot, ch.cen, ch.cen0, self._kp,
                       self._kd, self._rigid, float(m.shape_matching_alpha), float(bake.h),
                       int(m.damping_mode == "relative")],
                      [ch.x, ch.v]))
        return specs

    def _check(self, state: FaceState) -> None:
        """Raise :class:`SimulationBlowUpError` on NaN/inf or a runaway state, naming the member's time."""
        bake = state.bake
        radius, extent = (bake.radius, bake.extent) if bake is not None else (0.0, 0.0)
        bound = radius + self.blowup_factor * max(self.model.diameter_m, extent)
        for ch in state.chunks:
            for name, arr in (("position", ch.x), ("velocity", ch.v)):
                a = arr.numpy()
                top = float(np.abs(a).max()) if a.size else 0.0  # NaN propagates: one pass when all is well
                if (top <= bound) if name == "position" else np.isfinite(top):
                    continue
                bad = ~np.isfinite(a).all(axis=(1, 2))
                if name == "position":
                    bad |= np.abs(np.where(np.isfinite(a), a, 0.0)).max(axis=(1, 2)) > bound
                if bad.any():
                    b = int(np.argmax(bad)) + ch.members.start
                    t = state.start_times[b] + state.steps * (state.bake.h if state.bake is not None else 0.0)
                    raise SimulationBlowUpError(
                        f"face simulation blew up: {name} not finite or beyond {bound:.3g} m at t = {t:.6g} s "
                        f"(batch member {b}, step {state.steps})")


#: index of ``off0`` among face_step's arguments (``off1`` follows it)
_FUSED_OFF0 = [a.label for a in face_step.adj.args].index("off0")


def _locality_order(c: Clusters) -> np.ndarray:
    """A bandwidth-reducing order of the vertices (reverse Cuthill–McKee of the graph "shares a cluster"): a
    cluster's members then lie close together in memory (a production rig's subdivided vertices are appended at the
    end: a cluster's members spanned two thirds of the 27k rig's arrays), so the step's gathers hit the cache."""
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    n, nc = c.num_vertices, c.num_clusters
    if nc == 0 or n < 2:
        return np.arange(n, dtype=np.int64)
    m = sp.csr_matrix((np.ones(len(c.members), np.float32), c.members, c.offsets), shape=(nc, n))
    graph = sp.csr_matrix(m.T @ m + sp.identity(n, dtype=np.float32, format="csr"))
    return np.asarray(reverse_cuthill_mckee(graph, symmetric_mode=True), dtype=np.int64)


def _renumbered(c: Clusters, order: np.ndarray) -> Clusters:
    """``c`` with vertex order[k] renumbered k, and its clusters sorted by their first member's new number. Each
    cluster keeps its members in the same sequence (its moments sum in the same order, from the same first member)
    and each vertex its clusters in the same sequence (its goal sums in the same order): the same bits."""
    n, nc = c.num_vertices, c.num_clusters
    where = np.empty(n, dtype=np.int64)
    where[order] = np.arange(n)
    sizes = np.diff(c.offsets).astype(np.int64)
    first = np.full(nc, n, dtype=np.int64)  # an empty cluster sorts last
    full = sizes > 0
    if full.any():
        first[full] = np.minimum.reduceat(where[c.members], c.offsets[:-1][full].astype(np.int64))
    corder = np.argsort(first, kind="stable")  # new cluster k is old cluster corder[k]
    cwhere = np.empty(nc, dtype=np.int64)
    cwhere[corder] = np.arange(nc)
    members = where[c.members[np.repeat(c.offsets[:-1][corder].astype(np.int64), sizes[corder])
                              + _ranges(sizes[corder])]]
    counts = np.diff(c.vertex_offsets).astype(np.int64)
    vcl = cwhere[c.vertex_clusters[np.repeat(c.vertex_offsets[:-1][order].astype(np.int64), counts[order])
                                   + _ranges(counts[order])]]
    i32 = np.int32
    return Clusters(np.concatenate([[0], np.cumsum(sizes[corder])]).astype(i32), members.astype(i32),
                    np.concatenate([[0], np.cumsum(counts[order])]).astype(i32), vcl.astype(i32))


def _ranges(counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges 0..counts[k]-1."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    starts = np.repeat(np.cumsum(counts) - counts, counts)
    return np.arange(total) - starts
