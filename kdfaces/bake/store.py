"""The bake's on-disk store: the final trajectory of every frame, float32, in a chunked zarr (v3) group.

Layout of a store folder::

    zarr.json            group attributes: "kdfaces_bake" = {format, key, frames, vertices, chunk_frames, ...}
    positions/           float32 (F, N, 3) [m], chunks of (K, N, 3): one chunk per bake task
    times/               float64 (F,) frame times [s]
    chunk_keys/          uint64 (C,), one chunk per element: chunk i is complete when its element holds
                         chunk_key(key, i, lo, hi, content_digest(positions)), written after the chunk's positions

``key`` identifies what the store holds (the shot's content, the solved correction, the window, the step and the
code that computes the frames; see :func:`kdfaces.bake.bake_shot`); a chunk's mark adds its frame range and a
checksum (SHA-256) of the float32 bytes it holds. Every zarr chunk file is written atomically (a temporary file
renamed into place), the store is created in a temporary sibling and renamed into place, so a store read at any
moment (a killed worker, Ctrl-C) holds whole chunks and says which of them are complete.

A store damaged after its chunks were marked (a chunk file lost in an interrupted copy, cut short, or replaced by
another chunk's file) is detected: :meth:`BakeStore.complete` reads every chunk back and compares its checksum
with the mark, a chunk that cannot be read or does not match counts as not baked (the bake recomputes it), and
:meth:`BakeStore.iter_chunks` checks each chunk again as it hands it out. zarr reads a missing chunk file as its
fill value (zeros), so without the checksum such a store would read as a complete take of wrong frames.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ..errors import KDInputError, KDIOError
from ..io.atomic import remove_stale_siblings, tagged_sibling_prefix

__all__ = ["BakeStore", "chunk_key", "content_digest", "STORE_FORMAT"]

#: Version of the store layout; a store of another format is rebuilt (format 2: marks hold a content checksum).
STORE_FORMAT = 2
_ATTR = "kdfaces_bake"


def content_digest(positions) -> str:
    """SHA-256 (hex) of a chunk's positions as the store holds them: float32, C order, (k, N, 3)."""
    x = np.ascontiguousarray(positions, dtype=np.float32)
    return hashlib.sha256(x.tobytes()).hexdigest()


def chunk_key(key: str, index: int, lo: int, hi: int, digest: str = "") -> int:
    """The completion mark of chunk ``index`` (frames ``lo``..``hi`` − 1, content checksum ``digest`` from
    :func:`content_digest`) of a store with ``key``: 64 bits of a SHA-256, never 0 (the fill value of an unwritten
    mark)."""
    h = hashlib.sha256(f"{key}:{index}:{lo}:{hi}:{digest}".encode()).digest()
    return int.from_bytes(h[:8], "little") or 1


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
            remove_stale_siblings(path, kinds=("creating",))  # a killed create's leftovers
            tmp = Path(tempfile.mkdtemp(prefix=tagged_sibling_prefix(path, "creating"), dir=path.parent))
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

    def expected_key(self, index: int, positions) -> int:
        """The completion mark chunk ``index`` holds once ``positions`` (hi − lo, N, 3) are written into it."""
        return chunk_key(self.key, index, *self.chunk_range(index), content_digest(positions))

    def marks(self) -> np.ndarray:
        """(C,) uint64: each chunk's completion mark as stored (0: never marked, or its mark file is lost)."""
        arr = self._group["chunk_keys"]
        try:
            return np.asarray(arr[:], dtype=np.uint64)
        except Exception:  # a damaged mark file (cut short, junk): read them one by one, a damaged one reads 0
            out = np.zeros(self.num_chunks, dtype=np.uint64)
            for i in range(self.num_chunks):
                try:
                    out[i] = np.uint64(arr[i])
                except Exception:
                    pass
            return out

    def _verified(self, index: int, mark) -> np.ndarray | None:
        """Chunk ``index``'s positions when they read back and match ``mark``, else None (damaged or not baked)."""
        if int(mark) == 0:
            return None
        try:
            x = self.read_chunk(index)
        except Exception:  # a chunk file cut short or replaced by junk: the codec raises, whatever its type
            return None
        if x.shape != (self.chunk_range(index)[1] - self.chunk_range(index)[0], self.vertices, 3):
            return None
        return x if int(mark) == self.expected_key(index, x) else None

    def complete(self, indices=None) -> np.ndarray:
        """(C,) bool: which chunks are written, marked, and read back with the checksum their mark records (each
        chunk is read once: O(store size)). ``indices``: check only these chunks (the others read False)."""
        marks = self.marks()
        out = np.zeros(self.num_chunks, dtype=bool)
        for i in range(self.num_chunks) if indices is None else indices:
            out[i] = self._verified(i, marks[i]) is not None
        return out

    # --- chunks ----------------------------------------------------------------------------------------------------
    def write_chunk(self, index: int, positions) -> None:
        """Write chunk ``index``'s positions [m], (hi − lo, N, 3), stored as float32, then its completion mark (with
        the checksum of what was written)."""
        lo, hi = self.chunk_range(index)
        x = np.asarray(positions)
        if x.shape != (hi - lo, self.vertices, 3):
            raise KDInputError(f"{self.path}: chunk {index}: expected positions of shape {(hi - lo, self.vertices, 3)}"
                               f", got {x.shape}")
        x32 = np.ascontiguousarray(x, dtype=np.float32)
        self._group["positions"][lo:hi] = x32
        self._group["chunk_keys"][index] = np.uint64(self.expected_key(index, x32))

    def read_chunk(self, index: int) -> np.ndarray:
        """Chunk ``index``'s positions [m], (hi − lo, N, 3), float32, as stored (unchecked: see :meth:`iter_chunks`)."""
        lo, hi = self.chunk_range(index)
        return np.asarray(self._group["positions"][lo:hi])

    def iter_chunks(self):
        """Every chunk's positions in frame order, one (k, N, 3) float32 array at a time (bounded memory), each
        checked against its mark as it is read; raises :class:`KDInputError` at the first chunk not baked, and
        :class:`KDIOError` at one whose content does not match its mark (damaged since it was written)."""
        marks = self.marks()
        for i in range(self.num_chunks):
            lo, hi = self.chunk_range(i)
            if int(marks[i]) == 0:
                raise KDInputError(f"{self.path}: chunk {i} (frames {lo}..{hi - 1}) is not baked yet")
            x = self._verified(i, marks[i])
            if x is None:
                raise KDIOError(f"{self.path}: chunk {i} (frames {lo}..{hi - 1}) is damaged (its content does not "
                                "match its checksum); rerun the bake to recompute it")
            yield x

    def read(self) -> np.ndarray:
        """Every frame's positions [m], (F, N, 3), float32 (the whole take in memory: for short takes and tests)."""
        return np.concatenate(list(self.iter_chunks()))
