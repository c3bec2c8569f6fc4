"""A capture that maps nothing useful is an error, not a frozen face.

If no channel of a capture drives a shape of the rig, or fewer than half of the channels that move in the take do
(constant channels and channels the map drops are not counted), the run stops with one line naming the first
unmapped channels and how to map them. ``strict`` is unchanged: any unmapped channel is an error.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from cli_checks import check_one_line, run_cli

from kdfaces import BlendshapeRig, load_shot
from kdfaces.errors import KDInputError
from kdfaces.motion.curves import KeyframeCurve
from kdfaces.motion.trajectory import (
    MIN_MAPPED_SHARE,
    FaceAnimation,
    KinematicTrajectory,
    ShapeTrack,
    UnmappedChannelsWarning,
)
from kdfaces.rig import ARKIT_NAMES


def _rig_with(default_rig, keep: int, *, style=lambda i, n: f"shape{i:02d}") -> BlendshapeRig:
    """The default head whose first ``keep`` shapes keep their ARKit names and the rest are renamed by ``style``."""
    names = [n if i < keep else style(i, n) for i, n in enumerate(default_rig.shape_names)]
    return BlendshapeRig.create(default_rig.neutral, default_rig.deltas, default_rig.faces, names,
                                skeleton=default_rig.skeleton, name=f"keep{keep}")


def _capture(moving=None, seed: int = 5) -> FaceAnimation:
    """The 52 ARKit channels; those in ``moving`` (default all) vary, the others hold 0.2."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 6)
    v = np.full((len(t), len(ARKIT_NAMES)), 0.2)
    cols = [ARKIT_NAMES.index(n) for n in (ARKIT_NAMES if moving is None else moving)]
    v[:, cols] = rng.uniform(0, 1, (len(t), len(cols)))
    return FaceAnimation(tracks=(ShapeTrack(ARKIT_NAMES, KeyframeCurve.create(t, v, interpolation="linear")),),
                         end_s=1.0, fps=30.0, strict_channels=False, name="take")


def test_fewer_than_half_of_the_moving_channels_mapped_is_one_error(default_rig):
    keep = int(np.ceil(MIN_MAPPED_SHARE * len(ARKIT_NAMES))) - 1  # 25 of 52
    rig = _rig_with(default_rig, keep)
    with pytest.raises(KDInputError) as e:
        KinematicTrajectory(rig, _capture())
    msg = str(e.value)
    assert "\n" not in msg
    first = [n for n in ARKIT_NAMES if n not in rig.shape_names][:4]
    assert msg.startswith(f"animation 'take': rig 'keep{keep}' has a shape for only {keep} of the 52 channels that "
                          "move in the take, fewer than 50%")
    assert f"unmapped: {', '.join(first)}, ..." in msg and "[animation.map]" in msg
    assert f"e.g. {first[0]} = " in msg  # an example line, channel = the rig's closest shape


def test_half_mapped_is_a_warning(default_rig):
    rig = _rig_with(default_rig, int(np.ceil(MIN_MAPPED_SHARE * len(ARKIT_NAMES))))  # 26 of 52
    with pytest.warns(UnmappedChannelsWarning, match="has no shape for channel"):
        traj = KinematicTrajectory(rig, _capture())
    assert len(traj.skipped_channels) == 26


def test_only_moving_channels_count(default_rig):
    rig = _rig_with(default_rig, 4)  # 4 of 52 shapes keep their names
    with pytest.raises(KDInputError, match="only 4 of the 52 channels that move"):
        KinematicTrajectory(rig, _capture())
    # the same rig under a take in which only its 4 channels and 3 others move: 4 of 7 map
    moving = list(default_rig.shape_names[:4]) + [n for n in ARKIT_NAMES if n not in rig.shape_names][:3]
    with pytest.warns(UnmappedChannelsWarning):
        traj = KinematicTrajectory(rig, _capture(moving))
    assert traj.moves()
    # 4 of 9 map: an error again, naming the first moving channels that do not
    with pytest.raises(KDInputError, match=r"only 4 of the 9 channels .* unmapped: " + ", ".join(moving[4:]) + ", "):
        KinematicTrajectory(rig, _capture(moving + [n for n in ARKIT_NAMES if n not in moving][-2:]))


def test_dropped_channels_are_not_counted(default_rig):
    rig = _rig_with(default_rig, 10)
    dropped = {n: False for n in ARKIT_NAMES if n not in rig.shape_names}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        traj = KinematicTrajectory(rig, _capture(), channel_map=dropped)
    assert sum(h == "name" for h in traj.channel_resolution.values()) == 10


def test_the_map_counts_as_mapped(default_rig):
    rig = _rig_with(default_rig, 0, style=lambda i, n: f"Studio{i:02d}")
    cmap = {n: f"Studio{i:02d}" for i, n in enumerate(default_rig.shape_names) if i % 2 == 0}  # 26 of 52
    with pytest.warns(UnmappedChannelsWarning):
        KinematicTrajectory(rig, _capture(), channel_map=cmap)
    del cmap[default_rig.shape_names[0]]
    with pytest.raises(KDInputError, match="only 25 of the 52"):
        KinematicTrajectory(rig, _capture(), channel_map=cmap)


def test_strict_is_unchanged(default_rig):
    rig = _rig_with(default_rig, 51)
    with pytest.raises(KDInputError, match="unknown shape name 'tongueOut'"):
        KinematicTrajectory(rig, _capture(), strict=True)
    with pytest.warns(UnmappedChannelsWarning, match="tongueOut"):
        KinematicTrajectory(rig, _capture())


def test_no_channel_mapped_is_one_error(default_rig):
    rig = _rig_with(default_rig, 0)
    with pytest.raises(KDInputError, match=r"has no shape for any of the 52 channels .* \[animation.map\]"):
        KinematicTrajectory(rig, _capture())


def _take(tmp_path) -> None:
    """A 1 s Live Link Face CSV at 30 Hz in which every blend-shape channel moves."""
    header = ["Timecode", "BlendShapeCount", *[n[0].upper() + n[1:] for n in ARKIT_NAMES], "HeadYaw", "HeadPitch",
              "HeadRoll"]
    lines = [",".join(header)]
    for k in range(31):
        w = [f"{0.5 + 0.4 * np.sin(k / 3 + c):.6f}" for c in range(len(ARKIT_NAMES))]
        lines.append(",".join([f"10:00:00:{k % 30:02d}.000" if k < 30 else "10:00:01:00.000", "61", *w, "0", "0", "0"]))
    (tmp_path / "take.csv").write_text("\n".join(lines) + "\n")


def _npz(tmp_path, default_rig, names) -> None:
    r = default_rig
    np.savez(tmp_path / "prod.npz", neutral=r.neutral, deltas=r.deltas, faces=r.faces, shape_names=np.array(names))


def test_kdfaces_run_of_a_capture_that_maps_too_little_exits_2_with_one_line(tmp_path, capsys, default_rig):
    _take(tmp_path)
    _npz(tmp_path, default_rig, [n if i < 10 else f"shape{i:02d}" for i, n in enumerate(default_rig.shape_names)])
    shot = tmp_path / "shot.toml"
    shot.write_text('[rig]\nsource = "prod.npz"\n[animation]\nsource = "take.csv"\n')
    out = tmp_path / "out"
    rc, err, seconds = run_cli(["run", str(shot), "--out", str(out)], capsys)
    check_one_line(rc, err, seconds, out, names="shot.toml: animation",
                   field="has a shape for only 10 of the 52 channels that move in the take")
    assert "[animation.map]" in err


def test_a_capture_on_a_studio_named_rig_maps_without_a_map(tmp_path, default_rig):
    """The issue's avatar: shapes named AK_nn_Name, no map — every channel finds its shape."""
    _take(tmp_path)
    _npz(tmp_path, default_rig, [f"AK_{i + 1:02d}_{n[0].upper() + n[1:]}" for i, n in
                                 enumerate(default_rig.shape_names)])
    shot = tmp_path / "shot.toml"
    shot.write_text('[rig]\nsource = "prod.npz"\n[animation]\nsource = "take.csv"\n')
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnmappedChannelsWarning)
        s = load_shot(shot)
    assert set(s.trajectory.channel_resolution.values()) == {"name"} and s.trajectory.moves()
