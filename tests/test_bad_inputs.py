"""A corpus of malformed inputs through the real command-line entry points (``kdfaces.cli.main``,
``kdfem.cli.main``, in process): shot files with every kind of wrong field, rigs, captures, glTF files and surface
meshes. Each must end with exit status 2, exactly one line on stderr naming the file (and the field where there is
one), no traceback, no output folder, and quickly."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from cli_checks import check_one_line, run_cli

from kdfaces import KDInputError
from kdfaces.cli import main as kdfaces_main
from kdfem.cli import main as kdfem_main

REFERENCE = Path(__file__).resolve().parent / "reference" / "shot.toml"
GOOD = REFERENCE.read_text()

# (case id, edit of the good shot (old, new) or a full replacement text, expected field/text in the message)
SHOT_CASES = [
    ("alpha-string", ("damping_ratio = 0.3", 'damping_ratio = 0.3\nshape_matching_alpha = "stiff"'),
     "dynamics.shape_matching_alpha: expected a valid number (got 'stiff')"),
    ("alpha-range", ("damping_ratio = 0.3", "damping_ratio = 0.3\nshape_matching_alpha = 3"),
     "dynamics.shape_matching_alpha: expected less than or equal to 1"),
    ("weight-string", ("values = [[0], [1], [0]]", 'values = [[0], ["1"], [0]]'),
     "animation.tracks[0].values[1][0]: expected a valid number"),
    ("weight-huge", ("values = [[0], [1], [0]]", "values = [[0], [1e6], [0]]"),
     "animation.tracks[0].values[1][0]: expected less than or equal to 2"),
    ("head-string", ("yaw_deg = [0, 25, 0]", 'yaw_deg = [0, "25", 0]'), "animation.head.yaw_deg[1]"),
    ("head-huge", ("yaw_deg = [0, 25, 0]", "yaw_deg = [0, 1e300, 0]"), "animation.head.yaw_deg[1]"),
    ("head-length", ("yaw_deg = [0, 25, 0]", "yaw_deg = [0, 25]"), "animation.head.yaw_deg: expected 3 angles"),
    ("values-rows", ("values = [[0], [1], [0]]", "values = [[0], [1]]"), "animation.tracks[0].values: expected 3 rows"),
    ("unknown-shape", ('shapes = ["jawOpen"]', 'shapes = ["jawOpn"]'), "animation.tracks[0].shapes: unknown shape"),
    ("source-number", ('source = "keys"', "source = 3"), "animation.source: expected a valid string (got 3)"),
    ("rig-source-number", ('name = "render-test"', 'name = "render-test"\n[rig]\nsource = 3'),
     "rig.source: expected a valid string (got 3)"),
    ("rig-units", ('name = "render-test"', 'name = "render-test"\n[rig]\nunits = "inch"'), "rig.units: expected 'm'"),
    ("rig-missing", ('name = "render-test"', 'name = "render-test"\n[rig]\nsource = "nowhere.npz"'),
     "nowhere.npz: file not found"),
    ("constraints-numbers", ("[[constraints]]", "constraints = [1, 2]\n[[xconstraints]]"), "constraints"),
    ("constraints-scalars", [(GOOD[GOOD.index("[[constraints]]"):GOOD.index("[solver]")], ""),
                             ('name = "render-test"', 'name = "render-test"\nconstraints = [1, 2]')],
     "constraints: expected an array of tables"),
    ("settle-map-missing", ("settle_time_s = 0.3", "settle_time_s = { stiff_s = 0.2 }"),
     "dynamics.settle_time_s.loose_s: field required"),
    ("settle-huge", ("settle_time_s = 0.3", "settle_time_s = 1e9"), "dynamics.settle_time_s"),
    ("settle-negative", ("settle_time_s = 0.3", "settle_time_s = -0.3"), "dynamics.settle_time_s"),
    ("damping-ratio-tiny", ("damping_ratio = 0.3", "damping_ratio = 1e-12"),
     "dynamics.damping_ratio: expected greater than or equal to 0.001"),
    ("damping-ratio-string", ("damping_ratio = 0.3", 'damping_ratio = "low"'), "dynamics.damping_ratio"),
    ("damping-mode", ("damping_ratio = 0.3", 'damping_ratio = 0.3\ndamping_mode = "viscous"'),
     "dynamics.damping_mode: expected 'relative' or 'absolute'"),
    ("window-huge", ("window_s = 0.4", "window_s = 1e6"), "dynamics.window_s"),
    ("window-string", ("window_s = 0.4", 'window_s = "automatic"'), "dynamics.window_s: expected 'auto' or"),
    ("window-adaptive-typo", ("window_s = 0.4", 'window_s = "adaptiv"'),
     "dynamics.window_s: expected 'auto' or 'adaptive' or a valid number (got 'adaptiv')"),
    ("step-long", ("window_s = 0.4", "window_s = 0.4\nstep_s = 10"), "dynamics.step_s"),
    ("step-longer-than-shot", [("end_s = 1.2", "end_s = 0.6"), ("window_s = 0.4", "window_s = 0.4\nstep_s = 0.9")],
     "dynamics.step_s: 0.9 s is longer than the shot"),
    ("fps-huge", ("end_s = 1.2", "end_s = 1.2\nfps = 1e6"), "animation.fps: expected less than or equal to 1000"),
    ("fps-zero", ("end_s = 1.2", "end_s = 1.2\nfps = 0"), "animation.fps: expected a positive number"),
    ("end-missing", ("end_s = 1.2", ""), "keyed animations need 'end_s'"),
    ("end-before-start", ("end_s = 1.2", "end_s = 1.2\nstart_s = 2.0"), "animation.end_s: expected end_s > start_s"),
    ("unknown-key", ("window_s = 0.4", "window_s = 0.4\nstifness = 3"), "dynamics.stifness: unknown key"),
    ("misspelt-key", ("window_s = 0.4", "windw_s = 0.4"), "did you mean 'window_s'"),
    ("unknown-table", ("[solver]", "[solvr]"), "solvr: unknown key; did you mean 'solver'"),
    ("tolerance-zero", ("max_iterations = 10", "max_iterations = 10\ntolerance_m = 0"),
     "solver.tolerance_m: expected a positive number"),
    ("tolerance-negative", ("max_iterations = 10", "max_iterations = 10\ntolerance_m = -1e-5"),
     "solver.tolerance_m"),
    ("tolerance-string", ("max_iterations = 10", 'max_iterations = 10\ntolerance_m = "1e-5"'),
     "solver.tolerance_m: expected a valid number"),
    ("step-scale-string", ("max_iterations = 10", 'max_iterations = 10\nstep_scale = "0.8"'), "solver.step_scale"),
    ("iterations-float", ("max_iterations = 10", "max_iterations = 2.5"), "solver.max_iterations"),
    ("iterations-zero", ("max_iterations = 10", "max_iterations = 0"), "solver.max_iterations"),
    ("update-unknown", ('update = "secant"', 'update = "newton"'), "solver.update: expected 'secant' or 'paper'"),
    ("kind-unknown", ('kind = "pose"', 'kind = "pos"'), "constraints[0].kind"),
    ("time-missing", ("time_s = 0.8\n", ""), "constraints[0].time_s: field required"),
    ("time-outside", ("time_s = 0.8", "time_s = 5.0"), "constraints[0].time_s: 5.0 s is outside the shot"),
    ("width-negative", ("width_s = 0.2", "width_s = -0.2"), "constraints[0].width_s: expected a positive number"),
    ("curve-unknown", ("width_s = 0.2", 'width_s = 0.2\ncurve = "bump"'), "constraints[0].curve"),
    ("target-string", ("target = { head_deg = [0, 0, 10] }", 'target = "kinemtic"'),
     "constraints[0].target: expected 'kinematic' or a table"),
    ("target-offset-shape", ("target = { head_deg = [0, 0, 10] }", "target = { offset_m = [0, 1] }"),
     "constraints[0].target.offset_m: expected at least 3 items"),
    ("target-offset-huge", ("target = { head_deg = [0, 0, 10] }", "target = { offset_m = [0, 100, 0] }"),
     "constraints[0].target.offset_m[1]"),
    ("target-weight-string", ("target = { head_deg = [0, 0, 10] }", 'target = { weights = { jawOpen = "x" } }'),
     "constraints[0].target.weights.jawOpen: expected a valid number"),
    ("target-weight-name", ("target = { head_deg = [0, 0, 10] }", "target = { weights = { jawOpn = 1 } }"),
     "constraints[0].target.weights: unknown shape name 'jawOpn'"),
    ("target-obj-missing", ("target = { head_deg = [0, 0, 10] }", 'target = { obj = "pose.obj" }'),
     "pose.obj: file not found"),
    ("group-unknown", ('kind = "pose"', 'kind = "subset"\ngroup = "lipz"'), "constraints[0].group: unknown group"),
    ("group-missing", ('kind = "pose"', 'kind = "subset"'), "constraints[0]: a subset constraint needs 'group'"),
    ("group-index", ('kind = "pose"', 'kind = "subset"\ngroup = [1, 999999]'), "constraints[0].group"),
    ("part-unknown", ("window_s = 0.4", "window_s = 0.4\n[dynamics.parts]\nteeth = { rigid = true }"),
     "dynamics.parts.teeth: unknown group 'teeth'"),
    ("map-type", ('source = "keys"', 'source = "keys"\n[animation.map]\njawOpen = 3'), "animation.map.jawOpen"),
    ("capture-missing", ('source = "keys"', 'source = "take.csv"'), "take.csv: file not found"),
    ("not-toml", None, "not valid TOML"),
    ("binary", None, "not a UTF-8 text file"),
]


_run, _check = run_cli, check_one_line


@pytest.mark.parametrize("case, edit, field", SHOT_CASES, ids=[c[0] for c in SHOT_CASES])
def test_bad_shot_file(tmp_path, capsys, case, edit, field):
    shot = tmp_path / "shot.toml"
    if case == "not-toml":
        shot.write_text("name = [unclosed\n")
    elif case == "binary":
        shot.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe")
    else:
        text = GOOD
        for old, new in edit if isinstance(edit, list) else [edit]:
            assert old in text, (case, old)
            text = text.replace(old, new)
        shot.write_text(text)
    out = tmp_path / "out"
    _check(*_run(["run", str(shot), "--out", str(out)], capsys), out, names="shot.toml", field=field)


def test_shot_that_is_a_folder_or_missing(tmp_path, capsys):
    out = tmp_path / "out"
    _check(*_run(["run", str(tmp_path), "--out", str(out)], capsys), out, names=str(tmp_path),
           field="expected a TOML shot file, got a folder")
    _check(*_run(["run", str(tmp_path / "no.toml"), "--out", str(out)], capsys), out, names="no.toml",
           field="file not found")


def _capture(tmp_path, mutate) -> Path:
    """A small valid Live Link Face CSV (10 rows at 30 Hz), changed by ``mutate(header, rows)``."""
    from kdfaces.rig import ARKIT_NAMES

    header = ["Timecode", "BlendShapeCount", *[n[0].upper() + n[1:] for n in ARKIT_NAMES], "HeadYaw", "HeadPitch",
              "HeadRoll"]
    rows = [[f"00:00:01:{k:02d}.000", "61", *["0.1"] * len(ARKIT_NAMES), "0", "0", "0"] for k in range(10)]
    mutate(header, rows)
    path = tmp_path / "take.csv"
    path.write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n")
    return path


CAPTURE_CASES = [
    ("header", lambda h, r: h.__setitem__(0, "Time"), "header: expected 'Timecode,BlendShapeCount"),
    ("column-missing", lambda h, r: [h.pop(5)] + [row.pop(5) for row in r], "header lacks blend-shape column"),
    ("not-a-number", lambda h, r: r[3].__setitem__(4, "abc"), "expected numbers"),
    ("nan", lambda h, r: r[3].__setitem__(4, "nan"), "NaN or inf at row"),
    ("weight-huge", lambda h, r: r[3].__setitem__(4, "1e308"), "weight 1e+308; expected a blend-shape weight"),
    ("head-huge", lambda h, r: r[2].__setitem__(len(h) - 3, "1e300"), "'HeadYaw', row 4: 1e+300"),
    ("short-row", lambda h, r: r[5].pop(), "row 7 has"),
    ("one-row", lambda h, r: r.__delitem__(slice(1, None)), "need at least two distinct timecodes"),
    ("bad-timecode", lambda h, r: r[2].__setitem__(0, "noon"), "Timecode"),
]


@pytest.mark.parametrize("case, mutate, field", CAPTURE_CASES, ids=[c[0] for c in CAPTURE_CASES])
def test_bad_capture(tmp_path, capsys, case, mutate, field):
    take = _capture(tmp_path, mutate)
    assert take.exists()
    shot = tmp_path / "shot.toml"
    shot.write_text('[animation]\nsource = "take.csv"\n')
    out = tmp_path / "out"
    _check(*_run(["run", str(shot), "--out", str(out)], capsys), out, names="take.csv", field=field)


def _write_rig_cases(tmp_path, case) -> tuple[Path, str]:
    """A broken rig file of kind ``case`` and the text its error must contain."""
    from kdfaces import load_default_rig, save_gltf

    if case == "npz-garbage":
        p = tmp_path / "rig.npz"
        p.write_bytes(b"not a zip")
        return p, "not a readable npz rig"
    if case == "npz-fields":
        p = tmp_path / "rig.npz"
        np.savez(p, neutral=np.zeros((3, 3)))
        return p, "npz rig lacks field(s)"
    if case == "npz-shapes":
        p = tmp_path / "rig.npz"
        np.savez(p, neutral=np.zeros((3, 3)), deltas=np.zeros((1, 4, 3)), faces=np.array([[0, 1, 2]]),
                 shape_names=np.array(["a"]))
        return p, "deltas: expected shape (K, 3, 3)"
    folder = tmp_path / "obj"
    folder.mkdir()
    if case == "obj-no-neutral":
        (folder / "jawOpen.obj").write_text("v 0 0 0\n")
        return folder, "neutral.obj: file not found"
    if case == "obj-bad-line":
        (folder / "neutral.obj").write_text("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n")
        (folder / "jawOpen.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
        return folder, "neutral.obj:2: vertex line needs three numbers"
    if case == "obj-count":
        (folder / "neutral.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
        (folder / "jawOpen.obj").write_text("v 0 0 0\nv 1 0 0\n")
        return folder, "jawOpen.obj: 2 vertices, expected 3"
    if case == "obj-face-index":
        (folder / "neutral.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
        (folder / "jawOpen.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
        return folder, "face index out of range"
    rig = load_default_rig()
    p = save_gltf(rig, tmp_path / "rig.gltf")
    doc = json.loads(p.read_text())
    if case == "gltf-count":
        doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]["count"] = -1
        p.write_text(json.dumps(doc))
        return p, "count -1; expected a positive number of elements"
    if case == "gltf-no-targets":
        for prim in doc["meshes"][0]["primitives"]:
            prim.pop("targets")
        doc["meshes"][0]["extras"].pop("targetNames")
        p.write_text(json.dumps(doc))
        return p, "has no morph targets"
    if case == "gltf-json":
        p.write_text("{ not json")
        return p, "rig.gltf"
    raise AssertionError(case)


RIG_CASES = ["npz-garbage", "npz-fields", "npz-shapes", "obj-no-neutral", "obj-bad-line", "obj-count",
             "obj-face-index", "gltf-count", "gltf-no-targets", "gltf-json"]


@pytest.mark.parametrize("case", RIG_CASES)
def test_bad_rig(tmp_path, capsys, case):
    path, field = _write_rig_cases(tmp_path, case)
    out = tmp_path / "out"
    _check(*_run(["export-rig", "--rig", str(path), "--out", str(out)], capsys), out, names=path.name, field=field)


def _mesh(tmp_path, case) -> tuple[Path, str]:
    import trimesh

    box = trimesh.creation.box(extents=(0.02, 0.02, 0.04))
    if case == "open":
        m = trimesh.Trimesh(box.vertices, box.faces[:-1], process=False)
        msg = "surface is not closed"
    elif case == "inverted":
        m = trimesh.Trimesh(box.vertices, box.faces[:, ::-1], process=False)
        msg = "faces wind inward"
    elif case == "joined-at-vertex":
        other = box.copy()
        other.apply_translation(box.vertices.max(axis=0) - other.vertices.min(axis=0))
        m = trimesh.util.concatenate([box, other])
        m.merge_vertices()
        msg = "not 2-manifold at vertex"
    elif case == "self-intersecting":
        other = box.copy()
        other.apply_translation((0.01, 0.005, 0.003))
        m = trimesh.util.concatenate([box, other])
        msg = "surface intersects itself"
    elif case == "inconsistent":
        f = box.faces.copy()
        f[0] = f[0, ::-1]
        m = trimesh.Trimesh(box.vertices, f, process=False)
        msg = "inconsistent face winding"
    elif case == "flat":
        m = trimesh.Trimesh(box.vertices * [1, 1, 0], box.faces, process=False)
        msg = "zero volume"
    elif case == "unreadable":
        p = tmp_path / "junk.stl"
        p.write_bytes(b"solid junk\nfacet oops\n")
        return p, "junk.stl"
    elif case == "suffix":
        p = tmp_path / "mesh.fbx"
        p.write_text("x")
        return p, "expected a surface mesh .obj, .ply, .stl or .off"
    else:
        raise AssertionError(case)
    path = tmp_path / "mesh.obj"
    m.export(path)
    return path, msg


MESH_CASES = ["open", "inverted", "joined-at-vertex", "self-intersecting", "inconsistent", "flat", "unreadable",
              "suffix"]


@pytest.mark.parametrize("case", MESH_CASES)
def test_bad_mesh(tmp_path, capsys, case):
    path, field = _mesh(tmp_path, case)
    out = tmp_path / "out"
    rc, err, seconds = _run(["window", str(path), "--attach-below", "0.0", "--out", str(out), "--no-nonlinear",
                             "--no-sweep"], capsys, fn=kdfem_main)
    _check(rc, err, seconds, out, names=path.name, field=field)


def test_unwritable_output_is_reported_before_any_computation(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    out = blocker / "out"  # a folder inside a file
    t0 = time.perf_counter()
    rc = kdfaces_main(["run", str(REFERENCE), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "out" in err and "Traceback" not in err
    assert time.perf_counter() - t0 < 5  # checked first, not after simulating


def test_corpus_is_large_enough():
    assert len(SHOT_CASES) + len(CAPTURE_CASES) + len(RIG_CASES) + len(MESH_CASES) + 2 >= 60


DEMO_SHOT = Path(__file__).resolve().parents[1] / "kdfaces" / "shots" / "demo.toml"
# (entry point, argv, text of the one line): counts, factors and budgets that parse but cannot be right
ARG_CASES = [
    ("kdfaces", ["demo", "--threads", "0"], "threads: expected a whole number ≥ 1, got 0"),
    ("kdfaces", ["demo", "--threads", "-1"], "threads: expected a whole number ≥ 1, got -1"),
    ("kdfaces", ["demo", "--offset-grid", "-5"], "--offset-grid: expected a whole number ≥ 0, got -5"),
    ("kdfaces", ["bake", str(DEMO_SHOT), "--max-memory", "1k"], "--max-memory 1 KiB: one KD state needs"),
    ("kdfem", ["demo", "--threads", "0"], "threads: expected a whole number ≥ 1, got 0"),
    ("kdfaces", ["demo", "--max-steps", "10"], "demo.toml: 151 frames x at least 1 step per KD state"),
    ("kdfem", ["window", "--modes", "0"], "modes: expected a whole number ≥ 1, got 0"),
    ("kdfem", ["window", "--sweep-stride", "0"], "sweep_stride: expected a whole number ≥ 1, got 0"),
    ("kdfem", ["window", "--scale", "-1"], "scale: expected a positive factor"),
    ("kdfem", ["window", "--scale", "100"], "scale: 100.0 applies to a surface mesh file"),
]


@pytest.mark.parametrize("prog, argv, field", ARG_CASES, ids=[" ".join(c[1][:3]) for c in ARG_CASES])
def test_bad_arguments(tmp_path, capsys, prog, argv, field):
    out = tmp_path / "out"
    fn = kdfaces_main if prog == "kdfaces" else kdfem_main
    _check(*_run([*argv, "--out", str(out)], capsys, fn=fn), out, names=field.split(":")[0], field=field)


ARG_CASES_VIEW = [
    ("kdfaces", ["view", str(DEMO_SHOT), "--screenshot", "{tmp}/s.png", "--width", "0"], "--width, --height"),
    ("kdfaces", ["view", str(DEMO_SHOT), "--screenshot", "{tmp}/s.png", "--max-steps", "10"],
     "demo.toml: 151 frames x at least 1 step per KD state"),
    ("kdfaces", ["view", str(DEMO_SHOT), "--screenshot", "{tmp}/s.png", "--width", "100000"], "--width, --height"),
    ("kdfaces", ["render", str(DEMO_SHOT), "--frames", "-3", "--no-movie", "--out", "{tmp}/out"],
     "frames: expected a whole number ≥ 1, got -3"),
    ("kdfem", ["view", "--screenshot", "{tmp}/s.png", "--height", "-5"], "--width, --height"),
    ("kdfem", ["view", "--screenshot", "{tmp}/s.png", "--youngs-kpa", "-3"],
     "youngs_pa: expected a positive Young's modulus"),
    ("kdfem", ["view", "--screenshot", "{tmp}/s.png", "--youngs-kpa", "0"], "youngs_pa"),
]


@pytest.mark.parametrize("prog, argv, field", ARG_CASES_VIEW, ids=[" ".join(c[1][-2:]) for c in ARG_CASES_VIEW])
def test_bad_viewer_arguments(tmp_path, capsys, prog, argv, field):
    fn = kdfaces_main if prog == "kdfaces" else kdfem_main
    rc, err, seconds = _run([a.replace("{tmp}", str(tmp_path)) for a in argv], capsys, fn=fn)
    lines = [line for line in err.splitlines() if line.strip()]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err and field in lines[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no screenshot, no output folder


def test_an_error_inside_a_viewer_callback_is_raised_not_printed(capsys):
    """pyvista prints an exception raised inside a widget callback as a warning and goes on; the viewer keeps it
    and raises it (a screenshot must never be written over a failed state)."""
    from kdfem.viewer import HatViewer

    class Broken(HatViewer):
        def state(self):
            raise KDInputError("state: broken on purpose")

    with pytest.raises(KDInputError, match="broken on purpose"):
        Broken(off_screen=True)
    assert "Encountered issue in callback" not in capsys.readouterr().err


@pytest.mark.parametrize("prog, verb", [("kdfaces", "run"), ("kdfaces", "bake"), ("kdfaces", "render"),
                                        ("kdfem", "door")])
@pytest.mark.parametrize("text", ["", "# only a comment\n\n"], ids=["empty", "comment-only"])
def test_an_empty_shot_file_is_an_error_not_the_defaults(tmp_path, capsys, prog, verb, text):
    """An empty shot file parses (TOML allows it) but means nothing; it used to run the built-in demo (or door)."""
    shot = tmp_path / "mine.toml"
    shot.write_text(text)
    out = tmp_path / "out"
    fn = kdfaces_main if prog == "kdfaces" else kdfem_main
    _check(*_run([verb, str(shot), "--out", str(out)], capsys, fn=fn), out, names="mine.toml", field="is empty")
