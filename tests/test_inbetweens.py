"""In-betweens (FBX ``<channel>@<percent>`` targets) through the rig files: npz round trip, glTF extras (and the
weight animation a glTF carries), OBJ folders and ``export-rig`` saying what they lose; dynamics parts named after
groups through the shot's ``[animation.map]``."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from fbx_fixtures import write_ascii_fbx, write_gltf_twin

from kdfaces.errors import KDInputError
from kdfaces.io import export_rig, load_fbx_rig, load_gltf, load_gltf_rig, load_npz, save_gltf, save_npz
from kdfaces.io.gltf import INBETWEENS_EXTRAS
from kdfaces.io.rigfiles import LostInbetweensWarning, load_default_rig, load_obj_folder, load_rig, save_obj_folder
from kdfaces.motion.curves import KeyframeCurve
from kdfaces.motion.trajectory import FaceAnimation, KinematicTrajectory, ShapeTrack
from kdfaces.rig.blendshapes import RigUnitsWarning
from kdfaces.rig.groups import vertex_group
from kdfaces.rig.parts import part_vertices

CHANNEL_WEIGHTS = (-0.2, 0.0, 0.25, 0.5, 0.8, 1.0, 1.3)  # both segments and both extrapolations of jawOpen


@pytest.fixture(scope="module")
def fbx(tmp_path_factory):
    d = tmp_path_factory.mktemp("inbetweens")
    rig = load_fbx_rig(write_ascii_fbx(d / "fixture.fbx"))
    assert rig.inbetweens == ((1, (0, 1), (0.5, 1.0)),)  # jawOpen@50, jawOpen: the fixture has one in-between
    return rig, d


def _channel_poses(rig) -> np.ndarray:
    """Positions (7, N, 3) [m] of the rig at jawOpen = each of CHANNEL_WEIGHTS, mouthSmileLeft 0.4."""
    w = np.zeros((len(CHANNEL_WEIGHTS), rig.num_shapes))
    w[:, rig.shape_names.index("jawOpen")] = CHANNEL_WEIGHTS
    w[:, rig.shape_names.index("mouthSmileLeft")] = 0.4
    return rig.blend_channels(w)


def _float32_tol(rig) -> float:
    """glTF stores the neutral as float32: half an ulp of the largest coordinate each, one ulp with the blend."""
    return float(np.spacing(np.float32(np.abs(rig.neutral).max())))


def test_npz_round_trips_inbetweens_exactly(fbx, tmp_path):
    rig, _ = fbx
    back = load_npz(save_npz(rig, tmp_path / "rig.npz"))
    assert back.inbetweens == rig.inbetweens and back.shape_names == rig.shape_names
    np.testing.assert_array_equal(_channel_poses(back), _channel_poses(rig))  # same numbers, same arithmetic
    # load_rig's units rescale keeps them (the fixture is head-sized in metres: read as cm it is not, hence the
    # units warning, which is not what this checks)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RigUnitsWarning)
        assert load_rig(tmp_path / "rig.npz", units="cm").inbetweens == rig.inbetweens
    # a rig without in-betweens writes no in-between fields
    plain = tmp_path / "plain.npz"
    save_npz(load_default_rig(), plain)
    with np.load(plain) as d:
        assert not [f for f in d.files if f.startswith("inbetween")]
    assert load_npz(plain).inbetweens == ()


def test_npz_with_broken_inbetween_fields_is_one_error(fbx, tmp_path):
    rig, _ = fbx
    good = tmp_path / "rig.npz"
    save_npz(rig, good)
    with np.load(good) as d:
        fields = {k: d[k] for k in d.files}
    cases = {
        "counts": (dict(inbetween_counts=np.array([3])), "inbetween_counts"),
        "missing": (dict(inbetween_rows=None), "lacks field(s) ['inbetween_rows']"),
        "decreasing": (dict(inbetween_full_weights=np.array([1.0, 0.5])), "strictly increasing"),
        "row": (dict(inbetween_rows=np.array([0, 7])), "rows in [0, 3)"),
    }
    for case, (change, field) in cases.items():
        f = {**fields, **change}
        p = tmp_path / f"{case}.npz"
        np.savez(p, **{k: v for k, v in f.items() if v is not None})
        with pytest.raises(KDInputError) as e:
            load_npz(p)
        msg = str(e.value)
        assert msg.startswith(str(p)) and field in msg and "\n" not in msg, (case, msg)


@pytest.mark.parametrize("suffix", [".gltf", ".glb"])
def test_gltf_round_trips_inbetweens(fbx, tmp_path, suffix):
    """FBX → glTF → load keeps in-betweens: written in mesh.extras, read back as the same channels."""
    rig, _ = fbx
    back = load_gltf_rig(save_gltf(rig, tmp_path / f"rig{suffix}"))
    assert back.inbetweens == rig.inbetweens and back.shape_names == rig.shape_names
    assert np.abs(_channel_poses(back) - _channel_poses(rig)).max() <= _float32_tol(rig)
    # at the in-between's own weight the read-back rig is that target, not half the full one
    half = back.blend_channels(np.array([0.0, 0.5, 0.0]))
    assert np.abs(half - (back.neutral + back.deltas[0])).max() < 1e-12
    assert np.abs(back.deltas[0] - 0.5 * back.deltas[1]).max() > 1e-3  # the in-between matters


def test_gltf_without_metadata_stays_linear(fbx):
    """A glTF written by another tool with ``jawOpen@50`` targets but no kdfaces metadata is linear in its targets:
    names are never taken for in-betweens."""
    _, d = fbx
    twin = load_gltf_rig(write_gltf_twin(d / "twin.gltf"))
    assert "jawOpen@50" in twin.shape_names and twin.inbetweens == ()
    w = np.array([0.3, 0.5, 0.0])
    np.testing.assert_array_equal(twin.blend_channels(w), twin.blend(w))


def _edit_extras(path, edit) -> None:
    doc = json.loads(path.read_text())
    edit(doc["meshes"][0]["extras"])
    path.write_text(json.dumps(doc))


def test_gltf_animation_of_an_inbetween_rig_plays_everywhere(fbx, tmp_path):
    """The weights channel holds target weights (what any glTF player blends linearly); load_gltf turns them back
    into channel weights, so the trajectory is the original one at every frame, and the file read as a plain
    linear rig (metadata stripped: another tool's view) shows the same motion."""
    rig, _ = fbx
    curve = KeyframeCurve.create([0.0, 1.0], [[0.0, 0.0], [1.2, 0.4]], interpolation="linear")
    anim = FaceAnimation(tracks=(ShapeTrack(("jawOpen", "mouthSmileLeft"), curve),), start_s=0.0, end_s=1.0,
                         fps=30.0)
    path = save_gltf(rig, tmp_path / "anim.gltf", animation=anim)
    back, back_anim = load_gltf(path)
    times = anim.frame_times
    want = KinematicTrajectory(rig, anim).evaluate(times, 0)[0]
    got = KinematicTrajectory(back, back_anim).evaluate(times, 0)[0]
    # float32 neutral, float32 weights (relative 2^-24 of |w| ≤ 1.2 on ≤ 2 targets per channel) and float32 times
    tol = _float32_tol(rig) + 4 * 2.0**-24 * 1.2 * float(np.abs(rig.deltas).max()) * 3
    assert np.abs(got - want).max() <= tol
    _edit_extras(path, lambda extras: extras.pop(INBETWEENS_EXTRAS))
    plain, plain_anim = load_gltf(path)
    assert plain.inbetweens == ()
    assert np.abs(KinematicTrajectory(plain, plain_anim).evaluate(times, 0)[0] - want).max() <= tol


def test_gltf_with_bad_inbetween_metadata_is_one_error(fbx, tmp_path):
    rig, _ = fbx
    cases = {
        "unknown-target": (lambda e: e[INBETWEENS_EXTRAS][0]["targets"].__setitem__(0, "jawOpen@40"),
                           "extras.kdfaces_inbetweens[0]: 'jawOpen@40' is not one of the mesh's"),
        "count": (lambda e: e[INBETWEENS_EXTRAS][0]["full_weights"].pop(), "one full weight per target"),
        "not-a-list": (lambda e: e.__setitem__(INBETWEENS_EXTRAS, {"jawOpen": 1}), "expected a list"),
        "decreasing": (lambda e: e[INBETWEENS_EXTRAS][0].__setitem__("full_weights", [1.0, 0.5]),
                       "strictly increasing"),
    }
    for case, (edit, field) in cases.items():
        path = save_gltf(rig, tmp_path / f"{case}.gltf")
        _edit_extras(path, edit)
        with pytest.raises(KDInputError) as e:
            load_gltf_rig(path)
        msg = str(e.value)
        assert msg.startswith(str(path)) and field in msg and "\n" not in msg, (case, msg)


def test_obj_folder_and_export_rig_name_the_lost_inbetweens(fbx, tmp_path):
    """OBJ folders cannot keep in-betweens: one warning names the channel and its targets; the targets are still
    written as OBJs; export-rig's glTF keeps them."""
    rig, d = fbx
    with pytest.warns(LostInbetweensWarning, match=r"'jawOpen' \(jawOpen@50 at 0\.5, jawOpen at 1\)") as rec:
        save_obj_folder(rig, tmp_path / "obj")
    assert len(rec) == 1
    back = load_obj_folder(tmp_path / "obj")
    assert back.inbetweens == () and sorted(back.shape_names) == sorted(rig.shape_names)
    with pytest.warns(LostInbetweensWarning):
        written = export_rig(rig, tmp_path / "export", formats=["obj", "gltf"])
    assert load_gltf_rig(written[1]).inbetweens == rig.inbetweens
    with warnings.catch_warnings():  # glTF alone, or a linear rig, lose nothing and say nothing
        warnings.simplefilter("error", LostInbetweensWarning)
        export_rig(rig, tmp_path / "gltf_only", formats=["glb"])
        save_obj_folder(load_gltf_rig(write_gltf_twin(d / "twin2.gltf")), tmp_path / "linear")


# ----------------------------------------------------------------------------------------------------------------
# dynamics parts named after groups, through [animation.map]


def _jawdrop_rig(tmp_path):
    """The default head with its jawOpen shape called "JawDrop" (no other shape of group "jaw" has an ARKit
    name)."""
    rig = load_default_rig()
    names = ["JawDrop" if n == "jawOpen" else n for n in rig.shape_names]
    p = tmp_path / "jawdrop.npz"
    np.savez(p, neutral=rig.neutral, deltas=rig.deltas, faces=rig.faces, shape_names=np.array(names))
    return load_npz(p), p


def test_part_named_after_a_group_uses_the_channel_map(tmp_path):
    rig, _ = _jawdrop_rig(tmp_path)
    with pytest.raises(KDInputError, match="shape:"):
        part_vertices(rig, "jaw", where="dynamics.parts.jaw")
    idx = part_vertices(rig, "jaw", where="dynamics.parts.jaw", channel_map={"jawOpen": "JawDrop"})
    # closed form: the vertices JawDrop moves by at least a quarter of its largest displacement (vertex_group)
    mag = np.linalg.norm(rig.deltas[rig.shape_names.index("JawDrop")].astype(np.float64), axis=1)
    np.testing.assert_array_equal(idx, np.flatnonzero(mag >= 0.25 * mag.max()))
    np.testing.assert_array_equal(idx, vertex_group(rig, "shape:JawDrop"))
    assert 0 < len(idx) < rig.num_vertices


def test_shot_dynamics_parts_use_the_animation_map(tmp_path):
    from kdfaces.rig import ARKIT_NAMES
    from kdfaces.shots.shotfile import load_shot

    rig, p = _jawdrop_rig(tmp_path)
    # a one-second Live Link Face take at 30 fps in which the jaw opens and closes
    header = ["Timecode", "BlendShapeCount", *[n[0].upper() + n[1:] for n in ARKIT_NAMES], "HeadYaw", "HeadPitch",
              "HeadRoll"]
    rows = []
    for k in range(30):
        w = ["0.1"] * len(ARKIT_NAMES)
        w[ARKIT_NAMES.index("jawOpen")] = f"{0.5 + 0.4 * np.sin(k / 3):.6f}"
        rows.append(",".join([f"01:00:00:{k:02d}.000", "61", *w, "0", "0", "0"]))
    (tmp_path / "take.csv").write_text("\n".join([",".join(header), *rows]) + "\n")
    shot = tmp_path / "shot.toml"
    shot.write_text(f"""
[rig]
source = "{p.name}"

[animation]
source = "take.csv"

[animation.map]
jawOpen = "JawDrop"

[dynamics]
settle_time_s = 0.3

[dynamics.parts]
jaw = {{ settle_time_s = 0.05, rigid = true }}
""")
    s = load_shot(shot)
    jaw = vertex_group(rig, "shape:JawDrop")
    settle = s.settle_time()
    assert np.all(settle[jaw] == 0.05) and np.count_nonzero(settle == 0.05) == len(jaw)
    assert s.rigid()[jaw].all()
    assert s.model().rigid_mask[jaw].all()
