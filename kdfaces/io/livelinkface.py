"""Live Link Face (Epic Games' ARKit capture app) CSV import.

Header: ``Timecode,BlendShapeCount,<52 PascalCase ARKit names>,HeadYaw,HeadPitch,HeadRoll,<6 eye angles>``.
Columns are found by name (the CSV order is not ARKit's enum order). The timecode is ``HH:MM:SS:FF.fff`` with FF
counted at the timecode rate (inferred: the smallest standard rate above the largest FF seen); the sample rate
is inferred from the timecode steps. Blend-shape coefficients are ARKit's [0, 1] values; capture noise slightly
outside that range is clamped. Head angles are radians and become a yaw/pitch/roll drive of the neck chain.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import KDInputError
from ..motion.curves import KeyframeCurve
from ..motion.joints import JointDrive, SkeletonAnimation
from ..motion.trajectory import FaceAnimation, ShapeTrack
from ..rig.names import ARKIT_NAMES, canonical_name

__all__ = ["LiveLinkTake", "read_livelinkface", "livelinkface_animation"]

_TIMECODE_RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 120.0)
_HEAD = ("HeadYaw", "HeadPitch", "HeadRoll")


@dataclass(frozen=True)
class LiveLinkTake:
    """A parsed take. ``times`` [s] from the first sample, shape (T,); ``weights`` (T, 52) in ARKit order
    (:data:`~kdfaces.rig.names.ARKIT_NAMES`); ``head`` (T, 3) yaw/pitch/roll [rad] or None; ``rate_hz`` inferred;
    ``rows_read`` data rows in the file (rows repeating an earlier timecode are dropped from T)."""

    path: Path
    times: np.ndarray
    weights: np.ndarray
    head: np.ndarray | None
    rate_hz: float
    timecode_rate: float
    rows_read: int
    names: tuple[str, ...] = ARKIT_NAMES


def _parse_timecodes(codes: list[str], path: Path) -> np.ndarray:
    parts = []
    for row, code in enumerate(codes, start=2):
        fields = code.split(":")
        try:
            if len(fields) != 4:
                raise ValueError
            parts.append([float(f) for f in fields])
        except ValueError:
            raise KDInputError(f"{path}: row {row} field 'Timecode': expected HH:MM:SS:FF.fff, got {code!r}") from None
    a = np.asarray(parts)
    max_frame = a[:, 3].max()
    rate = next((r for r in _TIMECODE_RATES if max_frame < r), None)
    if rate is None:
        raise KDInputError(f"{path}: field 'Timecode': frame number {max_frame} exceeds every known timecode rate")
    return a[:, 0] * 3600 + a[:, 1] * 60 + a[:, 2] + a[:, 3] / rate, rate


def read_livelinkface(path) -> LiveLinkTake:
    """Parse a Live Link Face CSV. Raises :class:`KDInputError` naming the file and field on bad input."""
    p = Path(path)
    if not p.exists():
        raise KDInputError(f"{p}: file not found")
    with open(p, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        rows = [r for r in reader if r]
    if not header or header[0].strip() != "Timecode" or len(header) < 3 or header[1].strip() != "BlendShapeCount":
        raise KDInputError(f"{p}: header: expected 'Timecode,BlendShapeCount,<blend shape names>...', got "
                           f"{','.join((header or [])[:3])!r}")
    header = [h.strip() for h in header]
    col = {}
    for i, h in enumerate(header[2:], start=2):
        name = canonical_name(h)
        if name in ARKIT_NAMES:
            col[name] = i
        elif h not in _HEAD and "Eye" not in h:
            raise KDInputError(f"{p}: header column {h!r} is not an ARKit blend shape or a head/eye angle")
    missing = [n for n in ARKIT_NAMES if n not in col]
    if missing:
        raise KDInputError(f"{p}: header lacks blend-shape column(s) {missing[:5]}{'...' if len(missing) > 5 else ''}")
    if not rows:
        raise KDInputError(f"{p}: no data rows")
    width = len(header)
    for r, row in enumerate(rows, start=2):
        if len(row) != width:
            raise KDInputError(f"{p}: row {r} has {len(row)} fields, header has {width}")
    times, tc_rate = _parse_timecodes([row[0] for row in rows], p)

    def column(i, name):
        try:
            v = np.array([float(row[i]) for row in rows])
        except ValueError:
            raise KDInputError(f"{p}: column {name!r}: expected numbers") from None
        if not np.isfinite(v).all():
            raise KDInputError(f"{p}: column {name!r}: NaN or inf at row {int(np.argmin(np.isfinite(v))) + 2}")
        return v

    weights = np.stack([column(col[n], n) for n in ARKIT_NAMES], axis=1)
    bad = np.abs(weights - 0.5) > 1.5  # weights live in [0, 1]; capture noise goes a little beyond, never this far
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise KDInputError(f"{p}: column {ARKIT_NAMES[c]!r}, row {r + 2}: weight {weights[r, c]:.6g}; expected a "
                           "blend-shape weight in [0, 1]")
    head = None
    if all(h in header for h in _HEAD):
        head = np.stack([column(header.index(h), h) for h in _HEAD], axis=1)
        if (np.abs(head) > np.pi + 1e-6).any():
            r, c = np.argwhere(np.abs(head) > np.pi + 1e-6)[0]
            raise KDInputError(f"{p}: column {_HEAD[c]!r}, row {r + 2}: {head[r, c]:.6g}; expected an angle in "
                               "radians within ±π")
    # duplicated timecodes (the app repeats the first sample) keep the last row; order by time
    order = np.argsort(times, kind="stable")
    times, weights = times[order], weights[order]
    keep = np.append(np.diff(times) > 0, True)
    times, weights = times[keep], weights[keep]
    if head is not None:
        head = head[order][keep]
    if len(times) < 2:
        raise KDInputError(f"{p}: need at least two distinct timecodes")
    rate = float(1.0 / np.median(np.diff(times)))
    if abs(rate - round(rate)) < 1e-3 * rate:  # timecodes are rounded to the ms: snap to the nominal rate
        rate = float(round(rate))
    return LiveLinkTake(path=p, times=times - times[0], weights=np.clip(weights, 0.0, 1.0), head=head,
                        rate_hz=rate, timecode_rate=tc_rate, rows_read=len(rows))


def livelinkface_animation(take_or_path, *, fps: float | None = None, interpolation: str = "catmull-rom",
                           start: float = 0.0, end: float | None = None) -> FaceAnimation:
    """A :class:`FaceAnimation` from a take: one 52-channel weight track, and a head drive if angles are non-zero.

    ``start``/``end`` [s] crop the take (relative to its first sample); ``fps`` defaults to the capture rate, so
    the default simulation step puts every captured frame on the step grid. Channels a rig lacks are skipped with
    a warning (``strict_channels=False``; see :class:`~kdfaces.motion.KinematicTrajectory`).
    """
    take = take_or_path if isinstance(take_or_path, LiveLinkTake) else read_livelinkface(take_or_path)
    t = take.times
    end = float(t[-1]) if end is None else float(end)
    if not (0.0 <= start < end <= t[-1] + 1e-9):
        raise KDInputError(f"{take.path}: crop [{start}, {end}] s outside the take's [0, {t[-1]:.3f}] s")
    sel = (t >= start - 1.0 / take.rate_hz) & (t <= end + 1.0 / take.rate_hz)
    track = ShapeTrack(take.names, KeyframeCurve.create(t[sel], take.weights[sel], interpolation=interpolation,
                                                        where=f"{take.path} weights"))
    drives = ()
    if take.head is not None and np.abs(take.head).max() > 0:
        drives = (JointDrive(KeyframeCurve.create(t[sel], take.head[sel], interpolation=interpolation,
                                                  where=f"{take.path} head angles")),)
    return FaceAnimation(tracks=(track,), skeleton=SkeletonAnimation(drives), start=start, end=end,
                         fps=fps or take.rate_hz, name=Path(take.path).stem, strict_channels=False)

