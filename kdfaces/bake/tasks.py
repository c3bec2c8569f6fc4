"""What a bake task carries and what it runs on a Dask worker.

A task carries a :class:`BakePayload`: the shot file's text and path, the solved IKD correction, the window and
step, and fingerprints of the files the shot reads and of the code. No frame data travels to a worker; each
worker rebuilds the shot, its face system and its (corrected) trajectory from the payload once, keeps them in a
per-process cache keyed by the payload's content key (:data:`WORKER_CACHE_SIZE` shots), and then computes every
chunk it is given through :func:`kdfaces.kd.simulate_kd`, the same call ``kdfaces run`` makes for all frames at
once. KD states are independent simulations, so a chunk's frames come out bit for bit as in the one big batch.

A worker checks that it runs the same code (:func:`code_fingerprint`) and reads the same files
(:func:`input_fingerprint`) as the client: the paths inside a shot file must reach the same files on every
machine (a shared file system), and a mismatch is an error, never a silently different bake.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import socket
import sys
import time
import tomllib
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import KDInputError
from ..resources import peak_rss_bytes, single_threaded_blas
from .store import STORE_FORMAT, BakeStore

__all__ = ["BakePayload", "bake_chunk", "code_fingerprint", "input_fingerprint", "WORKER_CACHE_SIZE"]

#: Shots a worker process keeps rebuilt (system, trajectory) at once.
WORKER_CACHE_SIZE = 2
_PACKAGE = Path(__file__).resolve().parents[1]


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 of everything that computes a frame here: the kdfaces sources and the numpy and Warp versions."""
    import warp

    h = hashlib.sha256()
    for p in sorted(_PACKAGE.rglob("*.py")):
        h.update(str(p.relative_to(_PACKAGE)).encode() + b"\0" + p.read_bytes() + b"\0")
    h.update(f"numpy {np.__version__} warp {warp.config.version} python {sys.version_info[:2]}".encode())
    return h.hexdigest()


def _hash_path(h, p: Path) -> None:
    if p.is_dir():
        for q in sorted(x for x in p.rglob("*") if x.is_file()):
            h.update(str(q.relative_to(p)).encode() + b"\0")
            _hash_file(h, q)
    elif p.is_file():
        _hash_file(h, p)
    else:
        h.update(b"missing:" + str(p).encode())


def _hash_file(h, p: Path) -> None:
    with open(p, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    h.update(b"\0")


def input_fingerprint(path, text: str, table: dict) -> str:
    """SHA-256 of a shot's content: its text and every file it reads (the rig file or folder, the default rig, a
    capture CSV, target OBJ files), so an edited capture or rig is a new bake, whatever the shot file says."""
    from ..io.rigfiles import DEFAULT_RIG_PATH

    base = Path(path).resolve().parent
    h = hashlib.sha256(text.encode("utf-8") + b"\0")
    rig = (table.get("rig") or {}).get("source", "default")
    files = [DEFAULT_RIG_PATH if str(rig) == "default" else base / str(rig)]
    source = str((table.get("animation") or {}).get("source", "demo"))
    if source not in ("demo", "keys"):
        files.append(base / source)
    for c in table.get("constraints") or []:
        target = c.get("target") if isinstance(c, dict) else None
        if isinstance(target, dict) and target.get("obj") is not None:
            files.append(base / str(target["obj"]))
    for p in files:
        h.update(str(p.name).encode() + b"\0")
        _hash_path(h, p)
    return h.hexdigest()


def _correction_digest(correction) -> str:
    if correction is None:
        return "none"
    h = hashlib.sha256(repr([(s.time_s, s.kind, s.basis) for s in correction.slots]).encode())
    h.update(np.ascontiguousarray(correction.coefficients, dtype=np.float64).tobytes())
    h.update(repr(correction.state_shape).encode())
    return h.hexdigest()


@dataclass(frozen=True)
class BakePayload:
    """Everything a task needs besides its frame range (see the module docstring).

    Attributes:
        shot_text: the shot file's text; shot_path: its absolute path (relative paths inside resolve from there).
        inputs: :func:`input_fingerprint` of the shot; code: :func:`code_fingerprint` of the client.
        window_s: the KD window passed to :func:`~kdfaces.kd.simulate_kd` (seconds, already resolved from
            "auto" by the client; any other value the shot allows goes through unchanged); step_s: the step [s].
        correction: the solved IKD correction (:class:`~kdfaces.ikd.Correction`) or None.
        frames, vertices: the shot's frame count F and points per frame N.
        max_memory_bytes: the memory budget of a task's KD batch (None: half the worker's available memory).
        max_bake_bytes: the trajectory bake a worker keeps between chunks, and its trajectory's sample cache
            (bounds a worker's memory whatever the take's length).
        cache_dir: where workers keep parsed rigs (None: nowhere).
    """

    shot_text: str
    shot_path: str
    inputs: str
    code: str
    window_s: float | str
    step_s: float
    correction: object | None
    frames: int
    vertices: int
    max_memory_bytes: int | None = None
    max_bake_bytes: int | None = None
    cache_dir: str | None = None
    key: str = field(init=False)

    def __post_init__(self):
        ident = {"format": STORE_FORMAT, "inputs": self.inputs, "code": self.code, "window_s": repr(self.window_s),
                 "step_s": repr(float(self.step_s)), "correction": _correction_digest(self.correction),
                 "frames": int(self.frames), "vertices": int(self.vertices), "dtype": "float32", "device": "cpu"}
        object.__setattr__(self, "key", hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest())


@dataclass
class _Baked:
    """A worker's rebuilt shot: the face system, the final trajectory and the frame times."""

    system: object
    trajectory: object
    times: np.ndarray
    setup_s: float


_CACHE: OrderedDict[str, _Baked] = OrderedDict()


def _baked(payload: BakePayload) -> tuple[_Baked, bool]:
    """The worker's rebuilt shot for ``payload`` (built on first use), and whether this call built it."""
    hit = _CACHE.get(payload.key)
    if hit is not None:
        _CACHE.move_to_end(payload.key)
        return hit, False
    t0 = time.perf_counter()
    from ..dynamics import FaceSystem
    from ..ikd.corrections import CorrectedTrajectory
    from ..motion.trajectory import KinematicTrajectory
    from ..shots.shotfile import parse_shot

    host = socket.gethostname()
    if code_fingerprint() != payload.code:
        raise KDInputError(f"bake worker on {host}: runs other kdfaces code (or numpy/Warp versions) than the client; "
                           "install the same version everywhere")
    path = Path(payload.shot_path)
    table = tomllib.loads(payload.shot_text)
    if input_fingerprint(path, payload.shot_text, table) != payload.inputs:
        raise KDInputError(f"{path}: the files this shot reads differ on {host} from the client's (workers need the "
                           "same files at the same paths: a shared file system)")
    with warnings.catch_warnings():  # the client has shown the shot's warnings once
        warnings.simplefilter("ignore")
        shot = parse_shot(table, path, cache_dir=payload.cache_dir)
        if payload.max_bake_bytes is None:
            trajectory = shot.trajectory
        else:  # as Shot.trajectory, with a sample cache of about two chunks' windows (the system keeps its own rows):
            # the default cache would fill up to its 256 MiB on a long take, and a worker's memory would grow with it
            trajectory = KinematicTrajectory(shot.rig, shot.animation, channel_map=shot.channel_map,
                                             strict=shot.strict_channels, cache_bytes=int(payload.max_bake_bytes))
    times = shot.animation.frame_times
    if len(times) != payload.frames or shot.rig.num_vertices != payload.vertices:
        raise KDInputError(f"{path}: {len(times)} frames of {shot.rig.num_vertices} vertices on {host}, the client "
                           f"has {payload.frames} of {payload.vertices}")
    kwargs = {} if payload.max_bake_bytes is None else {"max_bake_bytes": int(payload.max_bake_bytes)}
    system = FaceSystem(shot.model(), device="cpu", threads=1, **kwargs)
    if payload.correction is not None:  # a copy: its version comes from this process's own counter
        trajectory = CorrectedTrajectory(trajectory, payload.correction.copy())
    baked = _Baked(system=system, trajectory=trajectory, times=times, setup_s=time.perf_counter() - t0)
    _CACHE[payload.key] = baked
    while len(_CACHE) > WORKER_CACHE_SIZE:
        _CACHE.popitem(last=False)
    return baked, True


@single_threaded_blas()  # as kdfaces run: the same bits on every worker
def bake_chunk(payload: BakePayload, index: int, store_path: str) -> dict:
    """The bake task: KD of chunk ``index``'s frames of the payload's trajectory, written to the store at
    ``store_path`` (positions, then the chunk's completion mark). Returns a small record: frame range, worker,
    seconds spent rebuilding the shot (0 when cached), in the KD and writing, wall-clock start and stop, and the
    worker process's peak resident memory so far [bytes]."""
    from ..kd import simulate_kd

    start = time.time()
    c0 = time.perf_counter()
    store = BakeStore.open(store_path, mode="r+")
    if store.key != payload.key:
        raise KDInputError(f"{store_path}: the store now belongs to another bake (was it replaced mid-bake?)")
    lo, hi = store.chunk_range(index)
    opened = time.perf_counter() - c0
    baked, built = _baked(payload)
    c1 = time.perf_counter()
    x = simulate_kd(baked.system, baked.trajectory, baked.times[lo:hi], payload.window_s, step_s=payload.step_s,
                    max_memory_bytes=payload.max_memory_bytes)
    c2 = time.perf_counter()
    store.write_chunk(index, x)
    c3 = time.perf_counter()
    return {"index": int(index), "lo": lo, "hi": hi, "host": socket.gethostname(), "pid": os.getpid(),
            "setup_s": baked.setup_s if built else 0.0, "open_s": opened, "kd_s": c2 - c1, "write_s": c3 - c2,
            "start": start, "stop": time.time(),
            "peak_rss_bytes": peak_rss_bytes()}



def quiet_worker_plugin():
    """A Dask worker plugin for the bake's own local cluster: Warp starts quietly in each worker process (no banner,
    no "no CUDA driver" warning, no kernel-cache lines), as it does in the command-line process; and a worker ignores
    Ctrl-C (a terminal sends it to the whole process group): the client that owns the cluster stops it."""
    from distributed import WorkerPlugin

    class QuietWarp(WorkerPlugin):
        name = "kdfaces-quiet-warp"

        def setup(self, worker):
            import signal

            import warp as wp

            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            except ValueError:  # not the main thread: leave the handler as it is
                pass
            import logging

            # a task's error reaches the client, which reports it in one line; the worker does not log it too
            logging.getLogger("distributed.worker").setLevel(logging.CRITICAL)

            wp.config.quiet = True
            wp.config.log_level = wp.LOG_WARNING
            sys.stderr.flush()
            saved = os.dup(2)
            try:
                with open(os.devnull, "w") as null:
                    os.dup2(null.fileno(), 2)
                    wp.init()
            finally:
                os.dup2(saved, 2)
                os.close(saved)

    return QuietWarp()
