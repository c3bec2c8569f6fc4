"""Bake a shot's final trajectory on Dask: frame chunks as tasks, results in a resumable zarr store.

KD states are history-free (paper §3): the state at every frame is its own short simulation, so a long take splits
into chunks of frames that any number of worker processes, on any number of machines, compute independently. The
client does what needs the whole shot once — the automatic window (§5.2) and, for a shot with constraints, the IKD
solve — and ships the shot file's text plus the solved correction to the tasks (no frame data). Each chunk goes
through :func:`kdfaces.kd.simulate_kd`, exactly as ``kdfaces run`` computes all frames in one batch, so the bake is
bit for bit the single-process result (float32 in the store).

Fault tolerance and resume come from the store (:class:`~kdfaces.bake.store.BakeStore`): a chunk is complete once
its positions and then its completion mark (a hash of what the store holds and the chunk's frame range) are
written, each atomically. A worker killed mid-task leaves nothing half-written; Dask reruns the task elsewhere. A
rerun with the same shot, correction, window, step and code skips complete chunks and computes only the rest; any
change of those starts a fresh store.
"""

from __future__ import annotations

import os
import shutil
import statistics
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import defaults
from ..errors import KDError, KDInputError, KDIOError, KDNumericalError, check_count
from ..resources import progress_bar, single_threaded_blas
from .cluster import _connect, _dask, check_scheduler_address, plan_bake
from .store import BakeStore

__all__ = ["BakeResult", "bake_shot", "export_bake", "bake_summary", "default_store_path", "add_bake_parser",
           "check_scheduler_address", "plan_bake", "OUTPUT_STORE_NAME"]

#: The store's name inside a finished ``kdfaces bake`` output folder.
OUTPUT_STORE_NAME = "bake.zarr"


@dataclass
class BakeResult:
    """What :func:`bake_shot` did.

    Attributes:
        store: the store folder; shot: the parsed shot (rig, animation) the store's frames belong to.
        key: the store's content key; frames, chunks, chunk_frames: its size.
        tasks: a record per chunk computed by this call (see :func:`~kdfaces.bake.tasks.bake_chunk`).
        skipped: chunks that were complete already (resumed).
        window_s: the window the tasks simulated with; window_auto_s, epsilon_m: the automatic window and its ε
            (None when the window was given).
        ikd: the client's IKD solve (None without constraints).
        workers: worker processes at the start; scheduler: the scheduler's address; dashboard: its dashboard
            address (None without one).
        wall_s: the whole call; client_s: loading, window and IKD in the client; tasks_wall_s: first submission to
            last result.
    """

    store: Path
    shot: object
    key: str
    frames: int
    chunks: int
    chunk_frames: int
    tasks: list = field(default_factory=list)
    skipped: int = 0
    window_s: float | str = 0.0
    window_auto_s: float | None = None
    epsilon_m: float | None = None
    step_s: float = 0.0
    ikd: object | None = None
    workers: int = 0
    scheduler: str | None = None
    dashboard: str | None = None
    wall_s: float = 0.0
    client_s: float = 0.0
    tasks_wall_s: float = 0.0

    @property
    def computed(self) -> int:
        """Chunks computed by this call."""
        return len(self.tasks)

    @property
    def frames_per_s(self) -> float:
        """Frames computed per second of task wall time (0 when nothing was computed)."""
        n = sum(t["hi"] - t["lo"] for t in self.tasks)
        return n / self.tasks_wall_s if self.tasks_wall_s > 0 else 0.0

    @property
    def busy_s(self) -> float:
        """Seconds spent inside tasks, summed over tasks: opening the store, rebuilding the shot, KD, writing."""
        return float(sum(t["open_s"] + t["setup_s"] + t["kd_s"] + t["write_s"] for t in self.tasks))

    @property
    def overhead_share(self) -> float:
        """Share of the workers' wall time (workers × tasks_wall_s) spent outside tasks: scheduling, transfers,
        result round trips and workers idle at the end of the take."""
        total = self.workers * self.tasks_wall_s
        return max(0.0, 1.0 - self.busy_s / total) if total > 0 else 0.0

    @property
    def task_gap_s(self) -> float | None:
        """Median gap between one task's end and the next task's start on the same worker [s]: the per-task cost of
        the scheduler and the transfers (None with fewer than two tasks on a worker)."""
        gaps = []
        for pid in {t["pid"] for t in self.tasks}:
            mine = sorted((t for t in self.tasks if t["pid"] == pid), key=lambda t: t["start"])
            gaps += [b["start"] - a["stop"] for a, b in zip(mine, mine[1:])]
        return statistics.median(gaps) if gaps else None

    @property
    def worker_peak_bytes(self) -> dict:
        """Peak resident memory of each worker process that ran tasks, ``"host:pid"`` → bytes."""
        out: dict = {}
        for t in self.tasks:
            k = f"{t['host']}:{t['pid']}"
            out[k] = max(out.get(k, 0), int(t["peak_rss_bytes"]))
        return out

    def summary(self) -> dict:
        """The ``bake`` block of summary.json."""
        peaks = self.worker_peak_bytes
        return {
            "store": str(self.store), "key": self.key, "frames": self.frames, "chunk_frames": self.chunk_frames,
            "chunks": self.chunks, "computed_chunks": self.computed, "skipped_chunks": self.skipped,
            "workers": self.workers, "scheduler": self.scheduler, "dashboard": self.dashboard,
            "wall_s": self.wall_s, "client_s": self.client_s, "tasks_wall_s": self.tasks_wall_s,
            "frames_per_s": self.frames_per_s, "busy_s": self.busy_s,
            "kd_s": float(sum(t["kd_s"] for t in self.tasks)), "setup_s": float(sum(t["setup_s"] for t in self.tasks)),
            "overhead_share": self.overhead_share, "task_gap_s": self.task_gap_s,
            "worker_peak_rss_bytes": peaks, "max_worker_peak_rss_bytes": max(peaks.values(), default=0),
        }


def default_store_path(out) -> Path:
    """Where ``kdfaces bake --out OUT`` keeps its store while baking: the hidden sibling ``.OUT.bake.zarr`` (it
    survives an interrupted bake, so the next run resumes; a finished bake moves it into the output folder)."""
    out = Path(out)
    return out.parent / f".{out.name}.bake.zarr"


def _identity(x):
    return x


def bake_shot(shot, store, *, workers: int | None = None, scheduler: str | None = None,
              chunk_frames: int | None = None, window_s: float | None = None, max_memory_bytes: int | None = None,
              cache_dir=None, progress: bool = False, callback=None,
              max_steps: float | None = defaults.MAX_STEPS) -> BakeResult:
    """Bake the final trajectory (IKD applied when the shot has constraints) of every frame of the shot file
    ``shot`` into the zarr store at ``store``, on Dask.

    Args:
        shot: path of a TOML shot file (its text travels to the workers; paths inside it must reach the same files
            on every worker).
        store: the store folder: created, or resumed when it holds this bake (complete chunks are skipped), or
            replaced when it holds another bake of this or another shot. Workers write it, so on a cluster it must be
            on a file system they share, at the same path.
        workers: worker processes of a new local cluster (default one per core, one thread each).
        scheduler: address of an existing Dask scheduler (``tcp://host:8786``) to use as it is, instead.
        chunk_frames: frames per task and per store chunk (default :data:`kdfaces.defaults.BAKE_CHUNK_FRAMES`).
        window_s: overrides the shot's ``dynamics.window_s``.
        max_memory_bytes: memory budget of each task's KD batch (default half a worker's available memory).
        max_steps: refuse a shot whose work estimate exceeds this many vertex-steps, before anything runs
            (:func:`~kdfaces.shots.shotfile.estimate_work`; default :data:`~kdfaces.defaults.MAX_STEPS`, None: none).
        cache_dir: where the client and the workers keep parsed rigs (None: nowhere).
        progress: a bar over chunks on stderr, and the Dask dashboard's address when there is one.
        callback: ``callback(record)`` after each computed chunk, in the calling thread (record: see
            :func:`~kdfaces.bake.tasks.bake_chunk`); an exception it raises stops the bake like Ctrl-C.

    Returns:
        A :class:`BakeResult`. Ctrl-C (KeyboardInterrupt) cancels the tasks, closes a local cluster and leaves the
        store with its complete chunks, for the next call to resume.
    """
    from ..shots.shotfile import Shot, parse_shot, read_shot_table
    from .tasks import BakePayload, code_fingerprint, input_fingerprint

    t_start = time.perf_counter()
    if isinstance(shot, Shot):
        raise KDInputError("shot: expected the path of a shot file (its text is what travels to the workers)")
    if workers is not None and scheduler is not None:
        raise KDInputError("workers, scheduler: give one (a new local cluster of N workers, or an existing "
                           "scheduler), not both")
    workers = None if workers is None else check_count(workers, "workers")
    k = defaults.BAKE_CHUNK_FRAMES if chunk_frames is None else check_count(chunk_frames, "chunk_frames")
    path = Path(shot).resolve()
    # a wrong address fails first, within SCHEDULER_TIMEOUT_S, before the shot is even read
    external = _connect(scheduler) if scheduler is not None else None
    try:
        table = read_shot_table(path)
        text = path.read_bytes().decode("utf-8")
        parsed = parse_shot(table, path, cache_dir=cache_dir, max_steps=max_steps)
        k, workers = plan_bake(len(parsed.animation.frame_times), parsed.rig.num_vertices, k, workers,
                               local=scheduler is None)
        payload, info = _solve(parsed, path, text, table, window_s=window_s, max_memory_bytes=max_memory_bytes,
                               k=k, cache_dir=cache_dir, progress=progress, max_steps=max_steps,
                               fingerprints=(input_fingerprint(path, text, table), code_fingerprint()),
                               payload_type=BakePayload)
        st = _open_store(Path(store).absolute(), payload.key, parsed.animation.frame_times, payload.vertices, k,
                         meta={"shot": parsed.name, "shot_path": str(path), "window_s": repr(payload.window_s),
                               "step_s": payload.step_s, "fps": parsed.animation.fps})
        result = BakeResult(store=st.path, shot=parsed, key=payload.key, frames=st.frames, chunks=st.num_chunks,
                            chunk_frames=k, step_s=payload.step_s, client_s=time.perf_counter() - t_start, **info)
        done = st.complete()  # reads every chunk back: a chunk damaged since it was marked is recomputed
        result.skipped = int(done.sum())
        todo = [i for i in range(st.num_chunks) if not done[i]]
        if todo:  # a local cluster starts only when there is something to compute
            with _dask(workers, external) as (client, count, dashboard):
                result.workers, result.dashboard, result.scheduler = count, dashboard, client.scheduler.address
                if progress and dashboard:
                    print(f"bake: Dask dashboard at {dashboard}", file=sys.stderr)
                t_tasks = time.perf_counter()
                with progress_bar("bake chunks", st.num_chunks, progress) as bar:
                    bar.update(result.skipped)
                    result.tasks = _run_tasks(client, payload, todo, st.path, bar, callback)
                result.tasks_wall_s = time.perf_counter() - t_tasks
    finally:
        if external is not None:
            external.close()
    missing = [i for i, ok in zip(todo, st.complete(todo)[todo]) if not ok] if todo else []
    if missing:
        raise KDIOError(f"{st.path}: chunks {missing[:5]} are not complete after the bake (was the store "
                        "changed by another process?)")
    result.wall_s = time.perf_counter() - t_start
    return result


@single_threaded_blas()  # the window and the solve as kdfaces run computes them, to the bit
def _solve(shot, path: Path, text: str, table: dict, *, window_s, max_memory_bytes, k, cache_dir, progress,
           fingerprints, payload_type, max_steps=defaults.MAX_STEPS):
    """The client's part: the window (as ``kdfaces run`` resolves it) and the IKD solve; the tasks' payload."""
    from ..dynamics import FaceSystem
    from ..ikd.solver import solve_ikd
    from ..kd import window_steps
    from ..window import automatic_window

    model = shot.model()
    traj = shot.trajectory
    h = shot.step_s
    w = shot.dynamics["window_s"] if window_s is None else window_s
    auto = eps = None
    if w == "auto":
        est = automatic_window(model, traj, step_s=h, max_steps=max_steps)
        auto, eps = max(est.window_s, h), est.epsilon_m
        window = auto
    elif isinstance(w, str):
        window = w  # another kind of window the shot allows goes to simulate_kd unchanged
    else:
        window = float(w)
        if not window > 0:
            raise KDInputError(f"window: expected positive seconds, got {window}")
    n = window_steps(window, h) if not isinstance(window, str) else 0
    if n and max_memory_bytes is not None:  # a budget a task cannot keep fails here, in one line, not in a worker
        from ..resources import format_bytes, memory_budget_bytes

        need = FaceSystem(model, device="cpu", threads=1).memory_bytes(1, n + 1)
        if need > memory_budget_bytes(max_memory_bytes):
            raise KDInputError(f"--max-memory {format_bytes(max_memory_bytes)}: one KD state needs "
                               f"{format_bytes(need)} ({n} steps); give a larger --max-memory or a shorter --window")
    result = None
    correction = None
    constraints = shot.constraints()
    if constraints:
        system = FaceSystem(model, device="cpu", threads=2)  # as kdfaces run: the client has the solve to itself
        s = shot.solver_options()
        with progress_bar("IKD sweeps", s["max_iterations"], progress) as bar:
            result = solve_ikd(system, traj, constraints, window_s=window, step_s=h,
                               callback=lambda it, err: bar.update(1), **s)
        final = result.trajectory
        if getattr(final, "base", None) is not traj or getattr(final, "bump", None) is not None:
            raise KDNumericalError("IKD: the solved trajectory is not the shot's trajectory plus one correction")
        correction = final.correction
    # the trajectory bake a worker keeps between chunks: the rows of about two chunks' windows, not the take's, so
    # a worker's memory does not grow with the take (rows are x_K, ẋ_K at grid times: re-baking gives the same);
    # a row holds the simulated vertices only (the model's region, FaceSystem.memory_bytes), not every vertex
    row_bytes = 4 * 3 * 4 * model.num_simulated
    max_bake = 2 * (k + n + 1) * row_bytes if n else None
    payload = payload_type(shot_text=text, shot_path=str(path), inputs=fingerprints[0], code=fingerprints[1],
                           window_s=window, step_s=h, correction=correction, frames=len(shot.animation.frame_times),
                           vertices=model.num_vertices, max_memory_bytes=max_memory_bytes, max_bake_bytes=max_bake,
                           cache_dir=None if cache_dir is None else str(cache_dir))
    return payload, {"window_s": window, "window_auto_s": auto, "epsilon_m": eps, "ikd": result}


def _open_store(path: Path, key: str, times, vertices: int, k: int, *, meta: dict) -> BakeStore:
    """The store at ``path`` when it holds this bake (resume), else a fresh one there."""
    if path.exists():
        try:
            st = BakeStore.open(path, mode="r+")
        except KDInputError:
            st = None
        if st is not None and st.key == key and st.chunk_frames == k and st.frames == len(times) \
                and st.vertices == vertices:
            return st
    return BakeStore.create(path, key=key, times=times, vertices=vertices, chunk_frames=k, meta=meta)


def _run_tasks(client, payload, todo: list[int], store: Path, bar, callback) -> list[dict]:
    """Submit a task per chunk in ``todo`` and collect their records as they finish; on any exception (a task's,
    the callback's, Ctrl-C) cancel what is left and re-raise."""
    if not todo:
        return []
    from distributed import KilledWorker, as_completed
    from distributed.client import FutureCancelledError

    from .tasks import bake_chunk

    tag = f"{payload.key[:12]}-{uuid.uuid4().hex[:8]}"  # this call's tasks only (a rerun never joins old ones)
    shared = client.submit(_identity, payload, key=f"kdfaces-bake-payload-{tag}")
    futures = [client.submit(bake_chunk, shared, i, str(store), key=f"kdfaces-bake-{tag}-{i:06d}") for i in todo]
    records = []
    try:
        for fut in as_completed(futures, loop=client.loop):
            try:
                record = fut.result()
            except KDError:
                raise
            except FutureCancelledError:
                raise KDIOError("bake: the scheduler cancelled the tasks (was the cluster shut down?)") from None
            except KilledWorker as e:
                raise KDNumericalError(f"bake: a chunk's task killed worker processes repeatedly ({e}); out of "
                                       "memory? try a smaller --chunk-frames or --max-memory") from None
            records.append(record)
            bar.update(1)
            if callback is not None:
                callback(record)
    except BaseException:
        client.cancel(futures + [shared], force=True)
        raise
    return records


def export_bake(store, out, *, kinds, rig, name: str, fps: float, unit_m: float = 1.0) -> list[Path]:
    """Point caches (``kinds`` among ``usd``, ``usda``, ``pc2``) of a complete bake store, written into the folder
    ``out`` as ``<name>.<ext>``, chunk by chunk in frame order (memory bounded by one chunk; a ``usda`` text layer
    is the exception, USD holds it whole). ``rig`` gives USD its polygons; ``unit_m``: metres per written unit."""
    from ..io.export import EXPORT_KINDS, export_chunks

    st = BakeStore.open(store)
    missing = np.flatnonzero(st.marks() == 0)  # the content of each chunk is checked as it is streamed
    if len(missing):
        raise KDInputError(f"{st.path}: {len(missing)} of {st.num_chunks} chunks are not baked; run the bake first")
    times = st.times
    out = Path(out)
    written = []
    for kind in dict.fromkeys(kinds):
        written.append(export_chunks(out / f"{name}{EXPORT_KINDS[kind]}", st.iter_chunks(), times, kind=kind,
                                     num_vertices=st.vertices, rig=rig, fps=fps, name=name, unit_m=unit_m))
    return written


def _adopt_store(src: Path, dst: Path) -> None:
    """Start the working store ``dst`` as a copy of a finished bake's store ``src`` (hard links where the file system
    allows: chunk files are replaced, never edited, so the two never affect each other)."""
    from ..io.atomic import remove_stale_siblings, tagged_sibling_prefix

    remove_stale_siblings(dst, kinds=("adopting",))
    tmp = dst.parent / f"{tagged_sibling_prefix(dst, 'adopting')}{uuid.uuid4().hex[:8]}"
    try:

        def link(a, b):
            try:
                os.link(a, b)
            except OSError:
                shutil.copy2(a, b)

        shutil.copytree(src, tmp, copy_function=link)
        os.replace(tmp, dst)
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)  # resuming is an optimisation: bake from scratch instead


def _bake_command(args) -> dict:
    from ..defaults import user_cache_dir
    from ..io.summary import write_summary
    from ..resources import parse_bytes

    out = Path(args.out)
    final = Path(getattr(args, "final_out", None) or args.out)
    store = Path(args.store) if args.store else default_store_path(final)
    if args.store is None and not store.exists() and (final / OUTPUT_STORE_NAME).is_dir():
        _adopt_store(final / OUTPUT_STORE_NAME, store)  # a rerun of a finished bake starts from its store
    budget = None if args.max_memory is None else parse_bytes(args.max_memory)
    try:
        result = bake_shot(args.shot, store, workers=args.workers, scheduler=args.scheduler,
                           chunk_frames=args.chunk_frames, window_s=args.window, max_memory_bytes=budget,
                           cache_dir=user_cache_dir(), progress=True, max_steps=args.max_steps)
    except KeyboardInterrupt:
        _report_kept(store)
        raise
    shot = result.shot
    unit = shot.rig.source_unit_m if args.export_unit == "rig" else 1.0
    paths = export_bake(store, out, kinds=args.export, rig=shot.rig, name=shot.name, fps=shot.animation.fps,
                        unit_m=unit)
    if args.store is None:
        os.replace(store, out / OUTPUT_STORE_NAME)
        result.store = final / OUTPUT_STORE_NAME
        paths.append(out / OUTPUT_STORE_NAME)
    summary = bake_summary(result, out, paths)
    write_summary(out, summary)
    return summary


def _report_kept(store: Path) -> None:
    try:
        st = BakeStore.open(store)
        n = int((st.marks() != 0).sum())
    except (KDError, OSError):
        return
    print(f"kdfaces bake: {n} of {st.num_chunks} chunks are kept in {store}; the same command resumes there",
          file=sys.stderr)


def bake_summary(result: BakeResult, out, paths) -> dict:
    """summary.json of a bake: shot, rig, window, the IKD solve, the bake's size, timing and memory, outputs."""
    shot = result.shot
    anim = shot.animation
    s = {
        "shot": shot.name,
        "rig": {"name": shot.rig.name, "vertices": shot.rig.num_vertices, "source_unit_m": shot.rig.source_unit_m},
        "fps": anim.fps, "frames": result.frames, "duration_s": anim.duration, "step_s": result.step_s,
        "kd": {"window_s": result.window_s, "window_auto_s": result.window_auto_s, "epsilon_m": result.epsilon_m},
        "bake": result.summary(),
        "outputs": [str(Path(p).relative_to(out)) for p in paths],
    }
    r = result.ikd
    if r is not None:  # as kdfaces run reports it, without its independent check
        seams = r.seam_ratios(shot.rig.faces) or [None] * len(r.constraints)
        bounds = r.seam_bounds() or [None] * len(r.constraints)
        gradients = r.gradient_ratios() or [None] * len(r.constraints)
        s["ikd"] = {"converged": bool(r.converged), "reason": r.reason, "iterations": int(r.iterations),
                    "wall_s": float(r.wall_s), "update": r.update, "kd_states_simulated": int(r.kd_states),
                    "constraints": [
                        {"label": c.label, "time_s": c.time_s, "kind": c.kind, "unit": c.unit,
                         "error_before_m": float(r.errors_before[i]), "error_after_m": float(r.errors_after[i]),
                         "seam_ratio": None if seams[i] is None else float(seams[i]),
                         "seam_ratio_bound": bounds[i], "gradient_ratio": gradients[i]}
                        for i, c in enumerate(r.constraints)]}
    return s


def add_bake_parser(subparsers) -> None:
    """``kdfaces bake SHOT.toml [--out DIR] [--workers N | --scheduler ADDRESS] [--chunk-frames K] [--store PATH]
    [--window S] [--max-memory SIZE] [--export usd|usda|pc2 ...] [--json]``."""
    from ..io.export import add_export_option

    p = subparsers.add_parser("bake", help="bake a shot's final trajectory on Dask, resumable (long takes, clusters)")
    p.add_argument("shot", help="TOML shot file")
    p.add_argument("--out", default=None, help="output folder (default kd-out/<shot name>)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None,
                       help="worker processes of a local Dask cluster (default: one per core)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="use an existing Dask cluster, e.g. tcp://host:8786 (workers must see the same files)")
    p.add_argument("--chunk-frames", type=int, default=None, metavar="K",
                   help=f"frames per task (default {defaults.BAKE_CHUNK_FRAMES})")
    p.add_argument("--store", default=None, metavar="PATH",
                   help="keep the zarr store here (kept and resumed across runs); default: a hidden sibling "
                        f".OUT.bake.zarr while baking, moved into the output folder as {OUTPUT_STORE_NAME} at the end")
    p.add_argument("--window", type=float, default=None, help="KD window [s] (overrides the shot's)")
    p.add_argument("--max-memory", default=None, metavar="SIZE",
                   help="memory budget of a task's KD batch, e.g. 4G (default: half a worker's available memory)")
    from ..shots.run import add_max_steps_option

    add_max_steps_option(p)
    p.add_argument("--json", action="store_true", help="print summary.json to stdout")
    add_export_option(p)
    p.set_defaults(func=_bake_command)
