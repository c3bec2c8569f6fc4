"""ARKit blend-shape names and the aliases used by other tools.

``eyeBlinkLeft`` (ARKit), ``EyeBlinkLeft`` (Live Link Face CSV), ``eyeBlink_L`` (many DCC rigs) and
``eye_blink_left`` all name the same shape; :func:`canonical_name` maps each to the ARKit spelling.
"""

from __future__ import annotations

import re

from ..errors import KDInputError

__all__ = ["ARKIT_NAMES", "canonical_name", "alias_key", "match_names", "resolve_channels", "ChannelResolution"]

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


def alias_key(name: str) -> str:
    """Case- and separator-insensitive key with ``_L``/``_R``/``.L`` suffixes spelled out as left/right."""
    s = name.strip()
    s = re.sub(r"[_.\-\s]([LR])$", lambda m: "left" if m.group(1) == "L" else "right", s)
    s = re.sub(r"[_.\-\s]([lr])$", lambda m: "left" if m.group(1) == "l" else "right", s)
    return re.sub(r"[^0-9a-z]", "", s.lower())


_KEY_TO_ARKIT = {alias_key(n): n for n in ARKIT_NAMES}


def canonical_name(name: str) -> str:
    """ARKit spelling of ``name`` if it is an alias of an ARKit shape, else ``name`` unchanged."""
    return _KEY_TO_ARKIT.get(alias_key(name), name)


def match_names(requested, available, *, where: str) -> list[int]:
    """Indices into ``available`` for each name in ``requested`` (alias-aware, case-insensitive).

    Raises :class:`KDInputError` naming ``where`` and the closest available names for an unknown name.
    """
    table = {alias_key(canonical_name(a)): i for i, a in enumerate(available)}
    out = []
    for r in requested:
        key = alias_key(canonical_name(str(r)))
        if key not in table:
            import difflib

            close = difflib.get_close_matches(str(r), list(available), n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise KDInputError(f"{where}: unknown shape name {r!r}; expected one of the rig's {len(available)} "
                               f"shapes (ARKit names or aliases){hint}")
        out.append(table[key])
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


_SIDES = (("left", "right"),)


def resolve_channels(channels, shape_names, *, channel_map: dict | None = None, where: str = "channels"
                     ) -> ChannelResolution:
    """Which rig shapes each animation channel drives.

    In order: an explicit ``channel_map`` entry (channel → a shape name, a list of shape names, or ``""``/None to
    drop the channel); the shape of the same name (ARKit aliases and case are ignored); the side-split pair of that
    name (``X_L``/``X_R``, ``XLeft``/``XRight``, any alias spelling) — the channel drives both sides; else the
    channel is skipped. Names in ``channel_map`` that are not shapes raise :class:`KDInputError` naming ``where``.
    """
    import numpy as np

    table = {alias_key(canonical_name(a)): i for i, a in enumerate(shape_names)}
    cmap = {alias_key(canonical_name(str(k))): v for k, v in (channel_map or {}).items()}
    pairs, skipped, how = [], [], {}
    for c, name in enumerate(channels):
        key = alias_key(canonical_name(str(name)))
        if key in cmap:
            target = cmap[key]
            if target in (None, "", False) or (isinstance(target, list | tuple) and not target):
                how[name] = "dropped"
                continue
            targets = [target] if isinstance(target, str) else list(target)
            for s in match_names(targets, shape_names, where=f"{where}.map.{name}"):
                pairs.append((c, s))
            how[name] = "map"
        elif key in table:
            pairs.append((c, table[key]))
            how[name] = "name"
        elif all(key + side in table for side in _SIDES[0]):
            pairs += [(c, table[key + side]) for side in _SIDES[0]]
            how[name] = "sides"
        else:
            skipped.append(str(name))
            how[name] = "skipped"
    unknown = set(cmap) - {alias_key(canonical_name(str(n))) for n in channels}
    if unknown:
        raise KDInputError(f"{where}.map: channel(s) {sorted(unknown)} are not in the animation")
    return ChannelResolution((np.asarray(pairs, dtype=np.int64).reshape(-1, 2), skipped, how))
