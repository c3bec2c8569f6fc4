"""A bake store damaged after its chunks were marked complete is never trusted: each kind of damage (a chunk file
lost in an interrupted copy, one cut short, one replaced by another chunk's file, a flipped byte, a lost completion
mark) is detected by the checksum each mark records, exactly the damaged chunks are recomputed, and the export then
has the same bytes as the fresh bake's. An export of a damaged store refuses in one error instead of writing
another chunk's frames or zeros."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from kdfaces import KDIOError
from kdfaces.bake import BakeStore, bake_shot, export_bake

DEMO = Path(__file__).resolve().parents[1] / "kdfaces" / "shots" / "demo.toml"
PLAIN = DEMO.read_text().split("[[constraints]]")[0].replace('name = "demo"', 'name = "plain"')
CHUNK_FRAMES = 16  # 151 frames: 10 chunks, the last one of 7 frames


@pytest.fixture(scope="module")
def cluster():
    import logging

    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR) as c, Client(c, set_as_default=False):
        yield c.scheduler_address


@pytest.fixture(scope="module")
def fresh(cluster, tmp_path_factory):
    """(shot path, a fresh complete store, its PC2 bytes)."""
    root = tmp_path_factory.mktemp("fresh")
    shot = root / "plain.toml"
    shot.write_text(PLAIN)
    store = root / "store.zarr"
    r = bake_shot(shot, store, scheduler=cluster, chunk_frames=CHUNK_FRAMES)
    assert (r.chunks, r.computed) == (10, 10)
    return shot, store, _pc2(store, r.shot, root / "export")


def _pc2(store, shot, out: Path) -> bytes:
    out.mkdir(parents=True, exist_ok=True)
    (path,) = export_bake(store, out, kinds=["pc2"], rig=shot.rig, name="plain", fps=shot.animation.fps)
    return path.read_bytes()


def _chunk_file(store: Path, index: int) -> Path:
    p = store / "positions" / "c" / str(index) / "0" / "0"
    assert p.is_file(), sorted(str(q.relative_to(store)) for q in (store / "positions").rglob("*"))
    return p


def _lose(store, i):
    _chunk_file(store, i).unlink()


def _cut(store, i):
    p = _chunk_file(store, i)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])


def _swap(store, i):
    shutil.copyfile(_chunk_file(store, i - 1), _chunk_file(store, i))  # the file of the chunk before it


def _flip(store, i):
    p = _chunk_file(store, i)
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0x10
    p.write_bytes(bytes(data))


def _lose_mark(store, i):
    (store / "chunk_keys" / "c" / str(i)).unlink()


DAMAGE = {"missing": _lose, "truncated": _cut, "another-chunk": _swap, "flipped-byte": _flip, "mark-lost": _lose_mark}


@pytest.mark.parametrize("kind", sorted(DAMAGE))
def test_each_kind_of_damage_is_detected_recomputed_and_exports_the_fresh_bytes(cluster, fresh, tmp_path, kind):
    shot, clean, reference = fresh
    store = tmp_path / "store.zarr"
    shutil.copytree(clean, store)
    damaged = [3, 9] if kind != "another-chunk" else [3, 8]  # 9 is the short last chunk
    for i in damaged:
        DAMAGE[kind](store, i)
    st = BakeStore.open(store)
    assert np.flatnonzero(~st.complete()).tolist() == damaged
    if kind != "mark-lost":
        with pytest.raises(KDIOError, match=f"chunk {damaged[0]} .* is damaged"):
            _pc2(store, _shot(shot), tmp_path / "refused")
    r = bake_shot(shot, store, scheduler=cluster, chunk_frames=CHUNK_FRAMES)
    assert sorted(t["index"] for t in r.tasks) == damaged and r.skipped == 10 - len(damaged)
    assert BakeStore.open(store).complete().all()
    assert _pc2(store, r.shot, tmp_path / "export") == reference


def _shot(path):
    from kdfaces.shots.shotfile import load_shot

    return load_shot(path)


def test_a_damaged_mark_file_untrusts_only_its_chunk(fresh, tmp_path):
    _, clean, _ = fresh
    store = tmp_path / "store.zarr"
    shutil.copytree(clean, store)
    mark = store / "chunk_keys" / "c" / "0"
    mark.write_bytes(b"\x00garbage")
    st = BakeStore.open(store)
    complete = st.complete()
    assert not complete[0] and complete[1:].all()
