"""The peer's side of ``bench_peers``: Fast Complementary Dynamics (``fast-cody``, Benchekroun et al. 2023) on a
scene file, driven over stdin/stdout by JSON lines. It runs in the peer's own virtualenv (made by
``bench_peers.peer_python``), so it imports nothing of ours: numpy, scipy, libigl and fast_cody only.

Scene (.npz, written by ``bench_peers``): tet nodes ``V`` (n, 3) [m], tets ``T`` (t, 4), primary skinning weights
``Wp`` (n, k) (the rig's joints plus the fixed body), bone world transforms ``P`` (S + 1, k, 3, 4) at the step times
k·h from the shot start (rest pose: identity), the step ``h`` [s], the scrub step ``scrub_step`` (t = 3 s),
``num_modes`` and ``num_clusters``. Set up as the package's own ``interactive_cd_rig_anim`` does: geometry scaled to
unit height and centred (its ``mu``, ``rho`` are for that size), LBS Jacobian J, the complementary constraint, the
skinning subspace B (``num_modes`` × 12 reduced DOFs) and clusters; positions x = J p + B z, mapped back to metres.

Commands (one JSON object per line) and replies:
- ``{"cmd": "play"}``: the whole shot from the start, one step per frame → ``{"ms_per_step": …}``.
- ``{"cmd": "scrub"}``: frame ``scrub_step`` from a fresh start (the only exact way: simulate from the start)
  → ``{"ms": …}``.
- ``{"cmd": "history", "from_steps": [...]}``: frame ``scrub_step`` reached by playing from the start against a jump
  the way the package's app scrubs (its state kept, the rig pose set to the frame's, one step) from each step in
  ``from_steps`` → ``{"jump_max_mm": [...]}`` (largest node distance, one per origin).
- ``{"cmd": "memory"}`` → ``{"peak_rss_mib": …}`` (this process's peak resident memory).
- ``{"cmd": "quit"}``.
"""

from __future__ import annotations

import json
import os
import resource
import sys
import time


def main(scene_path: str, cache_dir: str) -> None:
    out = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # the package's (and its C++ core's) prints go to stderr, replies alone to the pipe

    import fast_cd_pyb as fcdp
    import fast_cody as fcd
    import numpy as np

    d = np.load(scene_path)
    V, T, Wp, P = d["V"].astype(np.float64), d["T"].astype(np.int64), d["Wp"].astype(np.float64), d["P"]
    h, scrub_step = float(d["h"]), int(d["scrub_step"])
    num_modes, num_clusters = int(d["num_modes"]), int(d["num_clusters"])
    mu, rho = float(d["mu"]), float(d["rho"])
    t_setup = time.perf_counter()
    Vs, so, to = fcdp.scale_and_center_geometry(V, 1, np.array([[0, 0, 0.0]]))
    k = Wp.shape[1]
    P0 = np.tile(np.eye(4)[:3], (k, 1, 1)) * so
    P0[:, :, 3] = P0[:, :, 3] - to
    Pw = P * so
    Pw[:, :, :, 3] = Pw[:, :, :, 3] - to
    J = fcd.lbs_jacobian(Vs, Wp)
    Prel = fcd.world2rel(Pw, P0)
    frames = Prel.shape[0]
    Prel = np.transpose(Prel, [3, 1, 2, 0]).reshape((4 * 3 * k, frames), order="F")
    C = fcd.complementary_constraint_matrix(Vs, T, J, dt=1e-3)
    C2 = fcd.lbs_weight_space_constraint(Vs, C)
    os.makedirs(cache_dir, exist_ok=True)
    B, labels, _ = fcd.skinning_subspace(Vs, T, num_modes, num_clusters, C=C2, cache_dir=cache_dir,
                                         read_cache=os.path.exists(os.path.join(cache_dir, "B.npy")),
                                         constraint_enforcement="optimal")
    labels = np.asarray(labels, dtype=np.int32).reshape(-1, 1)
    sim = fcd.fast_cd_sim(Vs, T.astype(np.int32), B, labels, J, mu=mu, rho=rho, h=h, cache_dir=cache_dir,
                          read_cache=False)
    m = B.shape[1]
    z0 = np.zeros((m, 1))
    setup_s = time.perf_counter() - t_setup

    def positions(z, p):  # (n, 3) [m]: x = J p + B z in the unit-height frame, back to metres
        x = (J @ p + B @ z).reshape((-1, 3), order="F")
        return (x + to) / so

    def run(first: int, last: int, st=None):
        """Step from ``first`` to ``last`` (state ``st``, default a fresh start at ``first``) → (state, z)."""
        if st is None:
            st = fcd.fast_cd_state(z0, Prel[:, [first]])
        z = st.z_curr
        for s in range(first + 1, last + 1):
            p = Prel[:, [s]]
            z = sim.step(p, st).reshape((m, 1), order="F")
            st.update(z, p)
        return st, z

    run(0, 2)  # load everything once
    out.write(json.dumps({"ready": True, "nodes": int(len(V)), "tets": int(len(T)), "reduced_dofs": int(m),
                          "setup_s": setup_s}) + "\n")
    for line in sys.stdin:
        req = json.loads(line)
        cmd = req["cmd"]
        if cmd == "play":
            t0 = time.perf_counter()
            run(0, frames - 1)
            reply = {"ms_per_step": 1e3 * (time.perf_counter() - t0) / (frames - 1)}
        elif cmd == "scrub":
            t0 = time.perf_counter()
            run(0, scrub_step)
            reply = {"ms": 1e3 * (time.perf_counter() - t0)}
        elif cmd == "history":
            _, z = run(0, scrub_step)
            x_play = positions(z, Prel[:, [scrub_step]])
            dist = []
            for s0 in req["from_steps"]:
                st, _ = run(0, int(s0))
                p = Prel[:, [scrub_step]]  # the app's jump: keep the state, set the frame's rig pose, step once
                zj = sim.step(p, st).reshape((m, 1), order="F")
                dist.append(1e3 * float(np.linalg.norm(positions(zj, p) - x_play, axis=1).max()))
            reply = {"jump_max_mm": dist}
        elif cmd == "memory":
            reply = {"peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
        elif cmd == "quit":
            break
        else:
            reply = {"error": f"unknown command {cmd!r}"}
        out.write(json.dumps(reply) + "\n")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
