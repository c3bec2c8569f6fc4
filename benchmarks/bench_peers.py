"""The peer benchmark: Fast Complementary Dynamics (``fast-cody`` 0.0.8, Benchekroun et al. 2023) against our face KD
on the same head and the same head motion, in one interleaved run (``scripts/bench.py --only peers``).

- **Isolation.** The peer runs in its own virtualenv, made on first use under ``~/.cache/kdfaces-bench/peers-venv``
  (``KDFACES_BENCH_CACHE`` moves it; never in the repo, never a dependency of ours) with what it needs pinned:
  :data:`PEER_REQUIREMENTS` (newer libigl changed its API; with scipy ≥ 1.14 its mass matrix comes back empty).
  Each side is its own child process (``peer_fastcd_worker.py`` in that venv, this file's ``--ours`` worker in ours)
  driven by JSON lines, so each process's peak memory is its own.
- **Same head, same motion, same steps.** The default head (4.8k vertices) and the default head subdivided once
  (:func:`kdfaces.rig.subdivide_rig`, ~19k). The motion is the demo's head turn and nod alone (its joint curves, no
  expressions: the peer has no blend shapes), 0–6 s at the demo's 25 fps; both step h = 1/25 s, one step per frame.
  The peer's tet mesh fills the head's volume with about as many nodes as the rig has vertices (a regular grid of
  cubes kept inside by winding number, :func:`peer_tets`; a Delaunay mesh of the rig's own vertices is all slivers,
  and its Laplacian eigenproblem is singular), its rig the head chain's skin weights (nearest vertex) plus the
  fixed body (weight 1 − Σw, identity transform), the bone world transforms of our forward kinematics, and its own
  defaults: 16 skinning modes (192 reduced DOFs), 100 clusters, μ = 1e4, ρ = 1e3 at unit height, as its app sets up.
  Ours: ``FaceModel.from_rig(rig)`` with its defaults (a proxy where the library turns one on), δ = the automatic
  window (:func:`kdfaces.window.automatic_window`).
- **Rows** (medians of :data:`ROUNDS` interleaved rounds; in a round each side plays, then each scrubs):
  ``peer_fastcd_play`` (ms per step of play-forward; ours beside it both as a full simulation per step and as a KD
  batch of all 151 frames on 2 threads per frame, and on the 19k head also that batch on a 6k-vertex proxy,
  :data:`PROXY_VERTICES`, in a process of its own), ``peer_fastcd_scrub`` (ms to show t = 3 s: ours one KD state,
  the peer simulating from the start, the only way it gets that frame right), ``peer_fastcd_memory`` (each process's
  peak resident memory, MiB) and ``peer_fastcd_history`` (does frame t depend on how the user got there: ours, the
  largest difference between the KD state at 3 s scrubbed first and scrubbed after playing and scrubbing elsewhere,
  and the batch's frame; the peer, the largest node distance between frame 3 s played from the start and reached
  by a jump the way its app jumps — state kept, the frame's rig pose set, one step — from 0, 1, 2 and 5 s).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

#: what the peer needs, pinned in its own virtualenv
PEER_REQUIREMENTS = ("fast-cody==0.0.8", "libigl==2.5.1", "numpy==1.26.4", "scipy==1.13.1")
#: interleaved rounds; the rows are their medians
ROUNDS = 7
#: the scrub target [s]; the peer's jumps to it come from these times [s]
SCRUB_S, JUMP_FROM_S = 3.0, (0.0, 1.0, 2.0, 5.0)
#: the peer's subspace and material (its app's defaults: 16 modes × 12 = 192 reduced DOFs)
PEER_MODES, PEER_CLUSTERS, PEER_MU, PEER_RHO = 16, 100, 1e4, 1e3
#: (Loop levels, label) of the heads compared
SIZES = ((0, "4.8k"), (1, "19k"))
#: the proxy the subdivided head is also measured on (the accuracy tests' 6k: within ε/2 of the dense KD states)
PROXY_VERTICES = 6_000
HERE = Path(__file__).resolve().parent


def cache_root() -> Path:
    """Where the peer's virtualenv and its precomputations live (``KDFACES_BENCH_CACHE``, else
    ``~/.cache/kdfaces-bench``)."""
    return Path(os.environ.get("KDFACES_BENCH_CACHE", Path.home() / ".cache" / "kdfaces-bench"))


def peer_python() -> Path:
    """The peer virtualenv's python, made on first use (``python -m venv``, then pip with
    :data:`PEER_REQUIREMENTS`); a marker file records the pins, so a change of pins remakes it."""
    venv = cache_root() / "peers-venv"
    py = venv / "bin" / "python"
    marker = venv / "kdfaces-peer-requirements.txt"
    want = "\n".join(PEER_REQUIREMENTS) + "\n"
    if py.exists() and marker.exists() and marker.read_text() == want:
        return py
    import shutil

    shutil.rmtree(venv, ignore_errors=True)
    venv.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    subprocess.run([str(py), "-m", "pip", "install", "-q", *PEER_REQUIREMENTS], check=True)
    check = ("import importlib.metadata as m, numpy, scipy, fast_cody; "
             "print(m.version('libigl'), numpy.__version__, scipy.__version__, fast_cody.__version__)")
    got = subprocess.run([str(py), "-c", check], check=True, capture_output=True, text=True).stdout.split()
    pins = [r.split("==")[1] for r in PEER_REQUIREMENTS]
    if got != [pins[1], pins[2], pins[3], pins[0]]:
        raise RuntimeError(f"peer virtualenv {venv}: expected libigl, numpy, scipy, fast-cody {pins[1:] + pins[:1]}, "
                           f"got {got}")
    marker.write_text(want)
    return py


def head_motion_animation():
    """The demo's head turn and nod alone: its skeleton curves, no shape tracks, same span and fps."""
    import dataclasses

    from kdfaces.shots.builtin import demo_animation

    return dataclasses.replace(demo_animation(), tracks=(), name="head turn and nod")


def _rig(levels: int):
    from kdfaces import load_default_rig
    from kdfaces.rig import subdivide_rig

    rig = load_default_rig()
    return rig if levels == 0 else subdivide_rig(rig, levels)


def peer_tets(rig, nodes: int | None = None):
    """The peer's tet mesh of ``rig``'s head: a regular grid of cubes (six tets each, the Kuhn split, so neighbours
    conform) over the neutral mesh's bounding box, the cubes kept whose centre libigl's fast winding number puts
    inside the head (the open neck counts as closed), unused nodes dropped, the largest connected piece kept. The
    spacing is chosen so the node count is about ``nodes`` (default the rig's vertex count: as many degrees of
    freedom as ours). Returns nodes (n, 3) [m] and tets (t, 4)."""
    import igl
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from kdfem.geometry.tetmesh import structured_bar

    X = np.asarray(rig.neutral, dtype=np.float64)
    F = np.asarray(rig.faces, dtype=np.int64)
    target = int(nodes or rig.num_vertices)
    lo, hi = X.min(axis=0), X.max(axis=0)
    ext = hi - lo

    def mesh(spacing):
        n = np.maximum(1, np.ceil(ext / spacing).astype(int))
        bar = structured_bar(*(n * spacing), *n)
        V = bar.nodes + lo - 0.5 * (n * spacing - ext)
        T = bar.tets
        inside = igl.fast_winding_number(X, F, V[T].mean(axis=1)) > 0.5
        T = T[inside]
        used = np.unique(T)
        remap = np.full(len(V), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        V, T = V[used], remap[T]
        A = coo_matrix((np.ones(T.size), (np.repeat(np.arange(len(T)), 4), T.ravel())), shape=(len(T), len(V)))
        _, lab = connected_components((A.T @ A).tocsr(), directed=False)
        big = np.argmax(np.bincount(lab))
        T = T[lab[T[:, 0]] == big]
        used = np.unique(T)
        remap = np.full(len(V), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        return V[used], remap[T]

    s = float(ext.prod() / target) ** (1 / 3)  # the box's count; the head fills part of it
    for _ in range(12):  # the node count falls as the spacing grows: a few secant-like updates in log space
        V, T = mesh(s)
        if abs(len(V) - target) <= 0.05 * target:
            break
        s *= (len(V) / target) ** (1 / 3)
    return V, T


def peer_scene(rig, anim, path: Path) -> dict:
    """Write the peer's scene (see ``peer_fastcd_worker.py``) for ``rig`` under ``anim`` to ``path`` (.npz): the tets
    of :func:`peer_tets`, each node skinned as the rig's nearest vertex with the fixed body as one more bone, the bone
    world transforms at every step. Returns the node count and the step count."""
    from scipy.spatial import cKDTree

    from kdfaces import KinematicTrajectory
    from kdfaces.motion.joints import joint_frames

    V, T = peer_tets(rig)
    near = cKDTree(np.asarray(rig.neutral)).query(V)[1]
    W = rig.skeleton.weights[near]
    Wp = np.concatenate([W, 1.0 - W.sum(axis=1, keepdims=True)], axis=1)
    traj = KinematicTrajectory(rig, anim)
    h = 1.0 / anim.fps
    steps = int(round((anim.end_s - anim.start_s) * anim.fps))
    times = anim.start_s + h * np.arange(steps + 1)
    G = joint_frames(traj.joints, times)[0]  # (S + 1, J, 4, 4)
    P = np.concatenate([G[:, :, :3, :], np.broadcast_to(np.eye(4)[:3], (len(times), 1, 3, 4))], axis=1)
    np.savez(path, V=V, T=T, Wp=Wp, P=P, h=h, scrub_step=int(round(SCRUB_S / h)), num_modes=PEER_MODES,
             num_clusters=PEER_CLUSTERS, mu=PEER_MU, rho=PEER_RHO)
    return {"nodes": len(V), "steps": steps}


class _Worker:
    """A child process answering JSON lines (one request, one reply)."""

    def __init__(self, argv, env=None):
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1,
                                     env=env)
        self.hello = self._read()

    def _read(self) -> dict:
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"benchmark worker {self.proc.args[:3]} exited with {self.proc.wait()}")
        return json.loads(line)

    def ask(self, cmd: str, **kw) -> dict:
        self.proc.stdin.write(json.dumps({"cmd": cmd, **kw}) + "\n")
        self.proc.stdin.flush()
        reply = self._read()
        if "error" in reply:
            raise RuntimeError(reply["error"])
        return reply

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write(json.dumps({"cmd": "quit"}) + "\n")
                self.proc.stdin.close()
                self.proc.wait(timeout=30)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()


def _ours_worker(levels: int, proxy: int | None = None) -> None:
    """Our side (``python bench_peers.py --ours LEVELS [PROXY]``): the same commands as the peer's worker, plus
    ``batch``; with ``PROXY``, on a proxy of about that many vertices (``FaceModel.from_rig(rig, proxy=PROXY)``)."""
    import resource

    out = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    from kdfaces import FaceModel, FaceSystem, KinematicTrajectory, simulate_full, simulate_kd
    from kdfaces.window import automatic_window

    rig = _rig(levels)
    anim = head_motion_animation()
    traj = KinematicTrajectory(rig, anim)
    h = 1.0 / anim.fps
    times = traj.frame_times
    model = FaceModel.from_rig(rig) if proxy is None else FaceModel.from_rig(rig, proxy=proxy)
    one, two = FaceSystem(model, threads=1), FaceSystem(model, threads=2)
    window_s = float(automatic_window(one, traj, step_s=h).window_s)
    kd = {"step_s": h}

    def scrub(system, t):
        return simulate_kd(system, traj, [t], window_s, **kd)[0]

    first = scrub(one, SCRUB_S)  # the frame scrubbed to before anything else ran (and the kernels loaded)
    simulate_full(one, traj, times[:3], **kd)
    simulate_kd(two, traj, times[:4], window_s, **kd)
    proxy = int(len(model.region)) if getattr(model, "proxy", False) else None  # the proxy's vertex count
    out.write(json.dumps({"ready": True, "vertices": int(rig.num_vertices), "window_s": window_s,
                          "proxy": proxy}) + "\n")
    for line in sys.stdin:
        cmd = json.loads(line)["cmd"]
        if cmd == "play":
            t0 = time.perf_counter()
            simulate_full(one, traj, times, **kd)
            reply = {"ms_per_step": 1e3 * (time.perf_counter() - t0) / (len(times) - 1)}
        elif cmd == "batch":
            t0 = time.perf_counter()
            simulate_kd(two, traj, times, window_s, **kd)
            reply = {"ms_per_frame": 1e3 * (time.perf_counter() - t0) / len(times)}
        elif cmd == "scrub":
            t0 = time.perf_counter()
            scrub(one, SCRUB_S)
            reply = {"ms": 1e3 * (time.perf_counter() - t0)}
        elif cmd == "history":
            for t in JUMP_FROM_S:  # scrub around and play, then come back
                scrub(one, t)
            simulate_full(one, traj, times[:80], **kd)
            again = scrub(one, SCRUB_S)
            batch = simulate_kd(two, traj, times, window_s, **kd)[int(round(SCRUB_S / h))]
            reply = {"rescrub_max_m": float(np.abs(again - first).max()),
                     "batch_max_m": float(np.abs(batch - first).max()),
                     "bit_identical": bool(np.array_equal(again, first) and np.array_equal(batch, first))}
        elif cmd == "memory":
            reply = {"peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
        elif cmd == "quit":
            break
        else:
            reply = {"error": f"unknown command {cmd!r}"}
        out.write(json.dumps(reply) + "\n")


def _compare(levels: int, label: str, peer_py: Path, rounds: int) -> list[dict]:
    import tempfile

    rig = _rig(levels)
    anim = head_motion_animation()
    h = 1.0 / anim.fps
    with tempfile.TemporaryDirectory(prefix="kdfaces-peers-") as tmp:
        scene = Path(tmp) / "scene.npz"
        peer_scene(rig, anim, scene)
        del rig
        with np.load(scene) as d:  # the peer's precomputation is cached by the mesh's content
            import hashlib

            key = f"{label}-{hashlib.sha256(d['V'].tobytes() + d['T'].tobytes()).hexdigest()[:16]}"
        peer = _Worker([str(peer_py), str(HERE / "peer_fastcd_worker.py"), str(scene),
                        str(cache_root() / "peers-cache" / key)])
        ours = _Worker([sys.executable, str(Path(__file__).resolve()), "--ours", str(levels)])
        # the dense face above the default head also on a proxy (issue #29), in a process of its own: its own
        # memory, and the same rounds
        on_proxy = _Worker([sys.executable, str(Path(__file__).resolve()), "--ours", str(levels),
                            str(PROXY_VERTICES)]) if levels > 0 else None
        try:
            r = {k: [] for k in ("ours_play", "ours_batch", "peer_play", "ours_scrub", "peer_scrub", "proxy_batch")}
            for _ in range(rounds):  # interleaved: the machine's load falls on both sides alike
                r["ours_play"].append(ours.ask("play")["ms_per_step"])
                r["peer_play"].append(peer.ask("play")["ms_per_step"])
                r["ours_batch"].append(ours.ask("batch")["ms_per_frame"])
                if on_proxy is not None:
                    r["proxy_batch"].append(on_proxy.ask("batch")["ms_per_frame"])
                r["ours_scrub"].append(ours.ask("scrub")["ms"])
                r["peer_scrub"].append(peer.ask("scrub")["ms"])
            hist_ours = ours.ask("history")
            hist_peer = peer.ask("history", from_steps=[int(round(t / h)) for t in JUMP_FROM_S])
            mem_ours, mem_peer = ours.ask("memory")["peak_rss_mib"], peer.ask("memory")["peak_rss_mib"]
        finally:
            ours.close()
            peer.close()
            if on_proxy is not None:
                on_proxy.close()
    med = {k: statistics.median(v) for k, v in r.items() if v}
    proxy = ours.hello.get("proxy")
    us = f"ours {ours.hello['vertices']} vertices, " + (f"proxy {proxy}" if proxy else "no proxy")
    them = f"peer {peer.hello['nodes']} nodes, {peer.hello['reduced_dofs']} DOFs"
    where = f"{label} ({us}; {them})"
    frames = len(anim_frames(anim))
    jumps = hist_peer["jump_max_mm"]
    same = "bit-identical" if hist_ours["bit_identical"] else "DIFFERS"

    def row(name, size, value, unit, seconds=True):
        return {"name": name, "size": f"{where}: {size}", "median_s": value / 1e3 if seconds else float("nan"),
                "rate": value, "unit": unit}

    extra = []
    if on_proxy is not None:
        extra.append(row("peer_fastcd_play", f"ours on a {on_proxy.hello['proxy']}-vertex proxy, KD batch of {frames}, "
                                             f"2 threads, per frame (δ = {on_proxy.hello['window_s']:.3g} s; "
                                             f"{med['peer_play'] / med['proxy_batch']:.2f}× the peer's speed)",
                         med["proxy_batch"], "ms"))
    return [
        row("peer_fastcd_play", f"peer, per step (h = {h:g} s, median of {rounds})", med["peer_play"], "ms"),
        row("peer_fastcd_play", f"ours, full simulation, per step ({med['peer_play'] / med['ours_play']:.2f}× the "
                                "peer's speed)", med["ours_play"], "ms"),
        row("peer_fastcd_play", f"ours, KD batch of {frames}, 2 threads, per frame (δ = {ours.hello['window_s']:.3g} "
                                f"s; {med['peer_play'] / med['ours_batch']:.2f}× the peer's speed)", med["ours_batch"],
            "ms"),
        *extra,
        row("peer_fastcd_scrub", f"peer, t = {SCRUB_S:g} s (simulated from the start)", med["peer_scrub"], "ms"),
        row("peer_fastcd_scrub", f"ours, t = {SCRUB_S:g} s (one KD state; {med['peer_scrub'] / med['ours_scrub']:.1f}×"
                                 " faster)", med["ours_scrub"], "ms"),
        row("peer_fastcd_memory", "peer process, peak resident", mem_peer, "MiB", False),
        row("peer_fastcd_memory", f"ours process, peak resident ({mem_ours / mem_peer:.2f}× the peer's)", mem_ours,
            "MiB", False),
        row("peer_fastcd_history", f"ours, frame {SCRUB_S:g} s scrubbed first vs after playing and scrubbing "
                                   f"elsewhere and in the batch: {same}, history-free",
            1e3 * max(hist_ours["rescrub_max_m"], hist_ours["batch_max_m"]), "mm (largest difference)", False),
        row("peer_fastcd_history", f"peer, frame {SCRUB_S:g} s played vs its app's jump from "
                                   f"{', '.join(f'{t:g}' for t in JUMP_FROM_S)} s: "
                                   f"{min(jumps):.1f}–{max(jumps):.1f} mm, depends on history", max(jumps),
            "mm (largest node distance)", False),
    ]


def anim_frames(anim) -> np.ndarray:
    """The frame times [s] of ``anim``."""
    n = int(round((anim.end_s - anim.start_s) * anim.fps))
    return anim.start_s + np.arange(n + 1) / anim.fps


def bench_peers(repeats: int = ROUNDS) -> list[dict]:
    """The peer comparison on both head sizes (module docstring): ``repeats`` interleaved rounds, at least
    :data:`ROUNDS`."""
    py = peer_python()
    out = []
    for levels, label in SIZES:
        out += _compare(levels, label, py, max(ROUNDS, int(repeats)))
    return out


BENCHMARKS = [("peers", bench_peers)]


if __name__ == "__main__":
    if len(sys.argv) in (3, 4) and sys.argv[1] == "--ours":
        _ours_worker(int(sys.argv[2]), int(sys.argv[3]) if len(sys.argv) == 4 else None)
    else:
        for row in bench_peers(int(sys.argv[1]) if len(sys.argv) > 1 else ROUNDS):
            print(row)
