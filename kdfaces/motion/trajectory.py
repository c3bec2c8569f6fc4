"""Kinematic trajectories x_K(t), ẋ_K(t), ẍ_K(t) of a face rig (paper §3: the PD target of the simulation).

A :class:`FaceAnimation` holds blend-shape weight curves and head-joint rotation curves; a
:class:`KinematicTrajectory` evaluates the rig under it for arrays of times: blend shapes, then LBS by the neck
and head joints, with exact derivatives from the curves (no finite differences).
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from ..deprecation import renamed_attribute, renamed_kwargs
from ..errors import KDInputError, check_finite
from ..rig.blendshapes import BlendshapeRig
from ..rig.names import alias_key, canonical_name, resolve_channels
from ..rig.skeleton import joint_transforms, skin
from .curves import KeyframeCurve
from .joints import JointTrajectory, SkeletonAnimation

__all__ = ["ShapeTrack", "FaceAnimation", "KinematicTrajectory", "UnmappedChannelsWarning", "scan_trajectory",
           "MIN_MAPPED_SHARE", "RestrictedTrajectory", "SlicedTrajectory", "restrict_trajectory", "vertex_subset"]


def scan_trajectory(trajectory, times, order: int = 2):
    """``trajectory.evaluate(times, order)`` for a one-off pass over a shot: through the trajectory's ``scan`` when
    it has one (it then leaves its sample cache alone), else its ``evaluate`` — any object with
    ``evaluate(times, order)`` is a trajectory. ``times`` (T,) [s] → ``order + 1`` arrays ``(T, *state_shape)``."""
    scan = getattr(trajectory, "scan", None)
    return trajectory.evaluate(times, order) if scan is None else scan(times, order)


def vertex_subset(vertices, num_vertices: int, where: str = "vertices") -> tuple[np.ndarray, bytes]:
    """``vertices`` as sorted unique int64 indices (R,) into ``num_vertices`` (read-only), and a digest of the set
    (what caches and versions of a restricted trajectory are keyed by)."""
    v = np.asarray(vertices)
    if v.ndim != 1 or not (v.dtype.kind in "iu" or v.size == 0):
        raise KDInputError(f"{where}: expected 1-D integer vertex indices, got an array of shape {v.shape} and "
                           f"dtype {v.dtype}")
    v = v.astype(np.int64)
    if v.size == 0 or v[0] < 0 or v[-1] >= num_vertices or (np.diff(v) <= 0).any():
        raise KDInputError(f"{where}: expected at least one sorted unique vertex index in [0, {num_vertices}), got "
                           f"{v.size} indices" + (f" from {v.min()} to {v.max()}" if v.size else ""))
    v = np.array(v)  # an own copy: the caller's array may change, the subset must not
    v.flags.writeable = False
    return v, hashlib.blake2b(v.tobytes(), digest_size=16).digest()


def restrict_trajectory(trajectory, vertices):
    """The trajectory over the vertex subset ``vertices`` (sorted unique indices (R,), or None: ``trajectory``
    itself): ``evaluate(times, order)`` gives ``order + 1`` arrays (T, R, 3), rows ``vertices`` of the full
    evaluation. Through the trajectory's own ``restricted(vertices)`` when it has one (a
    :class:`KinematicTrajectory` blends and skins those rows only), else a :class:`SlicedTrajectory` that slices
    the full evaluation (any trajectory)."""
    if vertices is None:
        return trajectory
    restricted = getattr(trajectory, "restricted", None)
    return restricted(vertices) if restricted is not None else SlicedTrajectory(trajectory, vertices)


class SlicedTrajectory:
    """Rows ``vertices`` (R,) of any trajectory's full evaluation: the generic :func:`restrict_trajectory` (no work
    saved; the trajectory's own sample cache, if any, holds full samples as before). ``version`` follows the
    trajectory's (read on every access: a trajectory edited in place is new content) and the vertex set."""

    def __init__(self, trajectory, vertices):
        n = getattr(trajectory, "num_vertices", None)
        self.parent = trajectory
        self.vertices, self._key = vertex_subset(vertices, np.iinfo(np.int64).max if n is None else int(n))

    @property
    def version(self):
        """("restricted", the trajectory's version, the vertex set), or None when the trajectory has none."""
        base = getattr(self.parent, "version", None)
        return None if base is None else ("restricted", base, self._key)

    @property
    def num_vertices(self) -> int:
        """R, the subset's vertex count."""
        return len(self.vertices)

    @property
    def state_shape(self) -> tuple[int, int]:
        """(R, 3)."""
        return (len(self.vertices), 3)

    @property
    def start(self) -> float:
        """Shot start [s] (the trajectory's; 0 when it has none)."""
        return float(getattr(self.parent, "start", 0.0))

    def evaluate(self, times, order: int = 2):
        """Rows ``vertices`` of the trajectory's ``evaluate(times, order)``: ``order + 1`` arrays (T, R, 3)."""
        return tuple(np.asarray(a)[:, self.vertices] for a in self.parent.evaluate(times, order))

    def scan(self, times, order: int = 2):
        """The same through :func:`scan_trajectory` (a one-off pass)."""
        return tuple(np.asarray(a)[:, self.vertices] for a in scan_trajectory(self.parent, times, order))

    def positions(self, times) -> np.ndarray:
        """x_K of the subset at ``times`` (T,) [s] → (T, R, 3) [m]."""
        return self.evaluate(times, order=0)[0]


class _RigRows:
    """The rig data that evaluating vertex rows ``vertices`` (R,) needs: the neutral [m], flat deltas float64 [m]
    and the skeleton with the rows' skin weights, over the rows that something moves (``moving``, indices into the
    R rows). The other rows (``still``: no shape moves them and no joint skins them, e.g. a body outside its face
    region) are the neutral before root motion: the full evaluation gives them x0 + Σ w_k·0, skinned by
    Σ_j 0·G_j ỹ + 1·y, the same values (±0 aside), so when they are at least half the rows they are copied, not
    computed (``moving`` and ``still`` are None otherwise: every row is computed)."""

    def __init__(self, rig: BlendshapeRig, vertices: np.ndarray):
        self.num_rows = len(vertices)
        deltas = np.take(rig.deltas, vertices, axis=1)  # (K, R, 3) float32
        skel = rig.skeleton
        weights = None if skel is None else skel.weights[vertices]
        moves = (deltas != 0).any(axis=(0, 2))
        if weights is not None:
            moves |= (weights != 0).any(axis=1)
        # copying still rows into place costs a scatter per order: worth it when they are most rows (a body outside
        # its region), not for a region's margin
        split = 2 * int(moves.sum()) <= len(moves)
        self.moving = np.flatnonzero(moves) if split else None
        self.still = np.flatnonzero(~moves) if split else None
        self.still_neutral = None if self.still is None else rig.neutral[vertices[self.still]]
        keep = slice(None) if self.moving is None else self.moving
        self.neutral = np.ascontiguousarray(rig.neutral[vertices][keep])
        # the same float64 values as the rig's own flat deltas (float32 deltas widen exactly), columns of the rows
        self.flat = np.ascontiguousarray(deltas[:, keep]).reshape(rig.num_shapes, -1).astype(np.float64)
        self.skeleton = None if skel is None else dataclasses.replace(
            skel, weights=np.ascontiguousarray(weights[keep]))

    def blend_offsets(self, weights) -> np.ndarray:
        """Σ w_k Δ_k of the moving rows for weights (T, K) → (T, M, 3), as :meth:`BlendshapeRig.blend_offsets`
        (shapes whose weight is zero at every time skipped)."""
        w2 = np.atleast_2d(np.asarray(weights, dtype=np.float64))
        nz = np.flatnonzero(np.abs(w2).max(axis=0) > 0)
        if len(nz) == 0:
            return np.zeros((len(w2), len(self.neutral), 3))
        return (w2[:, nz] @ self.flat[nz]).reshape(len(w2), -1, 3)

    def blend(self, weights) -> np.ndarray:
        """x0 + Σ w_k Δ_k of the moving rows for weights (T, K) → (T, M, 3), as :meth:`BlendshapeRig.blend`."""
        w2 = np.atleast_2d(np.asarray(weights, dtype=np.float64))
        check_finite(w2, "weights")
        return self.blend_offsets(w2) + self.neutral

    def expand(self, y, dy, ddy):
        """The moving rows' (T, M, 3) x, ẋ, ẍ (None where not computed) → every row's (T, R, 3): still rows at the
        neutral, at rest."""
        if self.still is None:
            return y, dy, ddy
        out = []
        for o, a in enumerate((y, dy, ddy)):
            if a is None:
                out.append(None)
                continue
            full = np.empty((len(a), self.num_rows, 3))
            full[:, self.moving] = a
            full[:, self.still] = self.still_neutral if o == 0 else 0.0
            out.append(full)
        return tuple(out)


def _cached_evaluate(owner, times, order: int, chunk_fn, scan_fn):
    """``evaluate`` through ``owner``'s sample cache (``owner._cache``: time in ns → the tuple (x, ẋ[, ẍ]) of that
    time's sample, each array ``state_shape``, float64, as many derivative orders as the call that computed it asked
    for; ``owner._cache_max`` samples, ``owner.chunk`` times per ``chunk_fn(t, order)`` call); more distinct times
    than the cache holds go to ``scan_fn``. Only the orders asked for are computed and copied (a bake asks for
    x_K, ẋ_K; a cached sample with fewer orders than asked is computed again); the values of an order do not depend
    on how many are computed (:meth:`KinematicTrajectory._evaluate_chunk`), so a cached sample is the same bits."""
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    check_finite(t, "trajectory times")
    if order not in (0, 1, 2):
        raise KDInputError(f"trajectory: order must be 0, 1 or 2, got {order}")
    keys = np.round(t * 1e9).astype(np.int64)
    uniq, first_index, inverse = np.unique(keys, return_index=True, return_inverse=True)
    if len(uniq) > owner._cache_max:  # more distinct times than the cache holds: evaluate directly
        return scan_fn(t, order)
    cache = owner._cache
    found = {}
    missing = []
    for k, i in zip(uniq.tolist(), first_index.tolist()):
        sample = cache.get(k)
        if sample is None or len(sample) <= order:
            missing.append((k, i))  # times within 1 ns share a sample, evaluated at the first one asked for
        else:
            cache.move_to_end(k)
            found[k] = sample
    for c in range(0, len(missing), owner.chunk):
        part = missing[c:c + owner.chunk]
        arrays = chunk_fn(t[[i for _, i in part]], order)[:order + 1]
        for j, (k, _) in enumerate(part):
            found[k] = tuple(a[j].copy() for a in arrays)  # own copies: the cache frees samples one by one
    for k, _ in missing:  # cache after the call has what it needs, so nothing it uses is evicted early
        cache[k] = found[k]
        cache.move_to_end(k)
        if len(cache) > owner._cache_max:
            cache.popitem(last=False)
    samples = [found[k] for k in uniq.tolist()]
    identity = len(inverse) == len(uniq) and bool((np.diff(inverse.ravel()) == 1).all())  # sorted distinct times
    out = []
    for o in range(order + 1):
        a = np.stack([s[o] for s in samples])
        out.append(a if identity else a[inverse.ravel()])
    return tuple(out)


def _chunked_scan(chunk: int, times, order: int, chunk_fn):
    """``chunk_fn(t, order)`` over ``times`` in chunks of ``chunk`` times, concatenated (no cache)."""
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    check_finite(t, "trajectory times")
    if order not in (0, 1, 2):
        raise KDInputError(f"trajectory: order must be 0, 1 or 2, got {order}")
    parts = [chunk_fn(t[i:i + chunk], order)[:order + 1] for i in range(0, len(t), chunk)]
    return tuple(np.concatenate([p[o] for p in parts]) for o in range(order + 1))

_TOKENS = itertools.count()


@dataclass(frozen=True)
class ShapeTrack:
    """A curve whose channels are the weights of the named shapes (ARKit names or aliases)."""

    names: tuple[str, ...]
    curve: KeyframeCurve

    def __post_init__(self):
        if len(self.names) != self.curve.channels:
            raise KDInputError(f"shape track: {len(self.names)} names for a {self.curve.channels}-channel curve")


@dataclass(frozen=True)
class FaceAnimation:
    """Blend-shape weight tracks and head rotation drives over ``[start_s, end_s]`` seconds, sampled at ``fps``.

    ``strict_channels``: a channel that names no shape of the rig is an error (keyed animations, the default), or
    is skipped with one warning (captures, whose 52 ARKit channels a production rig rarely all has).
    """

    tracks: tuple[ShapeTrack, ...] = ()
    skeleton: SkeletonAnimation = field(default_factory=SkeletonAnimation)
    start_s: float = 0.0
    end_s: float = 1.0
    fps: float = 25.0
    name: str = "animation"
    strict_channels: bool = True

    def __post_init__(self):
        if not (np.isfinite(self.end_s) and np.isfinite(self.start_s) and self.end_s > self.start_s):
            raise KDInputError(f"animation {self.name!r}: expected end_s > start_s, got [{self.start_s}, "
                               f"{self.end_s}]")
        if not (self.fps > 0):
            raise KDInputError(f"animation {self.name!r}: fps must be positive, got {self.fps}")

    start = renamed_attribute("start_s")
    end = renamed_attribute("end_s")

    @property
    def duration(self) -> float:
        """end_s − start_s [s]."""
        return self.end_s - self.start_s

    @property
    def num_frames(self) -> int:
        """F, the number of frames in the shot (without building :attr:`frame_times`): every frame lies in
        [start_s, end_s] (a capture's last sample need not fall on the frame grid; rounding up put a frame past
        the shot's end)."""
        return int(np.floor(self.duration * self.fps + 1e-6)) + 1

    @property
    def frame_times(self) -> np.ndarray:
        """Times [s] of every frame in the shot, shape (F,)."""
        return self.start_s + np.arange(self.num_frames) / self.fps

    def moves(self) -> bool:
        """Whether anything in the animation changes over time: a shape-weight channel, a joint drive or the root
        translation whose keys are not all one value (False: every track holds one pose, the head does not turn)."""
        curves = [t.curve for t in self.tracks] + [d.curve for d in self.skeleton.drives]
        if self.skeleton.root is not None:
            curves.append(self.skeleton.root)
        return any(not c.constant_channels().all() for c in curves)



# the old keyword names start/end still work for one release (a warning names the new ones)
FaceAnimation.__init__ = renamed_kwargs(start="start_s", end="end_s")(FaceAnimation.__init__)


#: A capture whose mapped channels are fewer than this share of the channels that move in it is an error (its face
#: would hardly move): not a tunable, the line between "a rig lacking a few shapes" and "a rig the take misses".
MIN_MAPPED_SHARE = 0.5


def _how_to_map(rig, unmapped, used=()) -> str:
    """How to map the first of ``unmapped`` channels onto ``rig``: an ``[animation.map]`` line with the rig's
    closest shape among those no channel drives (``used``: indices of the driven shapes)."""
    from ..rig.names import closest_shapes

    channel = unmapped[0] if unmapped else "jawOpen"
    driven = set(used)
    free = [s for i, s in enumerate(rig.shape_names) if i not in driven] or list(rig.shape_names)
    close = closest_shapes(channel, free, n=1)
    example = close[0] if close else (free[0] if free else "<shape>")
    return (f"map them in the shot's [animation.map], channel = the rig's shape(s) (e.g. {channel} = {example!r}), "
            "or name the rig's shapes after the channels (ARKit names or aliases such as AK_25_JawOpen, "
            "Mouth_Smile_L)")


class UnmappedChannelsWarning(UserWarning):
    """Animation channels that drive no shape of the rig (skipped; ``strict`` makes them an error)."""


class KinematicTrajectory:
    """x_K(t) of a rig under an animation. Arrays are (T, N, 3) in metres, m/s and m/s².

    Time ranges outside the shot hold the end poses (curves are clamped), so KD windows may reach before the start.

    Each channel of the animation drives the rig's shapes as :func:`kdfaces.rig.names.resolve_channels` says: a
    ``channel_map`` entry, the shape of that name, or both halves of a side-split shape (``browInnerUp`` drives
    ``browInnerUp_L`` and ``browInnerUp_R``). Channels left over are an error when ``strict`` (default: the
    animation's ``strict_channels``), else skipped with one :class:`UnmappedChannelsWarning` listing them — unless
    fewer than :data:`MIN_MAPPED_SHARE` of the channels that move drive a shape, which is a
    :class:`~kdfaces.errors.KDInputError` naming the first unmapped ones (a capture that maps nothing useful would
    give a frozen face); shapes no channel drives stay at 0. An animation with channels none of which drives a
    shape (every one skipped or dropped) is a :class:`~kdfaces.errors.KDInputError` either way: its face would not
    move. ``channel_map`` keys that are no
    channel of any track are an error too. ``where`` names the animation in errors (default ``animation 'NAME'``;
    a shot file passes ``FILE: animation``). ``cache_bytes`` bounds the memory of evaluated samples kept for re-use.
    ``joints``, a joint-angle trajectory of the rig's skeleton (e.g. the KD head of
    :func:`kdfaces.articulated.kd_joint_trajectory`), drives the skeleton instead of the animation's joint curves (the
    face then rides on it).
    """

    def __init__(self, rig: BlendshapeRig, animation: FaceAnimation, *, channel_map: dict | None = None,
                 strict: bool | None = None, chunk: int = 16, cache_bytes: int = 256 * 2**20, joints=None,
                 where: str | None = None):
        self.rig = rig
        self.animation = animation
        self.chunk = int(chunk)
        # evaluated samples, keyed by time in ns: KD windows, IKD iterations and scrubbing re-read the same grid
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_bytes = int(cache_bytes)
        self._cache_max = int(cache_bytes) // (3 * rig.num_vertices * 3 * 8)
        self._views: OrderedDict[bytes, RestrictedTrajectory] = OrderedDict()  # restricted(), by vertex set
        strict = animation.strict_channels if strict is None else bool(strict)
        where = f"animation {animation.name!r}" if where is None else where
        self._tracks, skipped = [], []
        self.channel_resolution = {}
        cmap = dict(channel_map or {})
        channels = [str(n) for t in animation.tracks for n in t.names]
        keys = {alias_key(canonical_name(n)) for n in channels}
        unknown = [k for k in cmap if alias_key(canonical_name(str(k))) not in keys]
        if unknown:
            import difflib

            close = difflib.get_close_matches(str(unknown[0]), channels, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise KDInputError(f"{where}.map.{unknown[0]}: not a channel of the animation (map keys are the "
                               f"animation's channel names, values the rig's shapes){hint}")
        for t in animation.tracks:
            own = {alias_key(canonical_name(str(n))) for n in t.names}
            track_map = {k: v for k, v in cmap.items() if alias_key(canonical_name(str(k))) in own}
            res = resolve_channels(t.names, rig.shape_names, channel_map=track_map, where=where)
            skipped += res.skipped
            self.channel_resolution.update(res.how)
            self._tracks.append((res.pairs[:, 0], res.pairs[:, 1], t.curve))
        if skipped and strict:
            rig.shape_indices(skipped, where=where)  # raises, naming the first and the closest shapes
        if channels and not any(len(shape) for _, shape, _ in self._tracks):
            dropped = [n for n, how in self.channel_resolution.items() if how == "dropped"]
            if len(dropped) == len(channels):
                raise KDInputError(f"{where}.map: every one of the {len(channels)} channels is dropped (false), so "
                                   "the face would not move; expected at least one channel mapped to a shape of rig "
                                   f"{rig.name!r}")
            raise KDInputError(f"{where}: rig {rig.name!r} has no shape for any of the {len(channels)} channels "
                               f"({', '.join(channels[:3])}{', ...' if len(channels) > 3 else ''}), so the face would "
                               f"not move; {_how_to_map(rig, skipped)}")
        if skipped and not strict:
            self._check_mapped_share(rig, animation, where)
        if skipped:
            warnings.warn(f"{where}: rig {rig.name!r} has no shape for channel(s) {', '.join(skipped)}; they are "
                          "skipped (map them in [animation.map], or set strict = true to make this an error)",
                          UnmappedChannelsWarning, stacklevel=2)
        self.skipped_channels = tuple(skipped)
        self._joint_drives = bool(animation.skeleton.drives)
        if animation.skeleton.drives and rig.skeleton is None:
            if strict:
                raise KDInputError(f"animation {animation.name!r} drives joints but rig {rig.name!r} has no skeleton")
            warnings.warn(f"{where}: rig {rig.name!r} has no skeleton, so the animation's head rotations are ignored",
                          UnmappedChannelsWarning, stacklevel=2)
            self._joint_drives = False
        #: identifies the content for caches (rig and animation are immutable, so one token per trajectory)
        self.version = ("kinematic", next(_TOKENS))
        self._joints = None
        if joints is not None:  # a joint-angle trajectory (e.g. a KD head) drives the skeleton instead
            if rig.skeleton is None or tuple(getattr(joints, "state_shape", ())) != (len(rig.skeleton.names), 3):
                raise KDInputError(f"joints: expected a joint-angle trajectory of rig {rig.name!r}'s skeleton")
            self._joints = joints
        self._joint_override = joints is not None

    def _check_mapped_share(self, rig, animation, where: str) -> None:
        """A capture that maps nothing useful is an error: fewer than half of the channels that move in the take
        (non-constant curves; channels the map drops are not counted) drive a shape of the rig."""
        moving, unmapped = 0, []
        for t in animation.tracks:
            for name, still in zip(t.names, t.curve.constant_channels()):
                how = self.channel_resolution.get(name)
                if still or how == "dropped":
                    continue
                moving += 1
                if how == "skipped":
                    unmapped.append(str(name))
        mapped = moving - len(unmapped)
        if moving and mapped < MIN_MAPPED_SHARE * moving:
            raise KDInputError(f"{where}: rig {rig.name!r} has a shape for only {mapped} of the {moving} channels that "
                               f"move in the take, fewer than {MIN_MAPPED_SHARE:.0%}; unmapped: "
                               f"{', '.join(unmapped[:4])}{', ...' if len(unmapped) > 4 else ''}; "
                               f"{_how_to_map(rig, unmapped, {int(i) for _, sh, _ in self._tracks for i in sh})}")

    def moves(self) -> bool:
        """Whether x_K changes over time: a channel that drives a shape of the rig varies, the joints are driven
        (by varying drives, or by a joint-angle trajectory), or the root translation varies. False: every frame is
        the same pose, and so is every KD state."""
        if self._joint_override:
            return True
        for channel, shape, curve in self._tracks:
            if len(shape) and not curve.constant_channels()[np.unique(channel)].all():
                return True
        skel = self.animation.skeleton
        if self._joint_drives and any(not d.curve.constant_channels().all() for d in skel.drives):
            return True
        return skel.root is not None and not skel.root.constant_channels().all()

    @property
    def state_shape(self) -> tuple[int, int]:
        """(N, 3): the state IKD corrects is every vertex position [m]."""
        return (self.rig.num_vertices, 3)

    @property
    def joints(self) -> JointTrajectory:
        """The joint-angle trajectory θ_K(t) of the same animation (what drives the head and attached objects)."""
        if self.rig.skeleton is None:
            raise KDInputError(f"rig {self.rig.name!r} has no skeleton, so its trajectory has no joint angles")
        if self._joints is None:
            a = self.animation
            self._joints = JointTrajectory(self.rig.skeleton, a.skeleton, start_s=a.start_s, end_s=a.end_s, fps=a.fps)
        return self._joints

    @property
    def num_vertices(self) -> int:
        """N, the rig's vertex count."""
        return self.rig.num_vertices

    @property
    def start(self) -> float:
        """Shot start [s]."""
        return self.animation.start_s

    @property
    def end(self) -> float:
        """Shot end [s]."""
        return self.animation.end_s

    @property
    def fps(self) -> float:
        """Frame rate [1/s]; the default simulation step is 1/fps."""
        return self.animation.fps

    @property
    def frame_times(self) -> np.ndarray:
        """Times [s] of every frame, shape (F,)."""
        return self.animation.frame_times

    def weights(self, times, order: int = 2):
        """Shape weights and derivatives: ``order + 1`` arrays (T, K)."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        out = [np.zeros((len(t), self.rig.num_shapes)) for _ in range(order + 1)]
        for channel, shape, curve in self._tracks:
            if len(shape) == 0:
                continue
            vals = curve.evaluate(t, order)
            for o in range(order + 1):
                np.add.at(out[o], (slice(None), shape), vals[o][:, channel])
        return self.rig.expand_weights(out)  # channel → target weights through in-betweens (identity without)

    def evaluate(self, times, order: int = 2):
        """x_K, ẋ_K, ẍ_K at ``times`` (T,) → ``order + 1`` arrays of shape (T, N, 3), float64.

        Samples are kept for re-use (KD windows, IKD sweeps and scrubbing re-read the same step grid) within
        ``cache_bytes``; a call asking for more distinct times than fit is evaluated directly, in chunks (as
        :meth:`scan` does). Either way the memory does not grow with the number of times ever asked for.
        """
        return _cached_evaluate(self, times, order, self._evaluate_chunk, self.scan)

    def scan(self, times, order: int = 2):
        """:meth:`evaluate` without the sample cache, in chunks: for one-off passes over a shot (a window estimate,
        a bake that keeps its own rows) that would only push re-used samples out of it."""
        return _chunked_scan(self.chunk, times, order, self._evaluate_chunk)

    def restricted(self, vertices) -> RestrictedTrajectory:
        """x_K of the vertex subset ``vertices`` (sorted unique indices (R,)) as a trajectory of its own
        (:class:`RestrictedTrajectory`): it blends the deltas' columns of those rows and skins those rows only, so
        its cost is R's, not N's, and its samples are rows ``vertices`` of :meth:`evaluate`'s. The views of the
        last two vertex sets asked for are kept (a face system asks for its region at every bake), each with its
        own sample cache within ``cache_bytes``."""
        v, key = vertex_subset(vertices, self.rig.num_vertices)
        view = self._views.get(key)
        if view is None:
            view = self._views[key] = RestrictedTrajectory(self, v, key)
            if len(self._views) > 2:
                self._views.popitem(last=False)
        else:
            self._views.move_to_end(key)
        return view

    def positions(self, times) -> np.ndarray:
        """x_K at ``times`` (T,) [s] → (T, N, 3) [m]."""
        return self.evaluate(times, order=0)[0]

    def _pose_terms(self, t, order: int):
        """What x_K at ``t`` (T,) [s] is made of: the shape weights and derivatives (``order + 1`` arrays (T, K),
        through in-betweens), the joint transforms' triplet (T, J, 4, 4) for LBS or None (no skeleton drives the
        rig), and the root translation's triplet (T, 3) [m] or None."""
        w = self.weights(t, order)
        skel = self.rig.skeleton
        G = None
        if self._joint_override:
            G = joint_transforms(skel, self._joints.evaluate(t, 2), order=order)
        elif skel is not None and self.animation.skeleton.drives:
            G = joint_transforms(skel, self.animation.skeleton.joint_angles(skel, t, 2), order=order)
        r = self.animation.skeleton.root_translation(t, 2) if self.animation.skeleton.root is not None else None
        return w, G, r

    def pose_inputs(self, times):
        """The inputs of x_K at ``times`` (T,) [s] without derivatives, for an evaluator of the rig's pose elsewhere
        (:class:`~kdfaces.motion.pose.PoseSampler`): the shape weights (T, K), the joint world transforms
        (T, J, 4, 4) or None, the root translation (T, 3) [m] or None — the values :meth:`evaluate` uses."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        check_finite(t, "trajectory times")
        w, G, r = self._pose_terms(t, 0)
        return w[0], None if G is None else G[0], None if r is None else r[0]

    def _evaluate_chunk(self, t, order: int = 2, rows: _RigRows | None = None):
        """x_K, ẋ_K, ẍ_K at ``t``; derivatives above ``order`` are not computed (None). ``rows``: the vertex rows to
        evaluate (every vertex when None): the blend reads their columns of the deltas and LBS their skin weights,
        the same products per row as the full evaluation (the tests hold the two to float64 round-off; with
        OpenBLAS they are bit for bit the same)."""
        w, G, r = self._pose_terms(t, order)
        blend = self.rig if rows is None else rows
        y = blend.blend(w[0])
        dy = blend.blend_offsets(w[1]) if order >= 1 else None
        ddy = blend.blend_offsets(w[2]) if order >= 2 else None
        if G is not None:
            y, dy, ddy = skin(self.rig.skeleton if rows is None else rows.skeleton, G, y, dy, ddy)
        if rows is not None:
            y, dy, ddy = rows.expand(y, dy, ddy)
        if r is not None:  # root motion moves every vertex, skinned or not
            y = y + r[0][:, None]
            dy = None if dy is None else dy + r[1][:, None]
            ddy = None if ddy is None else ddy + r[2][:, None]
        return y, dy, ddy


class RestrictedTrajectory:
    """x_K of a :class:`KinematicTrajectory` over a vertex subset (R,) (from :meth:`KinematicTrajectory.restricted`):
    arrays (T, R, 3) in metres, m/s and m/s², rows ``vertices`` of the full trajectory's. Only those rows are
    blended and skinned (in-betweens, joint overrides and root motion as in the full trajectory), so the work
    scales with R: a full-body avatar's face system bakes its face region at the cost of the face alone.

    Its sample cache is its own, keyed by time (the subset is fixed, and the base trajectory is immutable, so
    samples never go stale), within the base's ``cache_bytes``. ``version`` is the base's and the vertex set's.
    """

    def __init__(self, base: KinematicTrajectory, vertices: np.ndarray, key: bytes):
        self.base = base
        self.vertices = vertices
        self._key = key
        self._rows = _RigRows(base.rig, vertices)
        self.chunk = base.chunk
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_max = base._cache_bytes // (3 * len(vertices) * 3 * 8)
        self.version = ("restricted", base.version, key)

    @property
    def rig(self) -> BlendshapeRig:
        """The base trajectory's rig (all N vertices; this trajectory has rows ``vertices`` of it)."""
        return self.base.rig

    @property
    def animation(self) -> FaceAnimation:
        """The base trajectory's animation."""
        return self.base.animation

    @property
    def num_vertices(self) -> int:
        """R, the subset's vertex count."""
        return len(self.vertices)

    @property
    def state_shape(self) -> tuple[int, int]:
        """(R, 3)."""
        return (len(self.vertices), 3)

    @property
    def start(self) -> float:
        """Shot start [s]."""
        return self.base.start

    @property
    def end(self) -> float:
        """Shot end [s]."""
        return self.base.end

    @property
    def fps(self) -> float:
        """Frame rate [1/s]."""
        return self.base.fps

    @property
    def frame_times(self) -> np.ndarray:
        """Times [s] of every frame, shape (F,)."""
        return self.base.frame_times

    def moves(self) -> bool:
        """Whether the base trajectory's x_K changes over time (see :meth:`KinematicTrajectory.moves`)."""
        return self.base.moves()

    def restricted(self, vertices) -> RestrictedTrajectory:
        """A subset of this subset: ``vertices`` index its R rows (a view of the base over those vertices)."""
        v, _ = vertex_subset(vertices, len(self.vertices))
        return self.base.restricted(self.vertices[v])

    def _evaluate_chunk(self, t, order: int = 2):
        return self.base._evaluate_chunk(t, order, self._rows)

    def evaluate(self, times, order: int = 2):
        """x_K, ẋ_K, ẍ_K of the subset at ``times`` (T,) → ``order + 1`` arrays (T, R, 3), float64 (cached as
        :meth:`KinematicTrajectory.evaluate` caches)."""
        return _cached_evaluate(self, times, order, self._evaluate_chunk, self.scan)

    def scan(self, times, order: int = 2):
        """:meth:`evaluate` without the sample cache, in chunks (a one-off pass)."""
        return _chunked_scan(self.chunk, times, order, self._evaluate_chunk)

    def positions(self, times) -> np.ndarray:
        """x_K of the subset at ``times`` (T,) [s] → (T, R, 3) [m]."""
        return self.evaluate(times, order=0)[0]
