"""Production-like test avatars and takes built from the committed full-body MakeHuman rig.

``meshes/makehuman_body.npz`` (``scripts/build_makehuman_body.py``) is the whole MakeHuman body with the 52 ARKit
face units and the neck/head skin, in metres. The functions here turn it into what a studio would hand over, in
memory or into a folder the caller gives (nothing is written anywhere else):

- :func:`studio_avatar`: the same rig with its shapes renamed to a studio convention (``AK_25_JawOpen`` or
  ``Jaw_Open`` / ``Mouth_Smile_L``) and ``source_unit_m`` saying what unit its file is written in (centimetres by
  default). Rigs are metres inside; the unit is what a writer puts in the file.
- :func:`write_avatar_fbx` (Blender, centimetres) and :func:`write_avatar_gltf` (glTF is metres, so a rig's
  ``source_unit_m`` does not reach it; the centimetre variant goes to FBX only).
- :func:`cut_out_face`: the same face cut out on its own — the vertices skinned to the neck/head chain (eyes,
  teeth, tongue, lashes included), as ``scripts/build_makehuman_head.py`` cuts the default head — the baseline a
  full-body avatar's secondary motion is compared with.
- :func:`write_livelink_take`: a synthetic Live Link Face CSV of any length (smooth channel curves, blinks, speech-like
  jaw motion, head turns), in the format :func:`kdfaces.io.read_livelinkface` reads.

Import it from a test (``from avatar_fixtures import ...``; pytest puts ``tests/`` on the path) or from a benchmark
after adding ``tests/`` to ``sys.path``; it imports nothing from conftest.
"""

from __future__ import annotations

import dataclasses
import functools
import re
from pathlib import Path

import numpy as np

from kdfaces.errors import KDInputError
from kdfaces.rig import ARKIT_NAMES, BlendshapeRig, subset_rig

ROOT = Path(__file__).resolve().parents[1]
BODY_PATH = ROOT / "meshes" / "makehuman_body.npz"

#: The studio numbering of ``AK_nn_Name``: ARKit names in alphabetical order (AK_01_BrowDownLeft, AK_25_JawOpen,
#: AK_52_TongueOut).
AK_ORDER: tuple[str, ...] = tuple(sorted(ARKIT_NAMES))

#: Live Link Face's blend-shape columns, in the order the app writes them (ARKit's enum order, which lists jawRight
#: before jawLeft and mouthRight before mouthLeft), then the head and eye angles [rad].
LIVELINK_SHAPES: tuple[str, ...] = tuple(
    n[0].upper() + n[1:] for n in (
        "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft",
        "eyeWideLeft", "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
        "eyeSquintRight", "eyeWideRight", "jawForward", "jawRight", "jawLeft", "jawOpen", "mouthClose", "mouthFunnel",
        "mouthPucker", "mouthRight", "mouthLeft", "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft",
        "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft", "mouthStretchRight",
        "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthPressLeft", "mouthPressRight",
        "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft", "mouthUpperUpRight", "browDownLeft",
        "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight", "cheekPuff", "cheekSquintLeft",
        "cheekSquintRight", "noseSneerLeft", "noseSneerRight", "tongueOut"))
LIVELINK_ANGLES: tuple[str, ...] = ("HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
                                    "RightEyeYaw", "RightEyePitch", "RightEyeRoll")
#: Timecode rates Live Link Face writes (frames per second of the ``FF`` field).
TIMECODE_RATES = (24, 25, 30, 48, 50, 60, 120)


@functools.lru_cache(maxsize=1)
def load_body() -> BlendshapeRig:
    """The committed full-body avatar (metres, ARKit names, neck/head skeleton); rigs are immutable, so one copy is
    shared."""
    from kdfaces.io.rigfiles import load_npz

    return load_npz(BODY_PATH)


def body_source_indices() -> np.ndarray:
    """(N,) int64: each body vertex's index in MakeHuman's ``base.obj`` (the default head stores the same map)."""
    with np.load(BODY_PATH) as d:
        return d["source_vertex_index"].astype(np.int64)


# ----------------------------------------------------------------------------------------------------------------
# studio names


def _words(arkit: str) -> list[str]:
    """``mouthSmileLeft`` → ``['Mouth', 'Smile', 'Left']``."""
    return [w[0].upper() + w[1:] for w in re.findall(r"[A-Z]?[a-z]+", arkit)]


def ak_name(arkit: str) -> str:
    """The ``AK_nn_Name`` spelling of an ARKit name: ``jawOpen`` → ``AK_25_JawOpen`` (numbered in :data:`AK_ORDER`)."""
    return f"AK_{AK_ORDER.index(arkit) + 1:02d}_{''.join(_words(arkit))}"


def sided_name(arkit: str) -> str:
    """The ``Capitalised_Words_L`` spelling of an ARKit name: ``mouthSmileLeft`` → ``Mouth_Smile_L``, ``jawOpen`` →
    ``Jaw_Open``, ``mouthLeft`` → ``Mouth_L``."""
    side = {"Left": "L", "Right": "R"}
    return "_".join(side.get(w, w) for w in _words(arkit))


#: Studio naming conventions: convention → (ARKit name → the studio's name).
CONVENTIONS = {"ak": ak_name, "sided": sided_name}


def rename_shapes(rig: BlendshapeRig, rename, *, name: str | None = None) -> BlendshapeRig:
    """``rig`` with each shape called ``rename(old name)`` (ARKit names in, the studio's out); everything else
    kept."""
    return dataclasses.replace(rig, shape_names=tuple(rename(s) for s in rig.shape_names),
                               name=rig.name if name is None else name)


def studio_avatar(rig: BlendshapeRig | None = None, *, convention: str = "ak", unit_m: float = 0.01) -> BlendshapeRig:
    """A studio's copy of ``rig`` (default: the body, :func:`load_body`): shapes renamed by ``convention`` (a key of
    :data:`CONVENTIONS`), ``source_unit_m = unit_m`` [m per file unit; 0.01: its file is in centimetres]. The
    geometry stays in metres; the writers put the unit in the file."""
    rig = load_body() if rig is None else rig
    if convention not in CONVENTIONS:
        raise KDInputError(f"convention: expected one of {sorted(CONVENTIONS)}, got {convention!r}")
    if not (np.isfinite(unit_m) and unit_m > 0):
        raise KDInputError(f"unit_m: expected a positive number of metres per file unit, got {unit_m!r}")
    out = rename_shapes(rig, CONVENTIONS[convention], name=f"studio_{convention}_{rig.name}")
    return dataclasses.replace(out, source_unit_m=float(unit_m))


# ----------------------------------------------------------------------------------------------------------------
# the face on its own


def face_vertices(rig: BlendshapeRig) -> np.ndarray:
    """Sorted indices (M,) of the cut-out face: the corners of the polygons whose every corner is skinned to the
    neck/head chain (skin weight sum > 0), which takes in the eyes, teeth, tongue and lashes (skinned rigidly) —
    how ``scripts/build_makehuman_head.py`` cuts the default head from the body."""
    if rig.skeleton is None:
        raise KDInputError(f"rig {rig.name!r}: no skeleton, so no head chain to cut the face out by")
    skinned = rig.skeleton.weights.sum(axis=1) > 0.0
    counts, corners = rig.polygon_counts, rig.polygon_corners
    ok = np.ones(len(counts), dtype=bool)
    np.logical_and.at(ok, np.repeat(np.arange(len(counts)), counts), skinned[corners])
    return np.unique(corners[np.repeat(ok, counts)])


def cut_out_face(rig: BlendshapeRig | None = None) -> BlendshapeRig:
    """The face of ``rig`` (default: the body) cut out on its own (:func:`face_vertices`), same shapes, names, joints
    and ``source_unit_m``: the baseline "same face cut out on its own" of a full-body avatar."""
    rig = load_body() if rig is None else rig
    return subset_rig(rig, face_vertices(rig), name=f"{rig.name}_face")


# ----------------------------------------------------------------------------------------------------------------
# files


def write_avatar_gltf(rig: BlendshapeRig, path) -> Path:
    """Write ``rig`` as glTF (``.gltf``/``.glb``) via :func:`kdfaces.io.save_gltf`: metres whatever
    ``rig.source_unit_m`` says (glTF has no unit), shape names in ``extras.targetNames``; the skeleton is not
    written."""
    from kdfaces.io.gltf import save_gltf

    return save_gltf(rig, path)


def write_avatar_fbx(rig: BlendshapeRig, path, *, unit_scale_m: float | None = None) -> Path:
    """Write ``rig`` as FBX with Blender (``tests/fbx_fixtures.py``), in units of ``unit_scale_m`` metres (default
    the rig's ``source_unit_m``: 0.01 for :func:`studio_avatar`, a centimetre file)."""
    from fbx_fixtures import write_fbx_with_blender

    unit = rig.source_unit_m if unit_scale_m is None else float(unit_scale_m)
    return Path(write_fbx_with_blender(rig, path, unit_scale_m=unit) or path)


# ----------------------------------------------------------------------------------------------------------------
# a Live Link Face take


def _smooth(rng: np.random.Generator, n: int, fps: float, corr_s: float) -> np.ndarray:
    """Unit-variance Gaussian-smoothed noise (n,): correlated over about ``corr_s`` seconds."""
    from scipy.ndimage import gaussian_filter1d

    z = gaussian_filter1d(rng.standard_normal(n + 1), sigma=max(corr_s * fps, 0.5), mode="wrap")[:n]
    return (z - z.mean()) / (z.std() or 1.0)


def _events(rng: np.random.Generator, t: np.ndarray, gap_s: tuple[float, float], width_s: tuple[float, float],
            height: tuple[float, float]) -> np.ndarray:
    """Raised-cosine bumps (T,) at random times: gaps, widths [s] and heights drawn uniformly from the ranges."""
    out = np.zeros_like(t)
    at = t[0] + rng.uniform(*gap_s) * 0.5
    while at < t[-1]:
        w, h = rng.uniform(*width_s), rng.uniform(*height)
        u = (t - at) / w
        inside = np.abs(u) < 0.5
        out[inside] = np.maximum(out[inside], h * 0.5 * (1.0 + np.cos(2.0 * np.pi * u[inside])))
        at += w + rng.uniform(*gap_s)
    return out


def livelink_channels(duration_s: float, fps: int = 30, seed: int = 0) -> tuple[np.ndarray, dict, np.ndarray]:
    """Sample times (T,) [s], ARKit name → weights (T,) in [0, 1], and the angles (T, 9) [rad] in
    :data:`LIVELINK_ANGLES` order, of a plausible take: slow expression drift (smoothed noise), left/right pairs that
    mostly agree, blinks every 2–6 s, speech-like jaw motion (syllables at 3–5 Hz in phrases) with a few wide opens,
    smiles that come and go, gaze that the ``eyeLook*`` channels follow, and head yaw/pitch/roll of a few tenths of a
    radian (sums of sines and drift). T = round(duration_s·fps) + 1; the same arguments give the same numbers."""
    n = int(round(duration_s * fps)) + 1
    t = np.arange(n) / fps
    rng = np.random.default_rng(seed)

    def pos(z):  # the positive part: ARKit coefficients rest at 0 much of the time
        return np.maximum(z, 0.0)

    w: dict[str, np.ndarray] = {}
    # speech: phrases of 1.5-4 s with syllables at 3-5 Hz; jaw, lips and mouth shapes follow the syllables
    phrase = np.clip(_events(rng, t, (0.6, 2.5), (1.5, 4.0), (0.7, 1.0)) * 1.6, 0.0, 1.0)
    syllable_hz = 4.0 + 0.8 * _smooth(rng, n, fps, 2.0)
    syllables = 0.5 * (1.0 - np.cos(2.0 * np.pi * np.cumsum(syllable_hz) / fps))
    speech = phrase * syllables
    w["jawOpen"] = 0.45 * speech + 0.05 * pos(_smooth(rng, n, fps, 0.5)) + _events(rng, t, (8.0, 20.0), (0.6, 1.2),
                                                                                   (0.5, 0.8))
    w["mouthClose"] = 0.15 * phrase * (1.0 - syllables)
    for k in ("mouthFunnel", "mouthPucker", "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper"):
        w[k] = 0.25 * speech * pos(_smooth(rng, n, fps, 0.4) + 0.3)
    smile = 0.55 * pos(_smooth(rng, n, fps, 2.5) - 0.2)
    frown = 0.3 * pos(_smooth(rng, n, fps, 2.0) - 0.8)
    brow = 0.4 * pos(_smooth(rng, n, fps, 1.2) - 0.3)
    blink = _events(rng, t, (2.0, 6.0), (0.15, 0.3), (0.85, 1.0))
    gaze_yaw = 0.25 * np.tanh(_smooth(rng, n, fps, 0.8))  # [rad], + toward the face's left
    gaze_pitch = 0.12 * np.tanh(_smooth(rng, n, fps, 1.0))

    def own(amp, corr_s):  # a side's own share of a shape
        return amp * pos(_smooth(rng, n, fps, corr_s))

    for side, sgn in (("Left", 1.0), ("Right", -1.0)):
        w[f"mouthSmile{side}"] = smile + own(0.05, 0.6)
        w[f"cheekSquint{side}"] = 0.5 * smile + own(0.03, 0.6)
        w[f"mouthDimple{side}"] = 0.3 * smile + own(0.05, 0.5)
        w[f"mouthFrown{side}"] = frown + own(0.03, 0.5)
        w[f"mouthStretch{side}"] = 0.2 * speech * pos(_smooth(rng, n, fps, 0.5)) + own(0.03, 0.5)
        w[f"mouthPress{side}"] = 0.2 * phrase * (1.0 - syllables) + own(0.05, 0.5)
        w[f"mouthLowerDown{side}"] = 0.3 * speech + own(0.03, 0.4)
        w[f"mouthUpperUp{side}"] = 0.2 * speech + own(0.03, 0.4)
        w[f"browDown{side}"] = 0.3 * frown + own(0.05, 0.8)
        w[f"browOuterUp{side}"] = brow + own(0.05, 0.8)
        w[f"noseSneer{side}"] = 0.2 * frown + own(0.04, 0.7)
        w[f"eyeBlink{side}"] = 0.08 + blink + own(0.03, 0.3)
        w[f"eyeSquint{side}"] = 0.4 * smile + own(0.05, 0.6)
        w[f"eyeWide{side}"] = 0.6 * brow + own(0.03, 0.6)
        yaw = sgn * gaze_yaw  # toward the ear on the eye's own side is "out"
        w[f"eyeLookOut{side}"] = pos(yaw) / 0.4
        w[f"eyeLookIn{side}"] = pos(-yaw) / 0.4
        w[f"eyeLookUp{side}"] = pos(gaze_pitch) / 0.3
        w[f"eyeLookDown{side}"] = pos(-gaze_pitch) / 0.3
        w[f"mouth{side}"] = 0.15 * pos(sgn * _smooth(rng, n, fps, 1.0) - 0.5)
        w[f"jaw{side}"] = 0.1 * pos(sgn * _smooth(rng, n, fps, 1.0) - 0.5)
    w["browInnerUp"] = brow + 0.05 * pos(_smooth(rng, n, fps, 0.8))
    w["jawForward"] = 0.08 * pos(_smooth(rng, n, fps, 1.0))
    w["cheekPuff"] = _events(rng, t, (15.0, 40.0), (0.8, 1.5), (0.4, 0.7))
    w["tongueOut"] = _events(rng, t, (20.0, 50.0), (0.5, 1.0), (0.3, 0.6))
    w = {k: np.clip(v, 0.0, 1.0) for k, v in w.items()}
    assert sorted(w) == sorted(ARKIT_NAMES)

    def sines(amp, periods_s):
        phases = rng.uniform(0.0, 2.0 * np.pi, len(periods_s))
        shares = rng.uniform(0.5, 1.0, len(periods_s))
        s = sum(a * np.sin(2.0 * np.pi * t / p + ph) for a, p, ph in zip(shares, periods_s, phases))
        return amp * s / shares.sum()

    head_yaw = sines(0.3, (11.0, 5.3, 2.7)) + 0.06 * _smooth(rng, n, fps, 0.4)
    head_pitch = sines(0.15, (7.1, 3.4, 1.9)) + 0.04 * _smooth(rng, n, fps, 0.4)
    head_roll = sines(0.08, (9.3, 4.1)) + 0.02 * _smooth(rng, n, fps, 0.5)
    angles = np.stack([head_yaw, head_pitch, head_roll, gaze_yaw, gaze_pitch, np.zeros(n), gaze_yaw, gaze_pitch,
                       np.zeros(n)], axis=1)
    return t, w, angles


def write_livelink_take(path, duration_s: float, fps: int = 30, seed: int = 0) -> Path:
    """Write a synthetic Live Link Face take of ``duration_s`` seconds at ``fps`` samples per second (one of
    :data:`TIMECODE_RATES`) to the CSV ``path``: header ``Timecode,BlendShapeCount,<52 names>,HeadYaw,...``, one row
    per sample with the timecode ``HH:MM:SS:FF.fff`` (FF at ``fps``), ``BlendShapeCount`` 61, weights in [0, 1] and
    angles [rad] with 10 decimals, as the app writes them (:func:`livelink_channels` makes the curves). A take shorter
    than a second starts late in its second, so its frame numbers reach ``fps - 1`` and the reader infers the
    timecode rate. Returns the path."""
    if fps not in TIMECODE_RATES:
        raise KDInputError(f"fps: expected one of the timecode rates {list(TIMECODE_RATES)}, got {fps!r}")
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise KDInputError(f"duration_s: expected a positive number of seconds, got {duration_s!r}")
    t, w, angles = livelink_channels(duration_s, fps, seed)
    n = len(t)
    frame0 = (13 * 3600 + 13 * 60 + 4) * fps + max(0, fps - n)  # from 13:13:04, late in that second if short
    frames = frame0 + np.arange(n)
    ff, secs = frames % fps, frames // fps
    codes = [f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}:{f:02d}.250" for s, f in zip(secs, ff)]
    values = np.column_stack([w[s[0].lower() + s[1:]] for s in LIVELINK_SHAPES] + [angles])
    header = ",".join(("Timecode", "BlendShapeCount", *LIVELINK_SHAPES, *LIVELINK_ANGLES))
    count = len(LIVELINK_SHAPES) + len(LIVELINK_ANGLES)
    lines = [header] + [f"{c},{count}," + ",".join(f"{v:.10f}" for v in row) for c, row in zip(codes, values)]
    p = Path(path)
    p.write_text("\n".join(lines) + "\n")
    return p
