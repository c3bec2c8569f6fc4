"""ARKit blend-shape names and the aliases used by other tools.

``eyeBlinkLeft`` (ARKit), ``EyeBlinkLeft`` (Live Link Face CSV), ``eyeBlink_L`` (many DCC rigs) and
``eye_blink_left`` all name the same shape; :func:`canonical_name` maps each to the ARKit spelling.
"""

from __future__ import annotations

import re

from ..errors import KDInputError

__all__ = ["ARKIT_NAMES", "canonical_name", "alias_key", "match_names"]

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
