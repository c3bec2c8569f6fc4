"""ARKit blend-shape names, the spellings other tools use for them, and name lookups on a rig.

``eyeBlinkLeft`` (ARKit), ``EyeBlinkLeft`` (Live Link Face CSV), ``eyeBlink_L`` (many DCC rigs), ``eye_blink_left``,
``L_eyeBlink``, ``blendShape1.eyeBlink_L`` and ``AK_01_EyeBlinkLeft`` all name the same shape: :func:`alias_key`
reduces each to one key and :func:`canonical_name` maps the key to the ARKit spelling.

A rig keeps its own shape names (exports and pose constraints use them); every lookup — a name asked for, a capture
channel, a named group, the soft-tissue settle map — goes through :class:`ShapeTable`: a name that is exactly one of
the rig's shapes is that shape, otherwise the shapes whose key is the name's key are its candidates, and there must be
exactly one. Two shapes with one key (``AK_25_JawOpen`` and ``blendShape1.jawOpen``) do not stop a rig from loading;
asking for that name raises, naming both.
"""

from __future__ import annotations

import difflib
import functools
import re

from ..errors import KDInputError

__all__ = ["ARKIT_NAMES", "canonical_name", "alias_key", "match_names", "resolve_channels", "ChannelResolution",
           "ShapeTable", "shape_table", "find_shapes", "closest_shapes"]

ARKIT_NAMES: tuple[str, ...] = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft",
    "eyeWideLeft", "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight", "jawForward", "jawLeft", "jawRight", "jawOpen", "mouthClose", "mouthFunnel",
    "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft",
    "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthPressLeft", "mouthPressRight",
    "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft", "mouthUpperUpRight", "browDownLeft",
    "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight", "cheekPuff", "cheekSquintLeft",
    "cheekSquintRight", "noseSneerLeft", "noseSneerRight", "tongueOut",
)

_SIDE_WORDS = {"l": "left", "r": "right", "left": "left", "right": "right"}
# what a DCC puts in front of a shape's name: a deformer word (BS_, blendShape1_, Shapes_, morph_, target_) ...
_DEFORMER_PREFIX = re.compile(r"^(?:bs|blend_?shapes?\d*|shapes?|morphs?|targets?)[_\-\s]+", re.IGNORECASE)
# ... a numbered prefix (AK_25_, 25_) ...
_NUMBERED_PREFIX = re.compile(r"^(?:[A-Za-z]+_)?\d+_")
# ... and the side, as a prefix (L_mouthSmile, Left_mouthSmile) or a suffix (Mouth_Smile_L, eyeBlink.l, _Right)
_SIDE_PREFIX = re.compile(r"^(left|right|l|r)[_\-\s]+(?=\w)", re.IGNORECASE)
_SIDE_SUFFIX = re.compile(r"(?<=\w)[_\-\s]+(left|right|l|r)$", re.IGNORECASE)


def alias_key(name: str) -> str:
    """The lookup key of a shape or channel name: lower case without separators, with the deformer or namespace
    prefix (``blendShape1.``, ``Shapes.``, ``head:``, ``BS_``), a numbered prefix (``<letters>_<digits>_`` such as
    ``AK_25_``) and the side (``L_``/``R_``/``Left_``/``Right_`` in front, ``_L``/``_R``/``.l``/``_Left``/``Right``
    behind) normalised to a trailing ``left``/``right``. ``Mouth_Smile_L``, ``L_mouthSmile``, ``MouthSmileLeft``
    and ``blendShape1.AK_24_mouthSmile_L`` all have the key ``mouthsmileleft``."""
    s = str(name).strip()
    parts = [p for p in re.split(r"[.:|]", s) if p.strip()]
    if len(parts) > 1:  # dotted/namespaced: the last part is the name, unless it is only the side (eyeBlink.L)
        s = f"{parts[-2]}_{parts[-1]}" if parts[-1].strip().lower() in _SIDE_WORDS else parts[-1]
    for prefix in (_DEFORMER_PREFIX, _NUMBERED_PREFIX):
        rest = prefix.sub("", s, count=1)
        s = rest if rest else s
    side = ""
    m = _SIDE_SUFFIX.search(s) or _SIDE_PREFIX.match(s)
    if m:
        side = _SIDE_WORDS[m.group(1).lower()]
        s = s[:m.start()] if m.re is _SIDE_SUFFIX else s[m.end():]
    return re.sub(r"[^0-9a-z]", "", s.lower()) + side


_KEY_TO_ARKIT = {alias_key(n): n for n in ARKIT_NAMES}


def canonical_name(name: str) -> str:
    """ARKit spelling of ``name`` if it is a spelling of an ARKit shape (:func:`alias_key`), else ``name``."""
    return _KEY_TO_ARKIT.get(alias_key(name), name)


def closest_shapes(name: str, shape_names, n: int = 3, *, also=()) -> list[str]:
    """Up to ``n`` of ``shape_names`` that look closest to the names in ``also`` (a group's ARKit names), then to
    ``name``: compared by :func:`alias_key`, so ``AK_25_JawOpen`` is close to ``jawOpen``; after the close matches
    of ``also`` come the shapes whose key contains ``name``'s, then the close matches of ``name``."""
    names = [str(s) for s in shape_names]
    keys = {}
    for s in names:
        keys.setdefault(alias_key(s), s)
    out = []
    for a in also:
        out += [keys[k] for k in difflib.get_close_matches(alias_key(a), list(keys), n=n, cutoff=0.6)]
    key = alias_key(name)
    out += [s for s in names if key and key in alias_key(s)]
    out += [keys[k] for k in difflib.get_close_matches(key, list(keys), n=n, cutoff=0.5)]
    out += difflib.get_close_matches(str(name), names, n=n)
    return list(dict.fromkeys(out))[:n]


class ShapeTable:
    """Name lookups on a rig's shape names (K,): exact names first, then :func:`alias_key` keys, ambiguity checked.

    Build it with :func:`shape_table` (one per tuple of names, cached)."""

    def __init__(self, shape_names):
        self.names = tuple(str(s) for s in shape_names)
        self.exact = {s: i for i, s in enumerate(self.names)}
        self.by_key: dict[str, list[int]] = {}
        for i, s in enumerate(self.names):
            self.by_key.setdefault(alias_key(s), []).append(i)

    def candidates(self, name: str) -> list[int]:
        """Indices of the shapes ``name`` may mean: the shape of exactly that name, else every shape with its key."""
        name = str(name)
        if name in self.exact:
            return [self.exact[name]]
        return list(self.by_key.get(alias_key(name), ()))

    def _one(self, name: str, found: list[int], where: str) -> int | None:
        if len(found) > 1:
            shown = ", ".join(repr(self.names[i]) for i in found)
            raise KDInputError(f"{where}: {len(found)} shapes of the rig could be {canonical_name(name)!r} ({shown}); "
                               f"expected exactly one: name the shape exactly (e.g. [animation.map] "
                               f"{canonical_name(name)} = {self.names[found[0]]!r}) or rename the other")
        return found[0] if found else None

    def index(self, name: str, *, where: str = "shape names") -> int | None:
        """The index of the one shape ``name`` means, None if none does; several candidates raise
        :class:`KDInputError` naming ``where`` and each of them."""
        return self._one(name, self.candidates(name), where)

    def sides(self, name: str, *, where: str = "shape names") -> tuple[int, int] | None:
        """(left, right) indices of the side-split pair of ``name`` (``browInnerUp`` → ``browInnerUp_L`` and
        ``browInnerUp_R``), None unless both halves exist; several candidates for a half raise."""
        key = alias_key(name)
        halves = [self._one(f"{name}{side.capitalize()}", list(self.by_key.get(key + side, ())), where)
                  for side in ("left", "right")]
        return None if None in halves else (halves[0], halves[1])


@functools.lru_cache(maxsize=32)
def _cached_table(names: tuple) -> ShapeTable:
    return ShapeTable(names)


def shape_table(shape_names) -> ShapeTable:
    """The :class:`ShapeTable` of ``shape_names`` (kept for re-use per tuple of names)."""
    return _cached_table(tuple(str(s) for s in shape_names))


def match_names(requested, available, *, where: str) -> list[int]:
    """Indices into ``available`` for each name in ``requested``: the exact name, else the one shape with its
    :func:`alias_key` (ARKit aliases, case, separators, prefixes and sides ignored).

    Raises :class:`KDInputError` naming ``where`` and the closest available names for an unknown name, and naming
    every candidate for a name that several shapes could be.
    """
    table = shape_table(available)
    out = []
    for r in requested:
        i = table.index(str(r), where=where)
        if i is None:
            close = closest_shapes(str(r), table.names)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise KDInputError(f"{where}: unknown shape name {r!r}; expected one of the rig's {len(table.names)} "
                               f"shapes (ARKit names or aliases){hint}")
        out.append(i)
    return out


class ChannelResolution(tuple):
    """``(pairs, skipped, how)`` from :func:`resolve_channels`: ``pairs`` (M, 2) int of (channel, shape) indices
    (a channel may drive several shapes), ``skipped`` the channel names that drive nothing, ``how`` a dict channel
    name → "map" | "name" | "sides" | "dropped" | "skipped" saying how each was resolved."""

    @property
    def pairs(self):
        """(M, 2) int array of (channel index, shape index)."""
        return self[0]

    @property
    def skipped(self) -> list[str]:
        """Channel names that drive no shape."""
        return self[1]

    @property
    def how(self) -> dict:
        """Channel name → how it was resolved."""
        return self[2]


def _is_drop(target) -> bool:
    return target in (None, "", False) or (isinstance(target, list | tuple) and not target)


def resolve_channels(channels, shape_names, *, channel_map: dict | None = None, where: str = "channels"
                     ) -> ChannelResolution:
    """Which rig shapes each animation channel drives.

    In order: an explicit ``channel_map`` entry (channel → a shape name, a list of shape names, or ``""``/None to
    drop the channel); the one shape the channel's name means (:meth:`ShapeTable.index`: the exact name, else the
    shape with its :func:`alias_key` — ``jawOpen`` drives ``AK_25_JawOpen``); the side-split pair of that name
    (``X_L``/``X_R``, ``L_X``/``R_X``, ``XLeft``/``XRight``) — the channel drives both sides; else the channel is
    skipped. Names in ``channel_map`` that are not shapes, and channels several shapes could be, raise
    :class:`KDInputError` naming ``where``.
    """
    import numpy as np

    table = shape_table(shape_names)
    cmap = {alias_key(str(k)): v for k, v in (channel_map or {}).items()}
    pairs, skipped, how = [], [], {}
    for c, name in enumerate(channels):
        key = alias_key(str(name))
        if key in cmap:
            target = cmap[key]
            if _is_drop(target):
                how[name] = "dropped"
                continue
            targets = [target] if isinstance(target, str) else list(target)
            for s in match_names(targets, table.names, where=f"{where}.map.{name}"):
                pairs.append((c, s))
            how[name] = "map"
            continue
        i = table.index(str(name), where=f"{where}: channel {name}")
        sides = None if i is not None else table.sides(str(name), where=f"{where}: channel {name}")
        if i is not None:
            pairs.append((c, i))
            how[name] = "name"
        elif sides is not None:
            pairs += [(c, s) for s in sides]
            how[name] = "sides"
        else:
            skipped.append(str(name))
            how[name] = "skipped"
    unknown = set(cmap) - {alias_key(str(n)) for n in channels}
    if unknown:
        raise KDInputError(f"{where}.map: channel(s) {sorted(unknown)} are not in the animation")
    return ChannelResolution((np.asarray(pairs, dtype=np.int64).reshape(-1, 2), skipped, how))


def find_shapes(names, shape_names, *, channel_map: dict | None = None, where: str = "shapes") -> list[int]:
    """Sorted indices of the rig's shapes that ``names`` (ARKit names, e.g. a group's) stand for, as a capture
    channel of that name would drive them (:func:`resolve_channels`: ``channel_map`` entries, the name, the
    side-split pair); names the rig has no shape for are left out, and ``channel_map`` entries for other names are
    ignored (as are entries that drop a channel: the shape itself is still there). A name several shapes could be
    raises :class:`KDInputError` naming them."""
    keys = {alias_key(str(n)) for n in names}
    cmap = {k: v for k, v in (channel_map or {}).items() if alias_key(str(k)) in keys and not _is_drop(v)}
    res = resolve_channels(list(names), shape_names, channel_map=cmap, where=where)
    return sorted({int(s) for s in res.pairs[:, 1]})
