"""Persistent worker threads for the face step: the calling thread and ``count`` workers each run one task per
round (one step of a batch split by members, or of one state split by vertices). Warp's CPU launches release the
GIL, so the tasks run on separate cores."""

from __future__ import annotations

import queue
import threading
import time

__all__ = ["Workers"]


class Workers:
    """``count`` persistent threads that each run one task per round, while the calling thread runs the first.

    Each worker reads its own FIFO inbox and answers on a shared outbox: a round costs a few microseconds per
    thread, against a pool submit and a future per thread per step. A task's exception is re-raised in the caller
    after the round. A round interrupted in the caller (Ctrl-C) is still finished by the workers before the
    interrupt leaves :meth:`run`: a kernel must never be left running while the interpreter unwinds and exits.
    """

    def __init__(self, count: int):
        self._inboxes = [queue.SimpleQueue() for _ in range(count)]
        self._outbox: queue.SimpleQueue = queue.SimpleQueue()
        self._lock = threading.Lock()  # one round at a time (two callers on one system take turns)
        self._threads = [threading.Thread(target=self._loop, args=(box,), daemon=True,
                                          name=f"kdfaces-face-worker-{k}") for k, box in enumerate(self._inboxes)]
        self._closed = False
        for t in self._threads:
            t.start()

    def _loop(self, inbox) -> None:
        while True:
            task = inbox.get()
            if task is None:
                return
            try:
                task()
                error = None
            except BaseException as e:  # noqa: BLE001 - handed to the caller
                error = e
            self._outbox.put(error)

    def run(self, tasks) -> None:
        """Run ``tasks[0]`` here and ``tasks[1:]`` on the workers; return when all are done."""
        extra = list(tasks[1:])
        if len(extra) > len(self._inboxes):
            raise ValueError(f"{len(tasks)} tasks for {len(self._inboxes) + 1} threads")
        with self._lock:
            try:
                for box, task in zip(self._inboxes, extra):
                    box.put(task)
                tasks[0]()
                errors = [self._outbox.get() for _ in extra]
            except BaseException:
                self._settle()
                raise
        for e in errors:
            if e is not None:
                raise e

    def _settle(self) -> None:
        """Wait until every worker has finished what it was handed (each inbox is FIFO: a marker queued behind the
        round's task runs after it), then drop the round's answers. Further interrupts meanwhile are held back and
        the first one raised at the end; the wait is bounded (an hour) so a hung kernel cannot hang the exit."""
        pending = None
        markers = [threading.Event() for _ in self._inboxes]
        for box, marker in zip(self._inboxes, markers):
            while True:
                try:
                    box.put(marker.set)
                    break
                except KeyboardInterrupt as e:
                    pending = pending or e
        deadline = time.monotonic() + 3600.0
        for marker in markers:
            while time.monotonic() < deadline:
                try:
                    if marker.wait(timeout=1.0):
                        break
                except KeyboardInterrupt as e:
                    pending = pending or e
        while True:
            try:
                self._outbox.get_nowait()
            except queue.Empty:
                break
        if pending is not None:
            raise pending

    def close(self) -> None:
        """Stop the threads (idempotent); a task still running is finished first (bounded wait)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            for box in self._inboxes:
                box.put(None)
            me = threading.current_thread()
            for t in self._threads:
                if t is not me:
                    t.join(timeout=5.0)
