"""Shape names on any rig: canonical ARKit keys, ambiguity, and the same groups, settle map and x_K on a renamed copy.

A rig keeps its own names (``AK_25_JawOpen`` stays ``AK_25_JawOpen``: exports and pose constraints use it); every
lookup goes through the canonical key, so a renamed copy of the default head must behave exactly like the head.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from kdfaces import BlendshapeRig
from kdfaces.dynamics.gains import soft_tissue_settle_map
from kdfaces.errors import KDInputError
from kdfaces.motion.curves import KeyframeCurve
from kdfaces.motion.trajectory import FaceAnimation, KinematicTrajectory, ShapeTrack
from kdfaces.rig import ARKIT_NAMES, GROUP_SHAPES, alias_key, canonical_name, vertex_group
from kdfaces.rig.names import find_shapes, resolve_channels


@pytest.mark.parametrize("name, arkit", [
    ("AK_25_JawOpen", "jawOpen"), ("AK_01_BrowDownLeft", "browDownLeft"), ("XY_7_tongueOut", "tongueOut"),
    ("25_jawOpen", "jawOpen"),
    ("Mouth_Smile_L", "mouthSmileLeft"), ("Mouth_Smile_R", "mouthSmileRight"), ("mouth_roll_lower", "mouthRollLower"),
    ("blendShape1.jawOpen", "jawOpen"), ("blendShape1.eyeBlink_L", "eyeBlinkLeft"), ("Shapes.cheekPuff", "cheekPuff"),
    ("BS_jawOpen", "jawOpen"), ("bs_mouthFunnel", "mouthFunnel"), ("head:browInnerUp", "browInnerUp"),
    ("blendShape1.AK_24_mouthSmile_L", "mouthSmileLeft"),
    ("L_mouthSmile", "mouthSmileLeft"), ("R_mouthSmile", "mouthSmileRight"), ("Left_browOuterUp", "browOuterUpLeft"),
    ("MouthSmileLeft", "mouthSmileLeft"), ("mouthSmile_l", "mouthSmileLeft"), ("mouthSmile_r", "mouthSmileRight"),
    ("eyeBlink.L", "eyeBlinkLeft"), ("eyeBlink_Right", "eyeBlinkRight"), ("EYEBLINKLEFT", "eyeBlinkLeft"),
    ("eye_blink_left", "eyeBlinkLeft"), ("EyeBlinkLeft", "eyeBlinkLeft"), ("mouthLeft", "mouthLeft"),
])
def test_canonical_names(name, arkit):
    assert canonical_name(name) == arkit
    assert alias_key(name) == arkit.lower()


@pytest.mark.parametrize("name", ["JawDrop", "viseme_aa", "browInnerUp_L", "smile", "AK_25_", "L_"])
def test_other_names_stay_as_they_are(name):
    assert canonical_name(name) == name


def _words(n: str) -> list[str]:
    return re.findall(r"[A-Z]?[a-z]+", n[0].upper() + n[1:])


def _renamed_name(i: int, n: str) -> str:
    """The i-th ARKit name ``n`` in one of four studio conventions."""
    words = _words(n)
    side = words[-1] if words[-1] in ("Left", "Right") else ""
    stem = words[:-1] if side else words
    if i % 4 == 0:
        return f"AK_{i + 1:02d}_{''.join(words)}"  # AK_25_JawOpen
    if i % 4 == 1:
        return "_".join(stem) + (f"_{side[0]}" if side else "")  # Mouth_Smile_L
    if i % 4 == 2:
        return f"blendShape1.{n}"
    return f"{side[0]}_{''.join(stem)}" if side else f"BS_{n}"  # L_MouthSmile, BS_jawOpen


@pytest.fixture(scope="module")
def renamed(default_rig):
    """The default head with every shape renamed (four conventions) and the shapes in reversed order."""
    order = np.arange(default_rig.num_shapes)[::-1]
    names = [_renamed_name(int(k), default_rig.shape_names[k]) for k in order]
    rig = BlendshapeRig.create(default_rig.neutral, default_rig.deltas[order], default_rig.faces, names,
                               skeleton=default_rig.skeleton, name="studio")
    return rig, order


def test_the_renamed_rig_keeps_its_names_and_canonicalises_each_once(renamed, default_rig):
    rig, order = renamed
    assert rig.shape_names[0] == _renamed_name(int(order[0]), default_rig.shape_names[order[0]])
    assert not set(rig.shape_names) & set(ARKIT_NAMES)  # not rewritten
    canon = [canonical_name(n) for n in rig.shape_names]
    assert sorted(canon) == sorted(default_rig.shape_names)  # one candidate for each canonical name
    assert rig.shape_indices(list(default_rig.shape_names)) == [int(np.flatnonzero(order == k)[0])
                                                               for k in range(default_rig.num_shapes)]
    own = rig.shape_names[3]
    assert rig.shape_indices([own]) == [3]  # the rig's own names work too (pose constraints, exports)


@pytest.mark.parametrize("group", sorted(GROUP_SHAPES))
def test_groups_on_the_renamed_rig_are_the_default_rigs(renamed, default_rig, group):
    np.testing.assert_array_equal(vertex_group(renamed[0], group), vertex_group(default_rig, group))


def test_the_settle_map_on_the_renamed_rig_is_the_default_rigs(renamed, default_rig):
    a = soft_tissue_settle_map(default_rig, stiff_s=0.12, loose_s=0.4)
    b = soft_tissue_settle_map(renamed[0], stiff_s=0.12, loose_s=0.4)
    np.testing.assert_array_equal(a, b)  # the same shapes in the same order: the same floats
    assert np.ptp(a) > 0.2


def _capture(names, seed: int = 3) -> FaceAnimation:
    """A 52-channel capture-like animation (every channel moves), not strict as captures are."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 9)
    curve = KeyframeCurve.create(t, rng.uniform(0, 1, (len(t), len(names))), interpolation="catmull-rom")
    return FaceAnimation(tracks=(ShapeTrack(tuple(names), curve),), end_s=1.0, fps=30.0, strict_channels=False)


def test_capture_channels_drive_the_same_shapes_on_the_renamed_rig(renamed, default_rig):
    rig, order = renamed
    anim = _capture(ARKIT_NAMES)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every channel maps: no warning
        a = KinematicTrajectory(default_rig, anim)
        b = KinematicTrajectory(rig, anim)
    assert set(b.channel_resolution.values()) == {"name"}
    t = np.linspace(0.0, 1.0, 7)
    wa, wb = a.weights(t, 0)[0], b.weights(t, 0)[0]
    np.testing.assert_array_equal(wb, wa[:, order])  # channel k drives the renamed copy of shape k
    for xa, xb in zip(a.evaluate(t, 2), b.evaluate(t, 2)):
        # the same sum in another order of shapes: float64 rounding only (|x| ≤ 2 m, 52 terms)
        np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-12)


def test_a_pose_in_the_rigs_own_names_is_the_same_pose(renamed, default_rig):
    rig, order = renamed
    jaw = rig.shape_names[int(np.flatnonzero(order == default_rig.shape_names.index("jawOpen"))[0])]
    assert jaw.lower().endswith("jawopen") and jaw != "jawOpen"
    own = rig.blend(rig.weight_vector({jaw: 0.7}))
    arkit = rig.blend(rig.weight_vector({"jawOpen": 0.7}))
    np.testing.assert_array_equal(own, arkit)
    np.testing.assert_allclose(own, default_rig.blend(default_rig.weight_vector({"jawOpen": 0.7})), atol=1e-12)


def test_exports_keep_the_rigs_own_names(renamed, tmp_path):
    from kdfaces.io.rigfiles import load_npz, save_npz

    rig = renamed[0]
    assert load_npz(save_npz(rig, tmp_path / "studio.npz")).shape_names == rig.shape_names


def _two_jaws(default_rig) -> BlendshapeRig:
    """The default head with its jawOpen twice, as ``AK_25_JawOpen`` and ``blendShape1.jawOpen``."""
    k = default_rig.shape_names.index("jawOpen")
    names = [n for n in default_rig.shape_names if n != "jawOpen"] + ["AK_25_JawOpen", "blendShape1.jawOpen"]
    keep = [i for i in range(default_rig.num_shapes) if i != k]
    deltas = np.concatenate([default_rig.deltas[keep], default_rig.deltas[[k, k]] * [[[1.0]], [[0.5]]]])
    return BlendshapeRig.create(default_rig.neutral, deltas, default_rig.faces, names, name="twins")


def test_two_candidates_load_and_every_use_of_the_name_names_both(default_rig):
    rig = _two_jaws(default_rig)  # loads
    both = r"2 shapes of the rig could be 'jawOpen' \('AK_25_JawOpen', 'blendShape1.jawOpen'\)"
    with pytest.raises(KDInputError, match=both):
        rig.shape_indices(["jawOpen"])
    with pytest.raises(KDInputError, match="group.*" + both):
        vertex_group(rig, "jaw")
    with pytest.raises(KDInputError, match="channel jawOpen: " + both):
        KinematicTrajectory(rig, _capture(ARKIT_NAMES))
    with pytest.raises(KDInputError, match="settle_time map.*" + both):
        soft_tissue_settle_map(rig, stiff_s=0.1, loose_s=0.4)
    # other names, and the twins by their own names, are unaffected
    assert rig.shape_indices(["AK_25_JawOpen", "blendShape1.jawOpen"]) == [rig.num_shapes - 2, rig.num_shapes - 1]
    np.testing.assert_array_equal(vertex_group(rig, "lips"), vertex_group(default_rig, "lips"))
    # the map settles it: the capture's jawOpen drives the one it names
    traj = KinematicTrajectory(rig, _capture(ARKIT_NAMES), channel_map={"jawOpen": "AK_25_JawOpen"})
    assert traj.channel_resolution["jawOpen"] == "map"
    jaw = vertex_group(rig, "jaw", channel_map={"jawOpen": "AK_25_JawOpen"})
    np.testing.assert_array_equal(jaw, vertex_group(default_rig, "jaw"))


def _jaw_drop(default_rig) -> BlendshapeRig:
    names = ["JawDrop" if n == "jawOpen" else n for n in default_rig.shape_names]
    return BlendshapeRig.create(default_rig.neutral, default_rig.deltas, default_rig.faces, names, name="drop")


def test_groups_take_the_map_into_account(default_rig):
    rig = _jaw_drop(default_rig)
    jaw = vertex_group(rig, "jaw", channel_map={"jawOpen": "JawDrop"})
    np.testing.assert_array_equal(jaw, vertex_group(default_rig, "jaw"))
    # a map entry that drops the channel from the capture does not hide the shape from a group
    np.testing.assert_array_equal(vertex_group(default_rig, "jaw", channel_map={"jawOpen": False}), jaw)
    # the settle map takes the map too
    cmap = {"jawOpen": "JawDrop"}
    np.testing.assert_array_equal(soft_tissue_settle_map(rig, stiff_s=0.1, loose_s=0.4, channel_map=cmap),
                                  soft_tissue_settle_map(default_rig, stiff_s=0.1, loose_s=0.4))


def test_an_underivable_group_suggests_shape_and_the_closest_shapes(default_rig):
    rig = _jaw_drop(default_rig)
    with pytest.raises(KDInputError) as e:
        vertex_group(rig, "jaw", where="shot.toml: constraints[0].group")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("shot.toml: constraints[0].group: rig 'drop' has none of the shapes")
    assert "shape:<name>" in msg and "closest to 'jaw': JawDrop" in msg
    np.testing.assert_array_equal(vertex_group(rig, "shape:JawDrop"), vertex_group(default_rig, "jaw"))


def test_an_unknown_group_suggests_shape_and_the_closest_shapes(default_rig):
    with pytest.raises(KDInputError, match=r"unknown group 'cheekz'.*'shape:<name>'.*closest to 'cheekz': cheek"):
        vertex_group(default_rig, "cheekz")


def test_side_split_shapes_serve_channels_and_groups(default_rig):
    k = default_rig.shape_names.index("browInnerUp")
    left = (default_rig.neutral[:, 0] > 0)[:, None]
    d = default_rig.deltas[k]
    names = [n for n in default_rig.shape_names if n != "browInnerUp"] + ["L_BrowInnerUp", "BrowInnerUp_R"]
    keep = [i for i in range(default_rig.num_shapes) if i != k]
    rig = BlendshapeRig.create(default_rig.neutral, np.concatenate([default_rig.deltas[keep], [d * left, d * ~left]]),
                               default_rig.faces, names, name="split")
    res = resolve_channels(["browInnerUp"], rig.shape_names)
    assert res.how == {"browInnerUp": "sides"} and res.pairs[:, 1].tolist() == [rig.num_shapes - 2, rig.num_shapes - 1]
    assert find_shapes(["browInnerUp"], rig.shape_names) == [rig.num_shapes - 2, rig.num_shapes - 1]
    np.testing.assert_array_equal(vertex_group(rig, "brows"), vertex_group(default_rig, "brows"))
