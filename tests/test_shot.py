"""TOML shot files: parsing, target resolution, and one clear error for each kind of bad file."""

import numpy as np
import pytest

from kdfaces import KDInputError
from kdfaces.rig.groups import vertex_group
from kdfaces.rig.poses import kinematic_pose
from kdfaces.shots.shotfile import load_shot

GOOD = """
name = "t"
[animation]
source = "keys"
end_s = 2.0
[[animation.tracks]]
shapes = ["mouthSmile_L", "mouthSmile_R"]
times_s = [0.0, 0.5, 2.0]
values = [[0, 0], [1, 1], [0, 0]]
[animation.head]
times_s = [0.0, 0.4, 2.0]
yaw_deg = [0, 30, 0]
[dynamics]
settle_time_s = { stiff_s = 0.1, loose_s = 0.3 }
window_s = 0.8
[[constraints]]
time_s = 1.0
kind = "pose"
target = { weights = { jawOpen = 0.5 }, head_deg = [0, 0, 10] }
width_s = 0.3
[[constraints]]
time_s = 1.4
kind = "subset"
group = "lips"
curve = "asymmetric"
ease_out_s = 0.6
[[constraints]]
time_s = 1.4
kind = "velocity"
group = "brows"
[[constraints]]
time_s = 1.8
kind = "end_effector"
group = [10, 11, 12]
target = { offset_m = [0, -0.005, 0] }
curve = "poly"
"""


def write(tmp_path, text, name="shot.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_good_shot(tmp_path):
    shot = load_shot(write(tmp_path, GOOD))
    cs = shot.constraints()
    assert [c.kind for c in cs] == ["pose", "subset", "velocity", "end_effector"]
    traj = shot.trajectory
    # pose target: jaw half open and head rolled by 10° on top of the animation at t = 1 s
    expect = kinematic_pose(traj, 1.0, weights={"jawOpen": 0.5}, head_deg=[0, 0, 10])
    np.testing.assert_array_equal(cs[0].target, expect)
    assert np.linalg.norm(expect - traj.positions([1.0])[0], axis=1).max() > 0.01
    # subset: the lips of the kinematic pose; velocity: the brows' kinematic velocity (default targets)
    lips = vertex_group(shot.rig, "lips")
    np.testing.assert_array_equal(cs[1].indices, lips)
    np.testing.assert_allclose(cs[1].target, traj.positions([1.4])[0][lips])
    np.testing.assert_allclose(cs[2].target, traj.evaluate([1.4], 1)[1][0][vertex_group(shot.rig, "brows")])
    np.testing.assert_allclose(cs[3].target, traj.positions([1.8])[0][[10, 11, 12]].mean(0) + [0, -0.005, 0])
    assert cs[1].basis.support()[1] - 1.4 == pytest.approx(3 * 0.6)
    assert isinstance(shot.settle_time(), np.ndarray) and shot.settle_time().min() >= 0.1 - 1e-12


@pytest.mark.parametrize(
    "edit, match",
    [
        (('shapes = ["mouthSmile_L", "mouthSmile_R"]', 'shapes = ["mouthSmyle_L", "mouthSmile_R"]'),
         "unknown shape name 'mouthSmyle_L'"),
        (("time_s = 1.8", "time_s = 2.5"), r"constraints\[3\].time_s: 2.5 s is outside the shot \[0.0, 2.0\] s"),
        (("width_s = 0.3", "width_s = -0.3"), r"constraints\[0\].width_s: expected a positive number"),
        (('group = "lips"', 'group = "lipz"'), "unknown group 'lipz'"),
        (("window_s = 0.8", "window_s = -1"), r"dynamics.window_s: expected 'auto' or a positive number \(got -1\)"),
        (("[dynamics]", "[dynamics]\nstifness = 3"), r"dynamics.stifness: unknown key"),
        (('kind = "pose"', 'kind = "pos"'), r"constraints\[0\].kind: expected 'pose', 'subset', 'velocity' or "
                                            r"'end_effector' \(got 'pos'\)"),
        (("target = { weights = { jawOpen = 0.5 }", "target = { weights = { jawOpen = nan }"),
         r"constraints\[0\].target.weights.jawOpen: expected a finite number"),
    ],
)
def test_bad_shot_files(tmp_path, edit, match):
    text = GOOD.replace(*edit)
    assert text != GOOD
    with pytest.raises(KDInputError, match=match) as info:
        load_shot(write(tmp_path, text))
    assert "shot.toml" in str(info.value)


def test_conflicting_constraints_at_the_same_time(tmp_path):
    text = GOOD + """
[[constraints]]
time_s = 1.0
kind = "subset"
group = "jaw"
width_s = 0.3
"""
    with pytest.raises(KDInputError, match=r"\(pose at 1 s #0\) and .*\(subset at 1 s #4\) have conflicting targets"):
        load_shot(write(tmp_path, text))


def test_not_toml_and_missing(tmp_path):
    with pytest.raises(KDInputError, match="not valid TOML"):
        load_shot(write(tmp_path, "name = [unclosed"))
    with pytest.raises(KDInputError, match="file not found"):
        load_shot(tmp_path / "none.toml")


def test_falloff_m_is_a_constraint_option(tmp_path):
    from kdfaces import defaults

    text = GOOD.replace('curve = "poly"', 'curve = "poly"\nfalloff_m = 0.03')
    cs = load_shot(write(tmp_path, text)).constraints()
    assert cs[3].falloff_m == 0.03 and cs[1].falloff_m == defaults.FALLOFF_M  # end effector set, subset default
    for bad, match in [("falloff_m = -0.01", r"constraints\[3\].falloff_m: expected greater than or equal to 0"),
                       ("falloff_m = true", r"constraints\[3\].falloff_m")]:
        with pytest.raises(KDInputError, match=match):
            load_shot(write(tmp_path, text.replace("falloff_m = 0.03", bad)))
    on_pose = GOOD.replace("width_s = 0.3", "width_s = 0.3\nfalloff_m = 0.03", 1)
    with pytest.raises(KDInputError, match=r"constraints\[0\].falloff_m: .* not to a pose constraint"):
        load_shot(write(tmp_path, on_pose))
