"""Captures and takes whose times lie, shots that move nothing, and work estimates made before anything runs.

Each case goes through the real command line (``kdfaces.cli.main``, in process) as ``tests/test_bad_inputs.py``
does: exit status 2, exactly one line on stderr naming the file (and the field or row) and what was expected, no
traceback, no output folder, and quickly. A few library checks sit beside them (the estimate, the bounded window
scan, the midnight unwrap).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from cli_checks import check_one_line, run_cli

from kdfaces.cli import main as kdfaces_main

REFERENCE = Path(__file__).resolve().parent / "reference" / "shot.toml"
GOOD = REFERENCE.read_text()


_run, _check = run_cli, check_one_line


def _codes(first_s: int, count: int, rate: int = 30) -> list[str]:
    """``count`` Live Link Face timecodes HH:MM:SS:FF.000, one per frame at ``rate`` from ``first_s`` [s of the day]
    (wrapping at midnight as a real clock does)."""
    out = []
    for f in range(first_s * rate, first_s * rate + count):
        s, ff = divmod(f, rate)
        s %= 86400
        out.append(f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}:{ff:02d}.000")
    return out


def _take(tmp_path, codes, *, moving: bool = True, name: str = "take.csv") -> Path:
    """A Live Link Face CSV with one row per timecode in ``codes``; the jaw opens and closes when ``moving``."""
    from kdfaces.rig import ARKIT_NAMES

    header = ["Timecode", "BlendShapeCount", *[n[0].upper() + n[1:] for n in ARKIT_NAMES], "HeadYaw", "HeadPitch",
              "HeadRoll"]
    jaw = ARKIT_NAMES.index("jawOpen")
    lines = [",".join(header)]
    for k, code in enumerate(codes):
        w = ["0.1"] * len(ARKIT_NAMES)
        if moving:
            w[jaw] = f"{0.5 + 0.4 * np.sin(k / 3):.6f}"
        lines.append(",".join([code, "61", *w, "0", "0", "0"]))
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def _capture_shot(tmp_path, extra: str = "") -> Path:
    shot = tmp_path / "shot.toml"
    shot.write_text('[animation]\nsource = "take.csv"\n' + extra)
    return shot


STEADY = _codes(3600, 30)  # one second at 30 fps, from 01:00:00


# (case id, timecodes, expected text naming the row and what was expected)
TIMECODE_CASES = [
    # a 60 fps take written with 30 fps codes: every code twice (half the rows were silently dropped)
    ("duplicated", [c for c in STEADY[:15] for _ in range(2)],
     "rows 2 and 3 have the same timecode '01:00:00:00.000' with different values"),
    # two takes in one file: the second starts over (they were interleaved)
    ("backwards", STEADY[:15] + _codes(3600, 15), "row 17: timecode '01:00:00:00.000' is 0.583333 s before row 16's"),
    # a second take appended a minute later (a frozen minute was interpolated across)
    ("gap", STEADY[:15] + _codes(3660, 15), "row 17: timecode '01:01:00:00.000' is 59."),
    # a wrap at midnight that is not a take crossing it (the step back is not one ordinary step)
    ("midnight-inconsistent", _codes(86399, 15) + _codes(10, 15),
     "row 17: timecode '00:00:10:00.000'"),
    ("hour-out-of-range", ["25:00:00:00.000"] + STEADY[1:], "row 2 field 'Timecode': expected HH:MM:SS:FF.fff"),
]


@pytest.mark.parametrize("case, codes, field", TIMECODE_CASES, ids=[c[0] for c in TIMECODE_CASES])
def test_lying_timecodes(tmp_path, capsys, case, codes, field):
    _take(tmp_path, codes)
    shot = _capture_shot(tmp_path)
    out = tmp_path / "out"
    _check(*_run(["run", str(shot), "--out", str(out)], capsys), out, names="take.csv", field=field)


def test_duplicated_timecodes_are_never_dropped_silently(tmp_path):
    from kdfaces import KDInputError, read_livelinkface

    p = _take(tmp_path, [c for c in STEADY[:15] for _ in range(2)])
    with pytest.raises(KDInputError, match="60 fps written with 30 fps codes"):
        read_livelinkface(p)
    # a row that repeats the previous one entirely carries nothing: dropped, with a warning naming it
    p = _take(tmp_path, STEADY)
    lines = p.read_text().splitlines()
    p.write_text("\n".join([lines[0], lines[1], *lines[1:]]) + "\n")
    with pytest.warns(UserWarning, match=r"row\(s\) 3 repeat the previous row exactly"):
        take = read_livelinkface(p)
    assert take.rows_read == 31 and len(take.times) == 30


def test_midnight_wrap_is_unwrapped(tmp_path, capsys):
    from kdfaces import read_livelinkface

    p = _take(tmp_path, _codes(86399, 60))  # 23:59:59:00 … 23:59:59:29, 00:00:00:00 … 00:00:00:29
    take = read_livelinkface(p)
    assert take.midnight_row == 32  # header is row 1, the first after midnight is the 31st data row
    np.testing.assert_allclose(np.diff(take.times), 1 / 30, atol=1e-9)
    assert take.times[-1] == pytest.approx(59 / 30)
    shot = _capture_shot(tmp_path)
    out = tmp_path / "out"
    t0 = time.perf_counter()
    rc = kdfaces_main(["run", str(shot), "--out", str(out), "--window", "0.2"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert time.perf_counter() - t0 < 60  # it hung before: a 24 h take


STRETCH_CASES = [
    ("start-after-take", "start_s = 5\n", "shot.toml: animation.start_s: 5 s is outside the take"),
    ("start-negative", "start_s = -1\n", "shot.toml: animation.start_s: -1 s is outside the take"),
    ("end-after-take", "end_s = 5\n", "shot.toml: animation.end_s: 5 s is outside the take"),
    ("end-before-start", "start_s = 0.5\nend_s = 0.2\n", "shot.toml: animation.end_s: 0.2 s is not after"),
]


@pytest.mark.parametrize("case, extra, field", STRETCH_CASES, ids=[c[0] for c in STRETCH_CASES])
def test_capture_stretch_outside_the_take(tmp_path, capsys, case, extra, field):
    _take(tmp_path, STEADY)
    shot = _capture_shot(tmp_path, extra)
    out = tmp_path / "out"
    _check(*_run(["run", str(shot), "--out", str(out)], capsys), out, names="take.csv", field=field)


def _foreign_rig(tmp_path) -> Path:
    """The default head with shapes named so that no ARKit channel finds one."""
    from kdfaces import load_default_rig

    rig = load_default_rig()
    p = tmp_path / "prod.npz"
    np.savez(p, neutral=rig.neutral, deltas=rig.deltas, faces=rig.faces,
             shape_names=np.array([f"shape{i:02d}" for i in range(rig.num_shapes)]))
    return p


def test_capture_that_maps_to_no_shape(tmp_path, capsys):
    _take(tmp_path, STEADY)
    _foreign_rig(tmp_path)
    shot = tmp_path / "shot.toml"
    shot.write_text('[rig]\nsource = "prod.npz"\n[animation]\nsource = "take.csv"\n')
    out = tmp_path / "out"
    rc, err, seconds = _run(["run", str(shot), "--out", str(out)], capsys)
    _check(rc, err, seconds, out, names="shot.toml", field="has no shape for any of the 52 channels")
    assert "[animation.map]" in err  # says what to change


MAP_CASES = [
    ("key-not-a-channel", '[animation.map]\nJaw_Opening = "jawOpen"\n',
     "shot.toml: animation.map.Jaw_Opening: not a channel of the animation"),
    ("drops-every-channel", None, "shot.toml: animation.map: every one of the 52 channels is dropped"),
]


@pytest.mark.parametrize("case, extra, field", MAP_CASES, ids=[c[0] for c in MAP_CASES])
def test_animation_map_that_maps_no_channel(tmp_path, capsys, case, extra, field):
    from kdfaces.rig import ARKIT_NAMES

    _take(tmp_path, STEADY)
    if extra is None:
        extra = "[animation.map]\n" + "".join(f"{n} = false\n" for n in ARKIT_NAMES)
    shot = _capture_shot(tmp_path, extra)
    out = tmp_path / "out"
    _check(*_run(["run", str(shot), "--out", str(out)], capsys), out, names="shot.toml", field=field)


def _still_keys() -> str:
    text = GOOD.replace("values = [[0], [1], [0]]", "values = [[0.3], [0.3], [0.3]]")
    text = text.replace("yaw_deg = [0, 25, 0]", "yaw_deg = [5, 5, 5]")
    return text[:text.index("[[constraints]]")] + text[text.index("[solver]"):]  # no constraints either


@pytest.mark.parametrize("command", ["run", "bake"])
def test_keyed_shot_that_moves_nothing(tmp_path, capsys, command):
    shot = tmp_path / "shot.toml"
    shot.write_text(_still_keys())
    out = tmp_path / "out"
    argv = [command, str(shot), "--out", str(out)] + (["--workers", "1"] if command == "bake" else [])
    _check(*_run(argv, capsys), out, names="shot.toml", field="animation: nothing moves")


def test_capture_that_moves_nothing(tmp_path, capsys):
    _take(tmp_path, STEADY, moving=False)
    shot = _capture_shot(tmp_path)
    out = tmp_path / "out"
    _check(*_run(["run", str(shot), "--out", str(out)], capsys), out, names="take.csv",
           field="shot.toml: animation.source: nothing moves in take.csv")


def test_a_still_shot_with_constraints_is_fine():
    """IKD makes the motion of a still shot with constraints: it parses."""
    import tomllib

    from kdfaces.shots.shotfile import parse_shot

    text = _still_keys()
    text += '\n[[constraints]]\ntime_s = 0.8\nkind = "pose"\ntarget = { head_deg = [0, 0, 10] }\nwidth_s = 0.2\n'
    shot = parse_shot(tomllib.loads(text), REFERENCE)
    assert not shot.trajectory.moves() and len(shot.constraints()) == 1


TEN_HOURS = GOOD.replace("end_s = 1.2", "end_s = 36000")


@pytest.mark.parametrize("command, window", [("run", "auto"), ("run", "0.4"), ("run", "adaptive"),
                                             ("render", "auto"), ("bake", "auto")])
def test_ten_hour_shot_is_refused_before_anything_runs(tmp_path, capsys, command, window):
    shot = tmp_path / "shot.toml"
    shot.write_text(TEN_HOURS.replace("window_s = 0.4", f'window_s = "{window}"' if window != "0.4" else
                                      "window_s = 0.4"))
    out = tmp_path / "out"
    argv = [command, str(shot), "--out", str(out)] + (["--workers", "1"] if command == "bake" else [])
    _check(*_run(argv, capsys), out, names="shot.toml", field="900,001 frames x", limit_s=10)
    # ... and says what to change


def test_max_steps_option(tmp_path, capsys):
    out = tmp_path / "out"
    rc, err, seconds = _run(["run", str(REFERENCE), "--out", str(out), "--max-steps", "1e5"], capsys)
    _check(rc, err, seconds, out, names="shot.toml", field="more than --max-steps 1e+05")
    assert "a larger --max-steps" in err
    with pytest.raises(SystemExit):
        kdfaces_main(["run", str(REFERENCE), "--out", str(out), "--max-steps", "lots"])
    assert "--max-steps: expected a positive number of vertex-steps" in capsys.readouterr().err


def test_work_estimate_library(default_rig):
    """The estimate is frames × steps × vertices (× 2 with constraints) plus the scan and the solve; instant."""
    import tomllib

    from kdfaces import defaults
    from kdfaces.shots.shotfile import estimate_work, parse_shot

    shot = parse_shot(tomllib.loads(GOOD), REFERENCE, rig=default_rig)
    est = estimate_work(shot)
    n = default_rig.num_vertices
    assert (est.frames, est.window_steps, est.vertices, est.kd_passes) == (31, 10, n, 2)
    assert est.kd_steps == 2 * 31 * 10 * n
    assert est.scan_steps == 31 * n * defaults.SCAN_COST
    assert est.solve_steps == (10 + 1) * 1 * 10 * n
    assert est.memory_bytes == 4 * 31 * n * 3 * 8
    auto = estimate_work(shot, window_s="auto")
    assert auto.lower_bound and auto.window_steps == 1
    assert estimate_work(shot, window_s="auto", window_auto_s=0.2).window_steps == 5
    est.check()  # within the default
    t0 = time.perf_counter()
    long = parse_shot(tomllib.loads(TEN_HOURS), REFERENCE, rig=default_rig)
    from kdfaces import KDInputError

    with pytest.raises(KDInputError, match="plan .* vertex-steps, more than --max-steps"):
        long.work_estimate().check()
    with pytest.raises(KDInputError, match="for the kinematic, KD and IKD trajectories"):
        long.work_estimate().check(None, max_memory_bytes=2**30)
    assert time.perf_counter() - t0 < 5


def test_window_scans_are_bounded(default_rig):
    """automatic_window and adaptive_windows refuse a scan beyond max_steps before sampling anything."""
    from kdfaces import FaceAnimation, KDInputError, KeyframeCurve, KinematicTrajectory, ShapeTrack
    from kdfaces.shots.shotfile import DYNAMICS_DEFAULTS, dynamics_model
    from kdfaces.window import adaptive_windows, automatic_window

    track = ShapeTrack(("jawOpen",), KeyframeCurve.create([0.0, 1.0], [[0.0], [1.0]]))
    traj = KinematicTrajectory(default_rig, FaceAnimation(tracks=(track,), end_s=36000.0, fps=25))
    model = dynamics_model(DYNAMICS_DEFAULTS, default_rig)
    t0 = time.perf_counter()
    with pytest.raises(KDInputError, match="scanning x_K at 900,001 step-grid times"):
        automatic_window(model, traj)
    with pytest.raises(KDInputError, match="adaptive windows: scanning x_K"):
        adaptive_windows(model, traj)
    with pytest.raises(KDInputError, match="more than max_steps 1e\\+03"):
        automatic_window(model, traj, times=np.arange(10.0), max_steps=1e3)
    assert time.perf_counter() - t0 < 5


def test_a_whole_real_take_runs_to_its_last_sample(tmp_path, llf_take_path, default_rig):
    """A capture's last sample need not fall on the frame grid (the real take ends 1.4 ms before a frame): the
    shot's frames all lie inside it. Rounding the frame count up put a frame past the end, and a whole-take
    `kdfaces run` failed with "outside the shot"."""
    from kdfaces.io.livelinkface import livelinkface_animation

    head = tmp_path / "head.csv"
    head.write_text("".join(llf_take_path.read_text().splitlines(keepends=True)[:300]))
    anim = livelinkface_animation(head)
    t = anim.frame_times
    assert t[-1] <= anim.end_s + 1e-12 and anim.end_s - t[-1] < 1.0 / anim.fps
    shot = tmp_path / "head.toml"
    shot.write_text('name = "head"\n[animation]\nsource = "head.csv"\n[dynamics]\nwindow_s = 0.1\n')
    assert kdfaces_main(["run", str(shot), "--out", str(tmp_path / "out")]) == 0


def test_a_capture_saved_with_a_byte_order_mark_reads_like_one_without(tmp_path, llf_take_path):
    from kdfaces.io.livelinkface import read_livelinkface

    rows = "".join(llf_take_path.read_text().splitlines(keepends=True)[:40])
    plain, bom = tmp_path / "plain.csv", tmp_path / "bom.csv"
    plain.write_text(rows)
    bom.write_bytes(b"\xef\xbb\xbf" + rows.replace("\n", "\r\n").encode())
    a, b = read_livelinkface(plain), read_livelinkface(bom)
    assert np.array_equal(a.times, b.times) and np.array_equal(a.weights, b.weights) and a.names == b.names
