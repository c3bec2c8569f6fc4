"""Live Link Face (Epic Games' ARKit capture app) CSV import.

Header: ``Timecode,BlendShapeCount,<52 PascalCase ARKit names>,HeadYaw,HeadPitch,HeadRoll,<6 eye angles>``.
Columns are found by name (the CSV order is not ARKit's enum order). The timecode is ``HH:MM:SS:FF.fff`` with FF
counted at the timecode rate (inferred: the smallest standard rate above the largest FF seen); the sample rate
is inferred from the timecode steps. Blend-shape coefficients are ARKit's [0, 1] values; capture noise slightly
outside that range is clamped. Head angles are radians and become a yaw/pitch/roll drive of the neck chain.

Timecodes are checked row by row, in file order (rows are never reordered):

- **Midnight.** A step back by about a day (``23:59:59:29`` → ``00:00:00:00``) whose unwrapped step is an
  ordinary one (positive, and no longer than the gap limit below) is a take recorded across midnight: 24 h are
  added to every later row. Only one wrap is possible (a take is shorter than a day).
- **Backwards.** Any other step back is an error naming the row (two takes in one file, or rows out of order).
- **Duplicates.** A row that repeats the previous row entirely (timecode and every value) carries nothing new and
  is dropped with a warning (``rows_read`` counts it). A repeated timecode with other values is an error naming the
  rows: the take was sampled faster than its timecodes say (e.g. 60 fps written with 30 fps codes), and dropping
  rows would lose half of it.
- **Gaps.** A step forward longer than :data:`MAX_GAP_S` and than :data:`MAX_GAP_STEPS` typical steps is an
  error (a second take appended, or a stalled capture); a few dropped frames are fine and are interpolated.
"""

from __future__ import annotations

import csv
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..deprecation import renamed_kwargs
from ..errors import KDInputError
from ..motion.curves import KeyframeCurve
from ..motion.joints import JointDrive, SkeletonAnimation
from ..motion.trajectory import FaceAnimation, ShapeTrack
from ..rig.names import ARKIT_NAMES, canonical_name

__all__ = ["LiveLinkTake", "read_livelinkface", "livelinkface_animation", "check_stretch", "MAX_GAP_S",
           "MAX_GAP_STEPS", "DAY_S"]

_TIMECODE_RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 120.0)
#: A step forward in the timecodes longer than this [s] and than :data:`MAX_GAP_STEPS` typical steps is an error.
MAX_GAP_S = 1.0
MAX_GAP_STEPS = 10
#: Seconds in a day: what a timecode wrap at midnight takes away.
DAY_S = 86400.0
_HEAD = ("HeadYaw", "HeadPitch", "HeadRoll")


@dataclass(frozen=True)
class LiveLinkTake:
    """A parsed take. ``times`` [s] from the first sample, shape (T,); ``weights`` (T, 52) in ARKit order
    (:data:`~kdfaces.rig.names.ARKIT_NAMES`); ``head`` (T, 3) yaw/pitch/roll [rad] or None; ``rate_hz`` inferred;
    ``rows_read`` data rows in the file (a row repeating the previous one entirely is dropped from T; see the
    module docstring for how timecodes are checked); ``midnight_row``: the first row after a wrap at midnight
    (None without one)."""

    path: Path
    times: np.ndarray
    weights: np.ndarray
    head: np.ndarray | None
    rate_hz: float
    timecode_rate: float
    rows_read: int
    names: tuple[str, ...] = ARKIT_NAMES
    midnight_row: int | None = None


def _parse_timecodes(codes: list[str], path: Path) -> np.ndarray:
    parts = []
    for row, code in enumerate(codes, start=2):
        fields = code.split(":")
        try:
            if len(fields) != 4:
                raise ValueError
            hh, mm, ss, ff = (float(f) for f in fields)
            if not (0 <= hh < 24 and 0 <= mm < 60 and 0 <= ss < 60 and 0 <= ff < 1000):
                raise ValueError
            parts.append((hh, mm, ss, ff))
        except ValueError:
            raise KDInputError(f"{path}: row {row} field 'Timecode': expected HH:MM:SS:FF.fff (hours < 24, minutes "
                               f"and seconds < 60), got {code!r}") from None
    a = np.asarray(parts)
    max_frame = a[:, 3].max()
    rate = next((r for r in _TIMECODE_RATES if max_frame < r), None)
    if rate is None:
        raise KDInputError(f"{path}: field 'Timecode': frame number {max_frame} exceeds every known timecode rate")
    return a[:, 0] * 3600 + a[:, 1] * 60 + a[:, 2] + a[:, 3] / rate, rate


def _check_times(t: np.ndarray, rows: list[list[str]], path: Path) -> tuple[np.ndarray, np.ndarray, int | None]:
    """Timecode seconds ``t`` (T,) in file order → (times unwrapped at midnight, rows to keep (T,) bool, the first
    row after midnight or None); every other lie is a :class:`KDInputError` naming the row (see the module
    docstring). File rows are numbered from 2 (the header is row 1)."""
    def row(i):
        return int(i) + 2

    d = np.diff(t)
    same = d == 0
    exact = np.zeros(len(d), dtype=bool)  # rows that repeat the previous row entirely
    if same.any():
        idx = np.flatnonzero(same)
        exact[idx] = [rows[i][1:] == rows[i + 1][1:] for i in idx]
        clash = idx[~exact[idx]]
        if len(clash):
            i = clash[0]
            raise KDInputError(f"{path}: rows {row(i)} and {row(i + 1)} have the same timecode {rows[i][0]!r} with "
                               f"different values ({len(clash)} row(s) repeat the previous row's timecode); expected "
                               "one timecode per row: the take was likely sampled faster than its timecode rate (e.g. "
                               "60 fps written with 30 fps codes) - re-export it with subframe timecodes (.fff)")
    forward = d[d > 0]
    if not len(forward):
        return t, np.r_[True, ~exact], None
    step = float(np.median(forward))
    gap = max(MAX_GAP_S, MAX_GAP_STEPS * step)
    back = np.flatnonzero(d < 0)
    midnight = None
    wraps = back[(d[back] + DAY_S > 0) & (d[back] + DAY_S <= gap)]
    if len(wraps):
        midnight = int(wraps[0]) + 1
        t = t.copy()
        t[midnight:] += DAY_S
        d = np.diff(t)
        back = np.flatnonzero(d < 0)
    if len(back):
        i = back[0]
        raise KDInputError(f"{path}: row {row(i + 1)}: timecode {rows[i + 1][0]!r} is {-d[i]:.6g} s before row "
                           f"{row(i)}'s {rows[i][0]!r}; expected timecodes that increase row by row (two takes in one "
                           "file? keep one take per CSV)")
    jumps = np.flatnonzero(d > gap)
    if len(jumps):
        i = jumps[0]
        raise KDInputError(f"{path}: row {row(i + 1)}: timecode {rows[i + 1][0]!r} is {d[i]:.6g} s after row "
                           f"{row(i)}'s {rows[i][0]!r}; expected steps of about {step:.4g} s (at most {gap:.3g} s): a "
                           "second take appended, or a capture that stalled? keep one continuous take per CSV")
    return t, np.r_[True, ~exact], midnight


def read_livelinkface(path) -> LiveLinkTake:
    """Parse a Live Link Face CSV. Raises :class:`KDInputError` naming the file, the row and the field on bad input,
    including timecodes that lie (duplicates, steps backwards, gaps; a wrap at midnight is unwrapped — see the
    module docstring)."""
    p = Path(path)
    if not p.exists():
        raise KDInputError(f"{p}: file not found")
    if p.is_dir():
        raise KDInputError(f"{p}: is a folder; expected a Live Link Face CSV file")
    try:  # utf-8-sig: a CSV saved by a spreadsheet on Windows starts with a byte-order mark
        with open(p, newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            rows = [r for r in reader if r]
    except UnicodeDecodeError as e:
        raise KDInputError(f"{p}: not a UTF-8 text file (byte {e.start}); expected a Live Link Face CSV") from None
    except (csv.Error, OSError) as e:
        raise KDInputError(f"{p}: not a readable CSV ({e})") from None
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
    times, keep, midnight = _check_times(times, rows, p)
    if not keep.all():
        dropped = np.flatnonzero(~keep)
        warnings.warn(f"{p}: row(s) {', '.join(str(int(i) + 2) for i in dropped[:5])}"
                      f"{'...' if len(dropped) > 5 else ''} repeat the previous row exactly and are dropped",
                      stacklevel=2)
    times, weights = times[keep], weights[keep]
    if head is not None:
        head = head[keep]
    if len(times) < 2:
        raise KDInputError(f"{p}: need at least two distinct timecodes")
    rate = float(1.0 / np.median(np.diff(times)))
    if abs(rate - round(rate)) < 1e-3 * rate:  # timecodes are rounded to the ms: snap to the nominal rate
        rate = float(round(rate))
    return LiveLinkTake(path=p, times=times - times[0], weights=np.clip(weights, 0.0, 1.0), head=head,
                        rate_hz=rate, timecode_rate=tc_rate, rows_read=len(rows),
                        midnight_row=None if midnight is None else midnight + 2)


def check_stretch(take: LiveLinkTake, start: float, end: float, *, names=("start", "end")) -> None:
    """Raise :class:`KDInputError` unless ``0 ≤ start < end ≤`` the take's length [s]; the message names the file
    and the field (``names``: how the caller calls start and end, e.g. ``animation.start_s``)."""
    length = float(take.times[-1])
    where = f"{take.path}: the take runs [0, {length:.6g}] s (times from its first sample)"
    if not (np.isfinite(start) and 0.0 <= start < length):
        raise KDInputError(f"{names[0]}: {start:g} s is outside the take; {where}")
    if not (np.isfinite(end) and end <= length + 1e-9):
        raise KDInputError(f"{names[1]}: {end:g} s is outside the take; {where}")
    if not end > start:
        raise KDInputError(f"{names[1]}: {end:g} s is not after {names[0]} ({start:g} s); {where}")


@renamed_kwargs(start="start_s", end="end_s")
def livelinkface_animation(take_or_path, *, fps: float | None = None, interpolation: str = "catmull-rom",
                           start_s: float = 0.0, end_s: float | None = None) -> FaceAnimation:
    """A :class:`FaceAnimation` from a take: one 52-channel weight track, and a head drive if angles are non-zero.

    ``start_s``/``end_s`` [s] crop the take (relative to its first sample; 0 ≤ start < end ≤ the take's length, else a
    :class:`KDInputError` naming the one that is outside); ``fps`` defaults to the capture rate, so the default
    simulation step puts every captured frame on the step grid. Channels a rig lacks are skipped with a warning
    (``strict_channels=False``; see :class:`~kdfaces.motion.KinematicTrajectory`).
    """
    take = take_or_path if isinstance(take_or_path, LiveLinkTake) else read_livelinkface(take_or_path)
    t = take.times
    end = float(t[-1]) if end_s is None else float(end_s)
    start = float(start_s)
    check_stretch(take, start, end, names=("start_s", "end_s"))
    sel = (t >= start - 1.0 / take.rate_hz) & (t <= end + 1.0 / take.rate_hz)
    track = ShapeTrack(take.names, KeyframeCurve.create(t[sel], take.weights[sel], interpolation=interpolation,
                                                        where=f"{take.path} weights"))
    drives = ()
    if take.head is not None and np.abs(take.head).max() > 0:
        drives = (JointDrive(KeyframeCurve.create(t[sel], take.head[sel], interpolation=interpolation,
                                                  where=f"{take.path} head angles")),)
    return FaceAnimation(tracks=(track,), skeleton=SkeletonAnimation(drives), start_s=start, end_s=end,
                         fps=fps or take.rate_hz, name=Path(take.path).stem, strict_channels=False)

