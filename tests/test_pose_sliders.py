"""The pose editor of ``kdfaces view`` (issue 26: "set shape weights and head angles with sliders at this frame: a
pose constraint"), driven off-screen through exactly the methods its sliders call.

Setting a weight or the head angles at a frame makes a pose constraint there through the authoring session, or
updates the one there (one per time), undoably; the constraint it builds is the shot loader's pose for that target
(the animation's pose with those weights replaced and the head turned), compared to round-off. Bad values are refused
with a status message and change nothing. The slider widgets (a window with widgets) call the same methods.
"""

import shutil
from pathlib import Path

import numpy as np
import pytest

from kdfaces.rig.poses import kinematic_pose

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "tests" / "reference" / "shot.toml"  # 1.2 s: jawOpen keyed, a pose constraint (head roll 10°) at 0.8 s


def _viewer(path, *, widgets=False):
    from kdfaces.shots.authoring import AuthoringSession
    from kdfaces.viz.viewer import ShotViewer

    session = AuthoringSession(path)
    return ShotViewer(session.shot, off_screen=True, size=(480, 360), widgets=widgets, session=session)


@pytest.fixture()
def small(tmp_path):
    shutil.copy(SMALL, tmp_path / "shot.toml")
    v = _viewer(tmp_path / "shot.toml")
    yield v
    v.close()


def _target_pose(v, row):
    """The pose constraint of ``row`` as built from the session's rows, (N, 3) [m]."""
    i = [k for k, r in enumerate(v.session.rows) if r.enabled].index(row)
    return v.session.constraints()[i].target


def test_pose_shapes_are_the_animated_ones_by_range(small):
    from kdfaces.viz.viewer import POSE_SLIDER_SHAPES

    v = small
    assert v.pose_shapes == ["jawOpen"]  # the only shape the shot keys
    # the rule on a shot animating more shapes than there are sliders: the largest weight ranges, at most 8
    w = v.trajectory.weights(v.times, 0)[0]
    v._pose_shapes = None
    v.trajectory = _Weights(v.trajectory, np.linspace(0.0, 1.0, len(v.times))[:, None] * np.arange(12)[None] / 11)
    try:
        names = v.pose_shapes
    finally:
        v.trajectory = v.trajectory.base
        v._pose_shapes = None
    assert len(names) == POSE_SLIDER_SHAPES
    assert names == [v.shot.rig.shape_names[k] for k in range(11, 11 - POSE_SLIDER_SHAPES, -1)]
    assert v.pose_shapes == ["jawOpen"] and w.shape[1] == v.shot.rig.num_shapes


class _Weights:
    """A trajectory whose first 12 shapes' weights are ``table`` (F, 12) on the viewer's frames (the rest zero)."""

    def __init__(self, base, table):
        self.base, self.table = base, table

    def weights(self, times, order=2):
        out = np.zeros((len(times), self.base.rig.num_shapes))
        out[:, : self.table.shape[1]] = self.table
        return (out,)


def test_sliders_set_and_update_a_pose_constraint(small):
    v = small
    rows0 = [r.key() for r in v.session.rows]
    v.set_frame(20)  # t = 0.8 s: the shot's pose constraint (head rolled 10°)
    assert v.pose_row() == 0
    weights, head = v.pose_values()
    jaw = v.shot.rig.shape_indices(["jawOpen"])[0]
    assert weights == {"jawOpen": pytest.approx(float(v.trajectory.weights([0.8], 0)[0][0, jaw]))}
    np.testing.assert_array_equal(head, [0.0, 0.0, 10.0])
    v.set_pose_weight("jawOpen", 0.4)
    assert len(v.session.rows) == 1 and v.selected == 0
    assert v.session.rows[0].target == {"head_deg": [0.0, 0.0, 10.0], "weights": {"jawOpen": 0.4}}
    np.testing.assert_allclose(_target_pose(v, 0), kinematic_pose(v.trajectory, 0.8, weights={"jawOpen": 0.4},
                                                                  head_deg=[0, 0, 10]), atol=1e-12)
    v.set_pose_head_deg(5.0, -3.0, 10.0)
    assert v.session.rows[0].target["head_deg"] == [5.0, -3.0, 10.0]
    assert v.pose_values()[0] == {"jawOpen": 0.4}
    np.testing.assert_array_equal(v.pose_values()[1], [5.0, -3.0, 10.0])
    # a frame without a pose constraint: the first slider edit makes one there
    v.set_frame(10)  # t = 0.4 s
    assert v.pose_row() is None
    v.set_pose_weight("jawOpen", 0.9)
    assert len(v.session.rows) == 2 and v.selected == 1 and v.pose_row() == 1
    r = v.session.rows[1]
    assert (r.kind, r.time_s, r.target) == ("pose", pytest.approx(0.4), {"weights": {"jawOpen": 0.9}})
    np.testing.assert_allclose(_target_pose(v, 1), kinematic_pose(v.trajectory, 0.4, weights={"jawOpen": 0.9}),
                               atol=1e-12)
    v.set_pose_head_deg(0.0, 8.0, 0.0)
    assert v.session.rows[1].target == {"weights": {"jawOpen": 0.9}, "head_deg": [0.0, 8.0, 0.0]}
    # every slider edit is one undo step, back to the file's rows
    for _ in range(4):
        assert v.undo()
    assert [r.key() for r in v.session.rows] == rows0
    assert v.redo() and v.session.rows[0].target["weights"] == {"jawOpen": 0.4}


def test_bad_slider_values_change_nothing(small):
    v = small
    v.set_frame(20)
    rows0 = [r.key() for r in v.session.rows]
    for name, value, why in (("elbowBend", 0.5, "elbowBend"), ("jawOpen", 5.0, "weights"),
                             ("jawOpen", "half", "could not convert")):
        assert not v.set_pose_weight(name, value)
        assert "refused" in v.status() and why in v.status() and "nothing changed" in v.status()
        assert [r.key() for r in v.session.rows] == rows0
    assert not v.set_pose_head_deg(0.0, 500.0, 0.0) and "refused" in v.status()
    assert [r.key() for r in v.session.rows] == rows0
    # off-screen there are no slider widgets: the key says so, the methods work
    assert v.toggle_pose_sliders() is False and "only in a window with widgets" in v.status()


def test_slider_widgets_call_the_methods(tmp_path):
    shutil.copy(SMALL, tmp_path / "shot.toml")
    v = _viewer(tmp_path / "shot.toml", widgets=True)
    try:
        v.set_frame(20)
        assert v._show_pose_sliders(True)  # what key k shows in a window
        assert list(v._pose_sliders) == ["jawOpen", "head_yaw", "head_pitch", "head_roll"]
        assert v._pose_sliders["head_roll"].GetRepresentation().GetValue() == pytest.approx(10.0)
        assert not v._sliders["settle"].GetEnabled() and v._sliders["frame"].GetEnabled()
        w = v._pose_sliders["head_yaw"]
        w.GetRepresentation().SetValue(7.0)
        w.InvokeEvent("EndInteractionEvent")  # the slider released
        v.raise_callback_error()
        assert v.session.rows[0].target["head_deg"] == [7.0, 0.0, 10.0]
        v.set_frame(10)  # the sliders follow the frame: the animation's weight, no head offset
        jaw = float(v.trajectory.weights([v.times[10]], 0)[0][0, v.shot.rig.shape_indices(["jawOpen"])[0]])
        assert jaw > 0.5 and v._pose_sliders["jawOpen"].GetRepresentation().GetValue() == pytest.approx(jaw)
        assert v._pose_sliders["head_yaw"].GetRepresentation().GetValue() == pytest.approx(0.0)
        assert len(v.session.rows) == 1  # following the frame is no edit
        v._show_pose_sliders(False)
        assert v._sliders["settle"].GetEnabled() and not v._pose_sliders["jawOpen"].GetEnabled()
    finally:
        v.close()
