"""Live Link Face CSV import: the real take (when present) and broken files."""

import numpy as np
import pytest

from kdfaces import KDInputError, KinematicTrajectory, livelinkface_animation, read_livelinkface
from kdfaces.rig.names import ARKIT_NAMES

HEADER = "Timecode,BlendShapeCount," + ",".join(n[0].upper() + n[1:] for n in ARKIT_NAMES) + \
    ",HeadYaw,HeadPitch,HeadRoll,LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll"


def write_csv(path, header=HEADER, rows=30, shuffle=False, value="0.5"):
    cols = header.split(",")
    if shuffle:  # the CSV order is not the ARKit order: columns are found by name
        cols = cols[:2] + cols[2:54][::-1] + cols[54:]
    lines = [",".join(cols)]  # FF = 0, 2, 4, ... at a 60 fps timecode: 30 Hz samples
    for r in range(rows):
        vals = [value] * 52 + ["0.1", "0", "0"] + ["0"] * 6
        lines.append(f"10:00:00:{2 * r:02d}.000,61," + ",".join(vals))
    path.write_text("\n".join(lines) + "\n")
    return path


def test_real_take(llf_take_path, default_rig):
    take = read_livelinkface(llf_take_path)
    assert take.rows_read == 4030
    assert len(take.times) == 4030
    assert abs(take.rate_hz - 30.0) < 0.5 and take.timecode_rate == 60.0
    assert take.weights.shape == (4030, 52)
    assert take.weights.min() >= 0.0 and take.weights.max() <= 1.0
    assert (np.diff(take.times) > 0).all()
    jaw = take.weights[:, ARKIT_NAMES.index("jawOpen")]
    assert jaw.max() > 0.3  # a range-of-motion take opens the jaw
    anim = livelinkface_animation(take, start_s=10.0, end_s=12.0)
    x = KinematicTrajectory(default_rig, anim).positions(anim.frame_times)
    assert x.shape == (len(anim.frame_times), default_rig.num_vertices, 3) and np.isfinite(x).all()


def test_columns_found_by_name(tmp_path):
    p = write_csv(tmp_path / "take.csv", shuffle=True)
    take = read_livelinkface(p)
    assert take.weights.shape == (30, 52) and np.allclose(take.weights, 0.5)
    assert abs(take.rate_hz - 30.0) < 1e-6
    np.testing.assert_allclose(take.head[:, 0], 0.1)


@pytest.mark.parametrize(
    "header, match",
    [
        ("Time,Count,EyeBlinkLeft", "header: expected 'Timecode,BlendShapeCount"),
        (HEADER.replace("JawOpen,", ""), r"lacks blend-shape column\(s\) \['jawOpen'\]"),
        (HEADER.replace("JawOpen", "JawOpenWide"), "header column 'JawOpenWide' is not an ARKit blend shape"),
    ],
)
def test_broken_header(tmp_path, header, match):
    p = write_csv(tmp_path / "bad.csv", header=header)
    with pytest.raises(KDInputError, match=match):
        read_livelinkface(p)


def test_broken_values(tmp_path):
    p = write_csv(tmp_path / "bad.csv", value="abc")
    with pytest.raises(KDInputError, match=r"bad.csv: column 'eyeBlinkLeft': expected numbers"):
        read_livelinkface(p)
    p = write_csv(tmp_path / "nan.csv", value="nan")
    with pytest.raises(KDInputError, match="NaN or inf"):
        read_livelinkface(p)


def test_broken_timecode(tmp_path):
    p = write_csv(tmp_path / "tc.csv")
    p.write_text(p.read_text().replace("10:00:00:02.000", "10:00:02.000"))
    with pytest.raises(KDInputError, match=r"row 3 field 'Timecode': expected HH:MM:SS:FF.fff"):
        read_livelinkface(p)


def test_missing_file(tmp_path):
    with pytest.raises(KDInputError, match="file not found"):
        read_livelinkface(tmp_path / "none.csv")
