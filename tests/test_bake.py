"""The Dask bake (library): chunks computed by worker processes equal the single-process KD bit for bit (a keyed
shot and a stretch of the real capture), a worker killed mid-task changes nothing, an interrupted bake resumes with
only its missing chunks, and the store refuses what is not its own. One two-worker local cluster serves the module
(``scheduler=`` its address, the path an existing cluster takes)."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from kdfaces import KDInputError
from kdfaces.bake import BakeStore, bake_shot, chunk_key
from kdfaces.shots import run_shot

DEMO = Path(__file__).resolve().parents[1] / "kdfaces" / "shots" / "demo.toml"
# the demo's animation and dynamics without its constraints: KD only, 151 frames, δ = 0.83 s (21 steps)
PLAIN = DEMO.read_text().split("[[constraints]]")[0].replace('name = "demo"', 'name = "plain"')
CAPTURE = """name = "capture"
[animation]
source = "{take}"
start_s = 70.0
end_s = 73.0
fps = 30
[dynamics]
settle_time_s = {{ stiff_s = 0.2, loose_s = 0.45 }}
damping_ratio = 0.3
"""


@pytest.fixture(scope="module")
def cluster():
    import logging

    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR) as c, Client(c, set_as_default=False) as client:
        yield c.scheduler_address, client


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """The plain shot file and its single-process KD (``kdfaces run``'s path), float32."""
    shot = tmp_path_factory.mktemp("plain") / "plain.toml"
    shot.write_text(PLAIN)
    return shot, run_shot(shot, solve=False).final.astype(np.float32)


def _executing(dask_worker):
    return [str(ts.key) for ts in dask_worker.state.executing]


def _wait_idle(client, timeout_s: float = 30.0) -> None:
    """Until no worker executes a task (a cancelled task that was running still finishes, writing its chunk)."""
    t0 = time.perf_counter()
    while any(client.run(_executing).values()):
        assert time.perf_counter() - t0 < timeout_s
        time.sleep(0.05)


def test_bake_equals_the_single_process_kd_and_a_rerun_skips_everything(cluster, plain, tmp_path):
    shot, reference = plain
    store = tmp_path / "store.zarr"
    r = bake_shot(shot, store, scheduler=cluster[0], chunk_frames=8)
    assert (r.frames, r.chunks, r.computed, r.skipped) == (151, 19, 19, 0)
    assert sorted(t["index"] for t in r.tasks) == list(range(19))  # each chunk computed once
    x = BakeStore.open(store).read()
    assert x.dtype == np.float32 and x.shape == reference.shape
    assert np.array_equal(x, reference)  # bit for bit: batching does not change a KD state
    again = bake_shot(shot, store, scheduler=cluster[0], chunk_frames=8)
    assert (again.computed, again.skipped, again.key) == (0, 19, r.key)
    # another chunking is another store layout: rebuilt, same numbers
    other = bake_shot(shot, store, scheduler=cluster[0], chunk_frames=40)
    assert (other.computed, other.skipped) == (4, 0)
    assert np.array_equal(BakeStore.open(store).read(), reference)


def test_a_worker_killed_mid_task_is_retried(cluster, plain, tmp_path):
    address, client = cluster
    shot, reference = plain
    killed = []

    def kill_one(record):
        if killed:
            return
        pids = client.run(os.getpid)
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 10:  # a worker in the middle of a bake task
            busy = [a for a, keys in client.run(_executing).items() if any("kdfaces-bake-" in k for k in keys)]
            if busy:
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(pids[busy[0]])
                return
            time.sleep(0.01)

    r = bake_shot(shot, tmp_path / "store.zarr", scheduler=address, chunk_frames=8, callback=kill_one)
    assert killed, "no worker was caught running a task"
    assert sorted(t["index"] for t in r.tasks) == list(range(r.chunks))  # nothing lost, nothing twice
    st = BakeStore.open(r.store)
    assert st.complete().all()
    assert np.array_equal(st.read(), reference)
    client.wait_for_workers(2, timeout=60)  # the nanny restarted it, for the tests that follow


def test_an_interrupted_bake_resumes_with_only_the_missing_chunks(cluster, plain, tmp_path):
    address, client = cluster
    shot, reference = plain
    store = tmp_path / "store.zarr"
    seen = []

    def interrupt(record):
        seen.append(record["index"])
        if len(seen) == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        bake_shot(shot, store, scheduler=address, chunk_frames=8, callback=interrupt)
    _wait_idle(client)
    kept = int(BakeStore.open(store).complete().sum())
    assert 3 <= kept < 19
    r = bake_shot(shot, store, scheduler=address, chunk_frames=8)
    assert r.skipped == kept and r.computed == 19 - kept
    assert not set(t["index"] for t in r.tasks) & set(seen)
    assert np.array_equal(BakeStore.open(store).read(), reference)


def test_a_capture_stretch_bakes_bit_for_bit(cluster, llf_take_path, tmp_path):
    shot = tmp_path / "capture.toml"
    shot.write_text(CAPTURE.format(take=llf_take_path))
    reference = run_shot(shot, solve=False).final.astype(np.float32)
    r = bake_shot(shot, tmp_path / "store.zarr", scheduler=cluster[0], chunk_frames=16)
    assert r.frames == len(reference) == 91
    assert np.array_equal(BakeStore.open(r.store).read(), reference)
    peak = r.summary()["max_worker_peak_rss_bytes"]
    assert 0 < peak < 1 << 30  # a worker holds the shot and about two chunks' windows, not the take (~0.3 GiB)


def test_the_store_says_which_chunks_are_complete(tmp_path):
    t = np.arange(10) / 25.0
    st = BakeStore.create(tmp_path / "s.zarr", key="k1", times=t, vertices=4, chunk_frames=4)
    assert (st.num_chunks, st.chunk_range(2)) == (3, (8, 10))
    assert not st.complete().any()
    x = np.arange(2 * 4 * 3, dtype=np.float64).reshape(2, 4, 3) + 0.1
    st.write_chunk(2, x)
    assert st.complete().tolist() == [False, False, True]
    assert np.array_equal(st.read_chunk(2), x.astype(np.float32))
    assert np.array_equal(BakeStore.open(st.path).times, t)
    with pytest.raises(KDInputError, match="chunk 0 .* not baked"):
        BakeStore.open(st.path).read()
    with pytest.raises(KDInputError, match="expected positions of shape"):
        st.write_chunk(0, x)
    # a mark is tied to the key and the frame range
    assert chunk_key("k1", 2, 8, 10) != chunk_key("k2", 2, 8, 10) != chunk_key("k1", 2, 8, 9)
    assert BakeStore.create(st.path, key="k2", times=t, vertices=4, chunk_frames=4).complete().sum() == 0


def test_a_store_never_replaces_a_folder_that_is_not_a_store(tmp_path):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("keep me")
    with pytest.raises(KDInputError, match="not a bake store"):
        BakeStore.create(folder, key="k", times=np.arange(3.0), vertices=2, chunk_frames=2)
    assert (folder / "notes.txt").read_text() == "keep me"
    with pytest.raises(KDInputError, match="not a bake store"):
        BakeStore.open(folder)


def test_bad_bake_arguments(tmp_path):
    with pytest.raises(KDInputError, match="chunk_frames"):
        bake_shot(DEMO, tmp_path / "s", chunk_frames=0)
    with pytest.raises(KDInputError, match="not both"):
        bake_shot(DEMO, tmp_path / "s", workers=2, scheduler="tcp://127.0.0.1:1")
    with pytest.raises(KDInputError, match="file not found"):
        bake_shot(tmp_path / "missing.toml", tmp_path / "s")
    assert not (tmp_path / "s").exists()
