"""The `kdfaces demo` command end to end: summary.json keys and a filmstrip that shows a face."""

import json

import pytest

from kdfaces.cli import main


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--out", str(out)]) == 0
    return out, json.loads((out / "summary.json").read_text())


def test_demo_summary(demo_run):
    out, s = demo_run
    assert s["rig"]["name"] == "makehuman_head" and s["rig"]["shapes"] == 52 and 4000 < s["rig"]["vertices"] < 5000
    assert s["fps"] == 25 and s["frames"] == 151 and abs(s["duration_s"] - 6.0) < 1e-9
    assert s["outputs"] and all((out / p).exists() for p in s["outputs"])


def test_demo_filmstrip_shows_a_face(demo_run):
    import matplotlib.image as mpimg

    out, s = demo_run
    png = next(p for p in s["outputs"] if p.startswith("filmstrip"))
    img = mpimg.imread(out / png)[..., :3]
    skin = (img[..., 0] > img[..., 2] + 0.1) & (img[..., 0] > 0.4)  # warm skin-coloured pixels
    assert 0.05 < skin.mean() < 0.6


def test_bad_rig_path_is_one_clear_error(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--rig", str(tmp_path / "missing.npz")]) == 2
    err = capsys.readouterr().err
    assert "missing.npz: file not found" in err and "Traceback" not in err
