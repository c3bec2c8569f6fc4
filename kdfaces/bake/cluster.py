"""Where a bake runs: the Dask cluster (a new local one, or an existing scheduler whose address is checked before
anything is read) and the plan of chunks and workers, checked against memory before anything starts."""

from __future__ import annotations

import contextlib
import logging
import os

from .. import defaults
from ..errors import KDInputError, KDIOError

__all__ = ["SCHEDULER_TIMEOUT_S", "WORKER_BASE_BYTES", "check_scheduler_address", "plan_bake"]


#: How long a ``--scheduler`` address may take to answer Dask's handshake before the bake gives up [s].
SCHEDULER_TIMEOUT_S = 2.0
_SCHEMES = ("tcp", "tls", "inproc", "ucx", "ws", "wss")


def check_scheduler_address(scheduler) -> str:
    """``scheduler`` when it has the form of a Dask scheduler address (``tcp://host:8786``, ``tls://…``, or
    ``host:port``), else :class:`KDInputError` naming what is wrong (an empty string, a dashboard ``http://`` link,
    no port, a port outside 1–65535). Nothing is contacted."""
    from distributed.comm.addressing import parse_address, parse_host_port

    what = f"--scheduler {scheduler!r}"
    if not isinstance(scheduler, str) or not scheduler.strip():
        raise KDInputError(f"{what}: expected a Dask scheduler address such as tcp://host:8786")
    addr = scheduler.strip()
    scheme = addr.split("://", 1)[0].lower() if "://" in addr else "tcp"
    if scheme in ("http", "https"):
        raise KDInputError(f"{what}: that is a web (dashboard) address; give the scheduler's own address, such as "
                           "tcp://host:8786 (the dashboard's page lists it)")
    if scheme not in _SCHEMES:
        raise KDInputError(f"{what}: unknown scheme {scheme!r}; expected one of {', '.join(_SCHEMES)}, such as "
                           "tcp://host:8786")
    if scheme != "inproc":
        try:
            _, loc = parse_address(addr if "://" in addr else f"tcp://{addr}")
            host, port = parse_host_port(loc)
        except (ValueError, TypeError):
            host, port = None, None
        if not host or not isinstance(port, int) or not 1 <= port <= 65535:
            raise KDInputError(f"{what}: expected host:port with a port in 1..65535, such as tcp://host:8786")
    return addr


def _connect(scheduler: str):
    """A client of the existing Dask scheduler at ``scheduler`` (the cluster is used as it is). The address is
    checked first (:func:`check_scheduler_address`), then Dask's handshake with it must complete within
    :data:`SCHEDULER_TIMEOUT_S`: a wrong host, a closed port or a port that speaks another protocol (a web server)
    is one clear error within about that time, and no client is made that would wait on it at exit."""
    import asyncio

    from distributed import Client
    from distributed.comm import connect

    addr = check_scheduler_address(scheduler)

    async def handshake():
        comm = await asyncio.wait_for(connect(addr, timeout=SCHEDULER_TIMEOUT_S * 0.75), SCHEDULER_TIMEOUT_S)
        await comm.close()

    why = None
    try:
        asyncio.run(handshake())
    except (KeyboardInterrupt, SystemExit):
        raise
    except TimeoutError:
        why = f"no Dask scheduler answered within {SCHEDULER_TIMEOUT_S:g} s"
    except OSError as e:  # refused or unreachable: Dask retries until its own timeout, then says "Timed out"
        why = (f"no Dask scheduler answered within {SCHEDULER_TIMEOUT_S:g} s" if "timed out" in str(e).lower()
               else str(e).splitlines()[0] or type(e).__name__)
    except BaseException as e:  # OSError (refused, unknown host), or a peer that sent junk (MemoryError, ValueError)
        why = str(e).splitlines()[0] if str(e) else type(e).__name__
    if why is not None:
        raise KDIOError(f"--scheduler {addr}: cannot connect to a Dask scheduler there ({why})")
    try:
        return Client(addr, timeout=f"{SCHEDULER_TIMEOUT_S}s", set_as_default=False)
    except (OSError, TimeoutError) as e:
        raise KDIOError(f"--scheduler {addr}: cannot connect to a Dask scheduler there ({e})") from None


@contextlib.contextmanager
def _dask(workers: int | None, client):
    """(client, workers, dashboard): ``client`` (of an existing cluster, left open), or a client of a new local
    cluster of ``workers`` single-threaded processes (default one per core), closed on exit."""
    import importlib.util

    from distributed import Client, LocalCluster

    cluster = None
    if client is None:
        n = workers or os.cpu_count() or 1
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=logging.ERROR)
        client = Client(cluster, set_as_default=False)
        client.register_plugin(_quiet_plugin())
    try:
        info = client.scheduler_info()
        count = len(info.get("workers", {}))
        if count == 0:
            client.wait_for_workers(1, timeout=60)
            count = len(client.scheduler_info().get("workers", {}))
        has_dashboard = "dashboard" in info.get("services", {}) and (
            cluster is None or importlib.util.find_spec("bokeh") is not None)
        yield client, count, (client.dashboard_link if has_dashboard else None)
    finally:
        if cluster is not None:
            log = logging.getLogger("distributed")
            level = log.level
            log.setLevel(logging.CRITICAL)  # closing talks about every worker it stops
            try:
                client.close()
                cluster.close()
            finally:
                log.setLevel(level)


def _quiet_plugin():
    from .tasks import quiet_worker_plugin

    return quiet_worker_plugin()


#: Resident memory of one bake worker process before its first chunk (Python, numpy, Warp, Dask; measured about
#: 0.3 GiB, see BENCHMARKS.md) [bytes]: the unit of the ``--workers`` estimate.
WORKER_BASE_BYTES = 350 << 20


def plan_bake(frames: int, vertices: int, chunk_frames: int, workers: int | None, *, local: bool = True,
              available_bytes: int | None = None) -> tuple[int, int | None]:
    """(chunk_frames, workers) for a bake of ``frames`` frames of ``vertices`` points, checked against memory before
    anything starts: ``chunk_frames`` beyond the take is the whole take (one chunk); a task holds its chunk's
    positions in float64 and float32 (12 bytes per coordinate); each local worker costs :data:`WORKER_BASE_BYTES`
    plus one task. Raises :class:`KDInputError` naming ``--chunk-frames`` or ``--workers`` and the largest value that
    fits when the plan does not fit ``available_bytes`` (default: the machine's available memory). ``workers`` None
    with ``local``: one per core, as many as fit and have a chunk; not ``local`` (an existing scheduler): None, and
    only the task is checked (against this machine's memory: the workers' own is not known here)."""
    from ..resources import available_memory_bytes, format_bytes

    avail = available_memory_bytes() if available_bytes is None else int(available_bytes)
    k = min(int(chunk_frames), int(frames))
    per_frame = 12 * 3 * int(vertices)
    task = k * per_frame
    if WORKER_BASE_BYTES + task > avail:
        fit = max(0, (avail - WORKER_BASE_BYTES) // per_frame)
        raise KDInputError(f"--chunk-frames {chunk_frames}: a task would hold {format_bytes(task)} ({k:,} frames × "
                           f"{vertices:,} vertices) and {format_bytes(avail)} is available; give --chunk-frames "
                           f"{max(1, fit):,} or fewer (default {defaults.BAKE_CHUNK_FRAMES})")
    chunks = -(-int(frames) // k)
    n = workers
    if n is None and local:
        return k, max(1, min(os.cpu_count() or 1, chunks, avail // (WORKER_BASE_BYTES + task)))
    if n is not None:
        need = n * (WORKER_BASE_BYTES + task)
        if need > avail:
            fit = max(1, avail // (WORKER_BASE_BYTES + task))
            raise KDInputError(f"--workers {n}: {n:,} worker processes need about {format_bytes(need)} "
                               f"({format_bytes(WORKER_BASE_BYTES + task)} each) and {format_bytes(avail)} is "
                               f"available; give --workers {fit:,} or fewer")
        n = min(n, chunks)  # a worker without a chunk would only cost start-up time
    return k, n
