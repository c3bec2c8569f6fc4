"""The bake's on-disk store: the final trajectory of every frame, float32, in a chunked zarr (v3) group.

Layout of a store folder::

    zarr.json            group attributes: "kdfaces_bake" = {format, key, frames, vertices, chunk_frames, ...}
    positions/           float32 (F, N, 3) [m], chunks of (K, N, 3): one chunk per bake task
    times/               float64 (F,) frame times [s]
    chunk_keys/          uint64 (C,), one chunk per element: chunk i is complete when its element holds
                         chunk_key(key, i), written after the chunk's positions

``key`` identifies what the store holds (the shot's content, the solved correction, the window, the step and the
code that computes the frames; see :func:`kdfaces.bake.bake_shot`); a chunk's key adds its frame range. Every zarr
chunk file is written atomically (a temporary file renamed into place), the store is created in a temporary
sibling and renamed into place, so a store read at any moment (a killed worker, Ctrl-C) holds whole chunks and
says which of them are complete.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ..errors import KDInputError, KDIOError

__all__ = ["BakeStore", "chunk_key", "STORE_FORMAT"]

#: Version of the store layout; a store of another format is rebuilt.
STORE_FORMAT = 1
_ATTR = "kdfaces_bake"


def chunk_key(key: str, index: int, lo: int, hi: int) -> int:
    """The completion mark of chunk ``index`` (frames ``lo``..``hi`` − 1) of a store with ``key``: 64 bits of a
    SHA-256, never 0 (the fill value of an unwritten mark)."""
    digest = hashlib.sha256(f"{key}:{index}:{lo}:{hi}".encode()).digest()
    return int.from_bytes(digest[:8], "little") or 1


class BakeStore:
    """An open bake store (see the module docstring). Create one with :meth:`create`, open one with :meth:`open`.

    Attributes:
        path: the store folder.
        meta: the ``kdfaces_bake`` attributes (key, frames, vertices, chunk_frames and what the bake recorded).
    """

    def __init__(self, path, group, meta: dict):
        self.path = Path(path)
        self._group = group
        self.meta = meta

    # --- opening ---------------------------------------------------------------------------------------------------
    @classmethod
    def create(cls, path, *, key: str, times, vertices: int, chunk_frames: int, meta: dict | None = None
               ) -> BakeStore:
        """A new, empty store at ``path`` (replacing a bake store there) for frames at ``times`` (F,) [s] of
        ``vertices`` points, in chunks of ``chunk_frames`` frames. It is built in a temporary sibling and renamed
        into place, so ``path`` never holds a half-made store. ``meta``: more attributes to record."""
        import zarr

        path = Path(path)
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        k = int(chunk_frames)
        if len(t) == 0 or k < 1 or int(vertices) < 1:
            raise KDInputError(f"{path}: a bake store needs frames, vertices and chunk_frames ≥ 1")
        if path.exists():
            cls._check_replaceable(path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.creating-", dir=path.parent))
        except OSError as e:
            raise KDIOError(f"{path}: cannot create the bake store ({e.strerror})") from None
        try:
            g = zarr.open_group(store=str(tmp), mode="w", zarr_format=3)
            chunks = -(-len(t) // k)
            attrs = {**(meta or {}), "format": STORE_FORMAT, "key": key, "frames": len(t), "vertices": int(vertices),
                     "chunk_frames": k, "chunks": chunks}
            g.attrs[_ATTR] = attrs
            g.create_array("positions", shape=(len(t), int(vertices), 3), chunks=(k, int(vertices), 3),
                           dtype="float32", fill_value=0.0)
            g.create_array("times", shape=(len(t),), chunks=(len(t),), dtype="float64", fill_value=0.0)[:] = t
            g.create_array("chunk_keys", shape=(chunks,), chunks=(1,), dtype="uint64", fill_value=0)
            if path.exists():
                shutil.rmtree(path)
            os.replace(tmp, path)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return cls.open(path, mode="r+")

    @classmethod
    def open(cls, path, *, mode: str = "r") -> BakeStore:
        """Open the store at ``path`` (``mode`` "r" to read, "r+" to write chunks)."""
        import zarr

        path = Path(path)
        if not (path / "zarr.json").is_file():
            raise KDInputError(f"{path}: not a bake store (no zarr.json); expected the folder `kdfaces bake` wrote")
        try:
            g = zarr.open_group(store=str(path), mode=mode, zarr_format=3)
            meta = dict(g.attrs[_ATTR])
        except (KeyError, ValueError, OSError) as e:
            raise KDInputError(f"{path}: not a readable bake store ({e})") from None
        return cls(path, g, meta)

    @classmethod
    def _check_replaceable(cls, path: Path) -> None:
        """Refuse to replace anything but a bake store (a mistyped --store must not delete a user's folder)."""
        if path.is_dir() and not any(path.iterdir()):
            return
        try:
            cls.open(path)
        except KDInputError:
            raise KDInputError(f"{path}: exists and is not a bake store; give another --store path or remove it") \
                from None

    # --- what it holds ------------------------------------------------------------------------------------------
    @property
    def key(self) -> str:
        """What the store holds (see the module docstring)."""
        return str(self.meta["key"])

    @property
    def frames(self) -> int:
        """Number of frames F."""
        return int(self.meta["frames"])

    @property
    def vertices(self) -> int:
        """Points per frame N."""
        return int(self.meta["vertices"])

    @property
    def chunk_frames(self) -> int:
        """Frames per chunk K (the last chunk may hold fewer)."""
        return int(self.meta["chunk_frames"])

    @property
    def num_chunks(self) -> int:
        """Number of chunks C = ceil(F / K)."""
        return int(self.meta["chunks"])

    @property
    def times(self) -> np.ndarray:
        """Frame times [s], (F,)."""
        return np.asarray(self._group["times"][:], dtype=np.float64)

    def chunk_range(self, index: int) -> tuple[int, int]:
        """Frames ``lo``..``hi`` − 1 of chunk ``index``, as (lo, hi)."""
        if not 0 <= index < self.num_chunks:
            raise KDInputError(f"{self.path}: chunk {index} outside 0..{self.num_chunks - 1}")
        lo = index * self.chunk_frames
        return lo, min(lo + self.chunk_frames, self.frames)

    def expected_key(self, index: int) -> int:
        """The completion mark chunk ``index`` holds once it is written."""
        return chunk_key(self.key, index, *self.chunk_range(index))

    def complete(self) -> np.ndarray:
        """(C,) bool: which chunks are written and marked with their key."""
        marks = np.asarray(self._group["chunk_keys"][:], dtype=np.uint64)
        want = np.array([self.expected_key(i) for i in range(self.num_chunks)], dtype=np.uint64)
        return marks == want

    # --- chunks ----------------------------------------------------------------------------------------------------
    def write_chunk(self, index: int, positions) -> None:
        """Write chunk ``index``'s positions [m], (hi − lo, N, 3), stored as float32, then its completion mark."""
        lo, hi = self.chunk_range(index)
        x = np.asarray(positions)
        if x.shape != (hi - lo, self.vertices, 3):
            raise KDInputError(f"{self.path}: chunk {index}: expected positions of shape {(hi - lo, self.vertices, 3)}"
                               f", got {x.shape}")
        self._group["positions"][lo:hi] = x.astype(np.float32)
        self._group["chunk_keys"][index] = np.uint64(self.expected_key(index))

    def read_chunk(self, index: int) -> np.ndarray:
        """Chunk ``index``'s positions [m], (hi − lo, N, 3), float32."""
        lo, hi = self.chunk_range(index)
        return np.asarray(self._group["positions"][lo:hi])

    def iter_chunks(self):
        """Every chunk's positions in frame order, one (k, N, 3) float32 array at a time (bounded memory);
        raises :class:`KDInputError` at the first incomplete chunk."""
        done = self.complete()
        for i in range(self.num_chunks):
            if not done[i]:
                lo, hi = self.chunk_range(i)
                raise KDInputError(f"{self.path}: chunk {i} (frames {lo}..{hi - 1}) is not baked yet")
            yield self.read_chunk(i)

    def read(self) -> np.ndarray:
        """Every frame's positions [m], (F, N, 3), float32 (the whole take in memory: for short takes and tests)."""
        return np.concatenate(list(self.iter_chunks()))
