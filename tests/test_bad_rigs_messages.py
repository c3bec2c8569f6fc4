"""Rigs that cannot be right, and the messages around errors (issue 23), through the real command-line entry points
(``kdfaces.cli.main``, ``kdfem.cli.main``, in process) like ``tests/test_bad_inputs.py``: a shape OBJ whose
vertices are in another order, one whose faces differ from the neutral's, a neutral of zero-area faces or of one
vertex, an npz with pickled object arrays; an error while a progress bar is drawn on a stream that is not a
terminal; the door's walk speed and an absurd frame rate; two conflicting constraints of a shot file; a screenshot
path that is not a PNG. Each ends with exit status 2, one line on stderr naming the file (or field) and what was
expected, no traceback and no output folder."""

from __future__ import annotations

import io
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_checks import check_one_line, run_cli

from kdfaces.cli import main as kdfaces_main
from kdfem.cli import main as kdfem_main

REFERENCE = Path(__file__).resolve().parent / "reference" / "shot.toml"
GOOD = REFERENCE.read_text()


_run, _check = run_cli, check_one_line


# ---- rigs that cannot be right -----------------------------------------------------------------------------------

def _grid(n: int = 6, size_m: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """An n × n curved patch (vertices (n², 3) [m], triangles (2(n−1)², 3)), head-sized."""
    u, v = np.meshgrid(np.linspace(0, size_m, n), np.linspace(0, size_m, n))
    verts = np.stack([u.ravel(), v.ravel(), 2.0 * ((u - size_m / 2) ** 2 + (v - size_m / 2) ** 2).ravel()], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return verts, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def _obj(path: Path, verts, faces=None, *, style: str = "plain") -> Path:
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in verts]
    if faces is not None:
        fmt = {"plain": "{}", "slashes": "{0}//{0}", "negative": None}[style]
        for f in faces:
            if style == "negative":
                lines.append("f " + " ".join(str(int(i) - len(verts)) for i in f))
            else:
                lines.append("f " + " ".join(fmt.format(int(i) + 1) for i in f))
    path.write_text("\n".join(lines) + "\n")
    return path


def _smile(verts):
    """A legitimate shape: the middle of the patch bulges by 1 cm."""
    c = verts[:, :2].mean(axis=0)
    r2 = ((verts[:, :2] - c) ** 2).sum(axis=1)
    return verts + np.outer(0.01 * np.exp(-r2 / 0.002), [0, 0, 1])


def _rig_case(tmp_path: Path, case: str) -> tuple[Path, str, str]:
    """A broken rig of kind ``case``: (its path, the file the message must name, the text it must contain)."""
    verts, faces = _grid()
    folder = tmp_path / "obj"
    folder.mkdir()
    perm = np.random.default_rng(3).permutation(len(verts))
    if case == "obj-reordered":  # the same head, listed in another vertex order, no faces: deltas would be scrambled
        _obj(folder / "neutral.obj", verts, faces)
        _obj(folder / "jawOpen.obj", _smile(verts)[perm])
        return folder, "jawOpen.obj", "expected the same vertices in the same order as neutral.obj"
    if case == "obj-reordered-faces":  # the same mesh exported with another vertex order, its faces renumbered
        inverse = np.argsort(perm)
        _obj(folder / "neutral.obj", verts, faces)
        _obj(folder / "jawOpen.obj", _smile(verts)[perm], inverse[faces])
        return folder, "jawOpen.obj", "expected the topology of neutral.obj"
    if case == "obj-fewer-faces":
        _obj(folder / "neutral.obj", verts, faces)
        _obj(folder / "jawOpen.obj", _smile(verts), faces[:-2])
        return folder, "jawOpen.obj", f"{len(faces) - 2} faces, neutral.obj has {len(faces)}"
    if case == "obj-zero-area":  # every triangle's corners on one line
        line = np.c_[np.linspace(0, 0.2, len(verts)), np.zeros((len(verts), 2))]
        _obj(folder / "neutral.obj", line, faces)
        _obj(folder / "jawOpen.obj", line)
        return folder, "neutral.obj", f"all {len(faces)} faces have zero area"
    if case == "obj-one-vertex":
        _obj(folder / "neutral.obj", [[0.0, 1.6, 0.1]])
        _obj(folder / "jawOpen.obj", [[0.0, 1.6, 0.11]])
        return folder, "neutral.obj", "1 vertex and 0 faces; expected a surface mesh"
    if case == "obj-no-faces":
        _obj(folder / "neutral.obj", verts)
        _obj(folder / "jawOpen.obj", _smile(verts))
        return folder, "neutral.obj", "36 vertices and 0 faces; expected a surface mesh"
    if case == "makehuman-zero-area":
        mh = tmp_path / "mh"
        mh.mkdir()
        (mh / "base.obj").write_text("v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\n")
        (mh / "jaw_open.target").write_text("2 0 -0.5 0.25\n")
        return mh, "base.obj", "its one face has zero area"
    p = tmp_path / "rig.npz"
    fields = dict(neutral=verts, deltas=(_smile(verts) - verts)[None], faces=faces, shape_names=np.array(["jawOpen"]))
    if case == "npz-reordered":
        fields["deltas"] = (_smile(verts)[perm] - verts)[None]
        np.savez(p, **fields)
        return p, "rig.npz", "shape 'jawOpen'"
    if case == "npz-one-vertex":
        np.savez(p, neutral=np.zeros((1, 3)), deltas=np.zeros((1, 1, 3)), faces=np.zeros((0, 3), dtype=np.int64),
                 shape_names=np.array(["jawOpen"]))
        return p, "rig.npz", "1 vertex and 0 faces; expected a surface mesh"
    if case == "npz-zero-area":
        np.savez(p, **{**fields, "neutral": np.zeros_like(verts)})
        return p, "rig.npz", "have zero area"
    if case == "npz-pickled-names":
        np.savez(p, **{**fields, "shape_names": np.array(["jawOpen"], dtype=object)}, allow_pickle=True)
        return p, "rig.npz", "field 'shape_names' holds pickled Python objects; expected a plain array"
    if case == "npz-pickled-neutral":
        np.savez(p, **{**fields, "neutral": np.array([verts, "x"], dtype=object)}, allow_pickle=True)
        return p, "rig.npz", "field 'neutral' holds pickled Python objects"
    if case == "npz-text-faces":
        np.savez(p, **{**fields, "faces": faces.astype(str)})
        return p, "rig.npz: field 'faces' holds", "values; expected integers"
    raise AssertionError(case)


RIG_CASES = ["obj-reordered", "obj-reordered-faces", "obj-fewer-faces", "obj-zero-area", "obj-one-vertex",
             "obj-no-faces", "makehuman-zero-area", "npz-reordered", "npz-one-vertex", "npz-zero-area",
             "npz-pickled-names", "npz-pickled-neutral", "npz-text-faces"]


@pytest.mark.parametrize("case", RIG_CASES)
def test_rig_that_cannot_be_right(tmp_path, capsys, case):
    path, names, field = _rig_case(tmp_path, case)
    out = tmp_path / "out"
    _check(*_run(["export-rig", "--rig", str(path), "--out", str(out)], capsys), out, names=names, field=field)


@pytest.mark.parametrize("style", ["plain", "slashes", "negative"])
def test_obj_folder_whose_shapes_share_the_neutral_topology_loads(tmp_path, style):
    """Shape files with the neutral's faces (written the same way, with normals, or with relative indices) and
    shape files without faces are one rig."""
    from kdfaces import load_rig

    verts, faces = _grid()
    _obj(tmp_path / "neutral.obj", verts, faces)
    _obj(tmp_path / "jawOpen.obj", _smile(verts), faces, style=style)
    _obj(tmp_path / "mouthClose.obj", _smile(verts) + [0, 0.002, 0])
    rig = load_rig(tmp_path)
    assert rig.shape_names == ("jawOpen", "mouthClose")
    np.testing.assert_allclose(rig.deltas[0], _smile(verts) - verts, atol=1e-7)


def test_default_rig_passes_the_checks_with_a_wide_margin():
    """Every shape of the default rig passes the plausibility check, far below the limit (its OBJ folder and glTF
    round trips are loaded in tests/test_rig_io.py and tests/test_gltf.py); a reordered copy of a shape fails it."""
    from kdfaces import load_default_rig
    from kdfaces.rig.blendshapes import REORDERED_FRACTION, reordered_shapes

    rig = load_default_rig()
    assert reordered_shapes(rig.neutral, rig.deltas, rig.faces) == []
    roll = np.roll(rig.neutral + rig.deltas[0], 1, axis=0) - rig.neutral  # off by one line: the mildest reorder
    bad = reordered_shapes(rig.neutral, np.concatenate([rig.deltas[:1], roll[None]]), rig.faces)
    assert [k for k, _ in bad] == [1] and bad[0][1] > REORDERED_FRACTION


# ---- an error while a progress bar is drawn, on a stream that is not a terminal --------------------------------

def test_error_during_a_progress_bar_starts_its_own_line(tmp_path, capsys, monkeypatch):
    """``kdfem window`` names each finished stage on its bar; the attachment then fails. On a non-terminal stderr
    (capsys) the error must be a line of its own, not the tail of the bar's line."""
    import trimesh

    import kdfaces.resources

    monkeypatch.setattr(kdfaces.resources, "PROGRESS_DELAY_S", 2.0)  # the default, whatever the environment says
    box = tmp_path / "box.obj"
    trimesh.creation.box(extents=(0.04, 0.04, 0.06)).export(box)
    out = tmp_path / "out"
    rc, err, seconds = _run(["window", str(box), "--attach-below", "-10", "--out", str(out), "--no-nonlinear",
                             "--no-sweep"], capsys, fn=kdfem_main)
    assert not sys.stderr.isatty()
    error = [line for line in err.splitlines() if "error" in line]
    assert len(error) == 1 and error[0].startswith("kdfem: error: --attach-below -10"), err
    _check(rc, err.replace("\r", "\n"), seconds, out, names="--attach-below -10", field="no node has y ≤ -10")


@pytest.mark.parametrize("draw", ["postfix", "refresh", "update"])
def test_a_closed_progress_bar_ends_its_line(monkeypatch, draw):
    """However the bar got drawn (a postfix, a refresh as tqdm's monitor thread does, an update after the delay),
    the failing stage's bar ends its line before the error is printed; a bar never drawn prints nothing."""
    import kdfaces.resources as resources

    monkeypatch.setattr(resources, "PROGRESS_DELAY_S", 0.05)
    stream = io.StringIO()
    monkeypatch.setattr(sys, "stderr", stream)
    with pytest.raises(ValueError, match="boom"):
        with resources.progress_bar("stage", 10, True) as bar:
            if draw == "postfix":
                bar.set_postfix_str("first")  # before the delay: no bar yet
                assert stream.getvalue() == ""
                time.sleep(0.06)
                bar.set_postfix_str("second")
            elif draw == "refresh":
                bar.refresh()
            else:
                time.sleep(0.06)
            bar.update(1)
            raise ValueError("boom")
    stream.write("kdfaces: error: boom\n")
    text = stream.getvalue()
    assert text.count("kdfaces: error: boom") == 1
    assert "\nkdfaces: error: boom\n" in text or text == "kdfaces: error: boom\n", repr(text)
    if draw == "refresh":
        assert "stage" in text  # it was drawn, and its line ended


# ---- kdfem door: the walk and the work ---------------------------------------------------------------------------

DOOR_CASES = [
    ("speed-zero", ("speed_mps = 1.2", "speed_mps = 0.0"), "walk.speed_mps: 0 m/s; expected a positive speed"),
    ("speed-backwards", ("speed_mps = 1.2", "speed_mps = -1.2"), "walk.speed_mps: -1.2 m/s; expected a positive"),
    ("speed-slow", ("speed_mps = 1.2", "speed_mps = 0.1"),
     "walk.speed_mps: the hat never passes under the lintel: at walk.speed_mps = 0.1 m/s"),
    ("speed-absurd", ("speed_mps = 1.2", "speed_mps = 1000.0"),
     "walk.speed_mps: the hat never passes under the lintel: it moves 10 m"),
    ("fps-low", [("fps = 100", "fps = 2"), ("step_s = 0.01", "step_s = 0.05")],
     "walk.fps: the hat is under the door in one frame only"),
    ("fps-lower", [("fps = 100", "fps = 1"), ("step_s = 0.01", "step_s = 0.05")],
     "walk.fps: the hat never passes under the lintel: it moves"),
    ("clearance-interval", ("kind = \"clearance\"", "kind = \"clearance\"\nstart_s = 1.0\nend_s = 0.5"),
     "constraints[1]: expected start_s < end_s, got [1, 0.5] s"),
    ("door-behind", ("front_z_m = 1.32", "front_z_m = -3.0"),
     "door.front_z_m: the hat never passes under the lintel: the door (z from -3 to -2.85 m) is behind"),
    ("door-far", ("front_z_m = 1.32", "front_z_m = 9.0"), "door.front_z_m: the hat never passes under the lintel"),
    ("fps-absurd", [("fps = 100", "fps = 10000"), ("step_s = 0.01", "step_s = 0.0001")],
     "walk.fps: 10000 frames/s asks for 2.6e+04 frames × 5.68e+03 KD steps per window"),
    ("fps-absurd-step", ("fps = 100", "fps = 1e9"), "walk.fps: 1e+09 frames/s asks for"),
    ("end-absurd", ("end_s = 2.6", "end_s = 1e7"), "walk.end_s: 1e+07 s asks for"),
    ("step-tiny", ("step_s = 0.01", "step_s = 1e-7"), "kd.step_s: 1e-07 s asks for"),
]


@pytest.mark.parametrize("case, edit, field", DOOR_CASES, ids=[c[0] for c in DOOR_CASES])
def test_door_names_the_field_that_is_wrong(tmp_path, capsys, case, edit, field):
    from kdfem.scenes.door import DOOR_SHOT

    text = DOOR_SHOT.read_text()
    for old, new in edit if isinstance(edit, list) else [edit]:
        assert old in text, (case, old)
        text = text.replace(old, new)
    shot = tmp_path / "door.toml"
    shot.write_text(text)
    out = tmp_path / "out"
    _check(*_run(["door", str(shot), "--out", str(out), "--no-movie"], capsys, fn=kdfem_main), out,
           names="door.toml: ", field=f"door.toml: {field}", limit_s=60)


def test_door_refuses_frames_beyond_the_memory_budget(tmp_path, capsys, monkeypatch):
    """Within the step limit but beyond the memory budget: refused once the hat's size is known, before the arrays
    over the frames are allocated."""
    import kdfaces.resources

    monkeypatch.setattr(kdfaces.resources, "memory_budget_bytes", lambda max_memory_bytes=None: 1 << 20)
    out = tmp_path / "out"
    _check(*_run(["door", "--out", str(out), "--no-movie"], capsys, fn=kdfem_main), out, names="door.toml: walk.fps",
           field="more than the memory budget of 1 MiB; expected a lower walk.fps", limit_s=60)


def test_door_refuses_absurd_work_before_allocating():
    """The estimate is arithmetic on the shot's numbers: no rig is loaded, no hat built, nothing allocated."""
    from kdfaces.errors import KDInputError
    from kdfaces.resources import peak_rss_bytes
    from kdfem.scenes.door import DOOR_MAX_STEPS, DoorShot, check_door_work

    assert check_door_work(DoorShot()) == (261, 57)
    assert 261 * 57 < DOOR_MAX_STEPS
    before = peak_rss_bytes()
    shot = DoorShot.model_validate({"walk": {"fps": 1e12}, "kd": {"step_s": 1e-12}})
    with pytest.raises(KDInputError, match=r"^door.toml: walk.fps: 1e\+12 frames/s asks for"):
        check_door_work(shot, where="door.toml")
    assert peak_rss_bytes() - before < 50 << 20


# ---- two constraints that contradict each other --------------------------------------------------------------------

CONFLICT_CASES = [
    ("pose-pose", """
[[constraints]]
time_s = 0.8
kind = "pose"
target = { head_deg = [0, 0, -10] }
width_s = 0.2
""", "constraints[0] and constraints[1]: ", "have conflicting targets on"),
    ("pose-subset", """
[[constraints]]
time_s = 0.8
kind = "subset"
group = "jaw"
target = { weights = { jawOpen = 1.0 } }
width_s = 0.2
""", "constraints[0] and constraints[1]: ", "shared vertices (up to"),
    ("pose-end-effector", """
[[constraints]]
time_s = 0.8
kind = "end_effector"
group = "jaw"
target = { point_m = [0, 0, 0.5] }
width_s = 0.2
""", "constraints[0] and constraints[1]: ", "the pose puts the end effector"),
    ("different-widths", """
[[constraints]]
time_s = 0.8
kind = "subset"
group = "jaw"
width_s = 0.3
""", "constraints[0] and constraints[1]: ", "different curve shapes or widths"),
]


@pytest.mark.parametrize("case, extra, fields, field", CONFLICT_CASES, ids=[c[0] for c in CONFLICT_CASES])
def test_conflicting_constraints_name_the_shot_file_and_both_fields(tmp_path, capsys, case, extra, fields, field):
    shot = tmp_path / "shot.toml"
    text = GOOD.replace("[solver]", extra.lstrip() + "\n[solver]")
    shot.write_text(text)
    out = tmp_path / "out"
    _check(*_run(["run", str(shot), "--out", str(out)], capsys), out, names=f"shot.toml: {fields}", field=field)


# ---- a screenshot path that is not a PNG ---------------------------------------------------------------------------

SCREENSHOT_CASES = [
    ("frame.txt", "expected a .png file name (screenshots are PNG images), got a '.txt' name"),
    ("frame", "expected a .png file name (screenshots are PNG images), got a name without a suffix"),
    ("frame.PNG.jpg", "got a '.jpg' name"),
    ("folder.png", "is a folder; expected a .png file name"),
    ("missing/frame.png", "not found; expected a .png file in an existing folder"),
]


@pytest.mark.parametrize("command", ["kdfaces", "kdfem"])
@pytest.mark.parametrize("name, field", SCREENSHOT_CASES, ids=[c[0] for c in SCREENSHOT_CASES])
def test_a_screenshot_that_is_not_a_png_is_refused_before_anything_runs(tmp_path, capsys, monkeypatch, command,
                                                                         name, field):
    import kdfaces.shots.shotfile
    import kdfem.viewer

    def never(*args, **kwargs):
        raise AssertionError("the shot or the hat was loaded before the screenshot path was checked")

    monkeypatch.setattr(kdfaces.shots.shotfile, "load_shot", never)
    monkeypatch.setattr(kdfem.viewer, "HatViewer", never)
    (tmp_path / "folder.png").mkdir()
    target = tmp_path / name
    if command == "kdfaces":
        argv, fn = ["view", str(REFERENCE), "--screenshot", str(target)], kdfaces_main
    else:
        argv, fn = ["view", "--screenshot", str(target)], kdfem_main
    _check(*_run(argv, capsys, fn=fn), None, names=f"--screenshot {target}", field=field)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder.png"]  # nothing written
