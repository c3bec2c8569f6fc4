"""An object's shot: the shot file (:mod:`kdfaces.shots.schema`) that says what the Blender scene says.

- :func:`animation_table` / :func:`shot_table` / :func:`write_shot_file`: a shot file for a rig, its animation, its
  ``[dynamics]`` and its constraint tables; the rig goes next to it as ``<stem>_rig.npz``. ``kdfaces run`` on that
  file rebuilds the same rig, the same x_K and the same constraints, so it computes the same trajectory.
- :func:`object_shot_table` / :func:`object_shot`: the shot of a Blender mesh object (its rig, shape-key animation
  and KD settings from :mod:`kdfaces.blender.scene`, the window its live KD uses), for constraint tables given by
  the caller (:func:`kdfaces.blender.ikd.constraint_tables`); :func:`object_shot_settings`, what a stored IKD
  correction depends on besides its constraints. An armature's pose is written as ``[[animation.joints]]`` (each
  head-chain joint's own angles, radians); :func:`object_shot` holds the rig as the shot's rig file loads back
  (:func:`as_rig_file_gives_back`: float32 skin weights), so a bake is ``kdfaces run`` on the exported file bit
  for bit.

Used by :mod:`kdfaces.blender.ikd` (Solve IKD) and :mod:`kdfaces.blender.bake` (bakes, Export shot file); it imports
neither.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kdfaces.errors import KDInputError

__all__ = ["Cancelled", "RIG_SUFFIX", "animation_table", "shot_table", "write_shot_file", "object_dynamics",
           "object_shot_settings", "object_shot_table", "object_shot", "shot_name", "as_rig_file_gives_back",
           "rig_constraint_tables"]

#: The rig written next to an exported shot file ``<stem>.toml``: ``<stem>_rig.npz``.
RIG_SUFFIX = "_rig.npz"


class Cancelled(Exception):
    """A solve or bake stopped by its ``cancel`` callback (Esc): nothing was stored or written."""


def _curve_table(curve, where: str) -> tuple[list, list, str]:
    """(times_s, values, interpolation) of a :class:`~kdfaces.motion.curves.KeyframeCurve` as the shot file writes
    them: linear and Catmull-Rom curves as they are, Hermite curves with zero tangents as ``"ease"`` (the only
    Hermite curve the schema has); anything else is an error naming ``where``."""
    interp = curve.interpolation
    if interp == "hermite":
        if np.any(curve.tangents != 0.0):
            raise KDInputError(f"{where}: a Hermite curve with non-zero tangents has no shot-file form (the schema "
                               "keys 'ease', 'linear' and 'catmull-rom' curves); expected keys of one of those")
        interp = "ease"
    elif interp not in ("linear", "catmull-rom"):
        raise KDInputError(f"{where}: interpolation {interp!r} has no shot-file form")
    return [float(t) for t in curve.times], np.asarray(curve.values, dtype=np.float64).tolist(), interp


def animation_table(animation) -> dict:
    """The ``[animation]`` table (``source = "keys"``) of a :class:`~kdfaces.motion.FaceAnimation`: its shape
    tracks, its head drive (one yaw/pitch/roll drive on the default head-chain shares, written in degrees) or its
    joints' own drives (each on one joint with share 1, an armature's pose: ``[[animation.joints]]`` in radians),
    start, end and fps. Float values are written exactly (TOML keeps every bit of a float), so the shot file's animation
    evaluates to the same numbers. Raises :class:`KDInputError` for what the schema cannot say (a root translation,
    several head drives, drives with other shares, Hermite tangents)."""
    from kdfaces.motion.joints import HEAD_CHAIN_SPLIT

    out = {"source": "keys", "fps": float(animation.fps), "start_s": float(animation.start_s),
           "end_s": float(animation.end_s), "strict": True}
    tracks = []
    for i, tr in enumerate(animation.tracks):
        t, v, interp = _curve_table(tr.curve, f"animation.tracks[{i}]")
        tracks.append({"shapes": [str(n) for n in tr.names], "times_s": t, "values": v, "interpolation": interp})
    if tracks:
        out["tracks"] = tracks
    sk = animation.skeleton
    if sk.root is not None:
        raise KDInputError("animation: a root translation has no shot-file form; expected the head's rotation only")
    if sk.drives and all(len(d.shares) == 1 and list(d.shares.values())[0] == 1.0 for d in sk.drives):
        joints = []  # each joint's own angles (an armature's pose): [[animation.joints]], radians, exact
        for i, d in enumerate(sk.drives):
            t, v, interp = _curve_table(d.curve, f"animation.joints[{i}]")
            v = np.asarray(v, dtype=np.float64)
            joints.append({"joint": str(next(iter(d.shares))), "times_s": t, "yaw_rad": v[:, 0].tolist(),
                           "pitch_rad": v[:, 1].tolist(), "roll_rad": v[:, 2].tolist(), "interpolation": interp})
        out["joints"] = joints
        return out
    if len(sk.drives) > 1:
        raise KDInputError(f"animation: {len(sk.drives)} joint drives; a shot file keys one head drive")
    if sk.drives:
        d = sk.drives[0]
        if dict(d.shares) != dict(HEAD_CHAIN_SPLIT):
            raise KDInputError("animation.head: a drive with its own joint shares has no shot-file form; expected "
                               "the default head-chain split")
        t, v, interp = _curve_table(d.curve, "animation.head")
        deg = np.degrees(np.asarray(v, dtype=np.float64))
        if not np.allclose(np.radians(deg), v, rtol=0, atol=0):
            raise KDInputError("animation.head: the angles do not survive degrees and back exactly")
        out["head"] = {"times_s": t, "yaw_deg": deg[:, 0].tolist(), "pitch_deg": deg[:, 1].tolist(),
                       "roll_deg": deg[:, 2].tolist(), "interpolation": interp}
    return out


def shot_table(*, name: str, rig_source: str, animation, dynamics: dict | None = None, constraints=(),
               solver: dict | None = None, channel_map: dict | None = None) -> dict:
    """A whole shot file as a dict (TOML tables): ``name``, ``[rig] source = rig_source`` (metres),
    :func:`animation_table` of ``animation``, ``[dynamics]`` (settings as in the schema; defaults fill the rest),
    ``[[constraints]]`` (tables as in the schema, e.g. from :func:`kdfaces.blender.ikd.constraint_tables`),
    ``[solver]`` and ``[animation.map]``."""
    table = {"name": str(name), "rig": {"source": str(rig_source), "units": "m"},
             "animation": animation_table(animation)}
    if channel_map:
        table["animation"]["map"] = dict(channel_map)
    if dynamics:
        table["dynamics"] = {k: v for k, v in dynamics.items() if v is not None}
    if constraints:
        table["constraints"] = [{k: v for k, v in c.items() if v is not None} for c in constraints]
    if solver:
        table["solver"] = dict(solver)
    return table


def _toml(value):
    import tomlkit

    if isinstance(value, dict):
        t = tomlkit.table()
        for k, v in value.items():
            t[k] = _toml(v)
        return t
    if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        aot = tomlkit.aot()
        for v in value:
            aot.append(_toml(v))
        return aot
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, dict | list | tuple):
        return tomlkit.item(_plain(value))
    return tomlkit.item(value)


def _plain(value):
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def shot_name(name: str) -> str:
    """A file-safe stem from an object name (letters, digits, ``-``, ``_``; others become ``_``)."""
    out = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in str(name)).strip("_")
    return out or "shot"


def write_shot_file(path, rig, animation, *, dynamics: dict | None = None, constraints=(), solver: dict | None = None,
                    name: str | None = None, channel_map: dict | None = None) -> Path:
    """Write the shot file ``path`` (``.toml``) and its rig ``<stem>_rig.npz`` beside it (both atomically, the rig
    first); returns ``path``. The shot's ``name`` defaults to the file stem. Parsed back
    (:func:`~kdfaces.shots.load_shot`), it is the same shot: the rig's arrays, x_K and the constraints' targets are
    the same numbers (checked here before anything is written)."""
    import tomlkit

    from kdfaces.io.atomic import atomic_path
    from kdfaces.io.rigfiles import save_npz
    from kdfaces.shots.shotfile import parse_shot

    p = Path(path)
    if p.suffix != ".toml":
        raise KDInputError(f"{p}: expected a .toml shot file path")
    rig_path = p.with_name(p.stem + RIG_SUFFIX)
    table = shot_table(name=name or p.stem, rig_source=rig_path.name, animation=animation, dynamics=dynamics,
                       constraints=constraints, solver=solver, channel_map=channel_map)
    parse_shot(table, p, rig=rig)  # the schema's errors now, before a file exists
    doc = tomlkit.document()
    doc.add(tomlkit.comment("written by the kdfaces Blender extension (Export shot file); run: kdfaces run "
                            f"{p.name} --export pc2"))
    for k, v in table.items():
        doc[k] = _toml(v)
    save_npz(rig, rig_path)
    with atomic_path(p, ".toml") as tmp:
        Path(tmp).write_text(tomlkit.dumps(doc), encoding="utf-8")
    return p


def object_dynamics(obj, scene) -> dict:
    """The ``[dynamics]`` table of the object's KD settings and the window its live KD uses (the automatic window
    resolved to seconds, so ``kdfaces run`` simulates with exactly that δ)."""
    from .scene import kd_settings, object_window

    s = kd_settings(obj)
    settle = float(s.stiff_s) if s.stiff_s == s.loose_s else {"stiff_s": float(s.stiff_s),
                                                               "loose_s": float(s.loose_s)}
    window = object_window(obj, scene)
    return {"settle_time_s": settle, "damping_ratio": float(s.damping_ratio),
            "shape_matching_alpha": float(s.shape_matching_alpha),
            "window_s": window if isinstance(window, str) else float(window)}


def object_shot_settings(obj, scene) -> dict:
    """What the object's shot depends on besides its constraints (hashes of the rig and the animation, the KD
    settings and window): a stored IKD correction is current while these and the constraints are unchanged."""
    from .scene import object_entry

    e = object_entry(obj, scene)
    return {"rig": e.rig_key.hex(), "animation": e.anim_key.hex(), "dynamics": object_dynamics(obj, scene)}


def rig_constraint_tables(obj, scene, constraints) -> list[dict]:
    """``constraints`` (``[[constraints]]`` tables whose ``group`` names the Blender mesh's vertices, as
    :func:`kdfaces.blender.ikd.constraint_tables` reads them) with each group on the rig's vertices: a welded mesh
    (:func:`kdfaces.blender.scene._weld`, UV-seam copies) names the rig vertex of each mesh vertex, each rig vertex
    once (an Empty vertex-parented to a seam copy constrains the copy's rig vertex; a vertex group holding both
    copies of a seam vertex counts it once). Tables without a group, and every table of a mesh that does not weld,
    are returned as they are."""
    from .scene import object_entry

    e = object_entry(obj, scene)
    if e.weld is None:
        return list(constraints)
    out = []
    for c in constraints:
        if "group" in c:
            mesh = np.asarray(c["group"], dtype=np.int64)
            rig = e.rig_vertices(mesh)
            _, first = np.unique(rig, return_index=True)
            c = {**c, "group": [int(v) for v in rig[np.sort(first)]]}  # each rig vertex once, in the group's order
        out.append(c)
    return out


def object_shot_table(obj, scene, constraints, *, rig_source: str = "rig.npz") -> dict:
    """The object's shot file as a dict: its rig (``rig_source``), shape-key animation over the scene's range,
    ``[dynamics]`` from its KD settings, and ``constraints`` (tables, e.g.
    :func:`kdfaces.blender.ikd.constraint_tables`, on the mesh's vertices: :func:`rig_constraint_tables` puts
    them on the rig's)."""
    from .scene import _armature, object_animation

    anim = object_animation(obj, scene)
    sk = anim.skeleton
    if _armature(obj) is None and (sk.root is not None or sk.drives):
        raise KDInputError(f"object {obj.name!r}: its own transform is keyed (head motion), which a shot file cannot "
                           "say yet (no root translation, no object-origin joint); IKD, bakes and Export shot file "
                           "need an object whose transform is not keyed (key a parent Empty instead)")
    return shot_table(name=shot_name(obj.name), rig_source=rig_source, animation=anim,
                      dynamics=object_dynamics(obj, scene), constraints=rig_constraint_tables(obj, scene, constraints))


def as_rig_file_gives_back(rig):
    """``rig`` as its rig file (:func:`kdfaces.io.rigfiles.save_npz`, what :func:`write_shot_file` writes) loads
    back: skin weights rounded to float32 and rows that sum to one (within 1e-5) renormalised, as
    :func:`~kdfaces.io.rigfiles.load_npz` does; everything else is stored exactly. A bake computes on this rig, so
    it is ``kdfaces run`` on the exported shot file bit for bit (a skinned rig's x_K moves by ~1e-8 m)."""
    import dataclasses

    sk = rig.skeleton
    if sk is None:
        return rig
    w = sk.weights.astype(np.float32).astype(np.float64)
    total = w.sum(axis=1, keepdims=True)
    w = np.where(np.abs(total - 1.0) < 1e-5, w / np.where(total > 0, total, 1.0), w)
    return dataclasses.replace(rig, skeleton=dataclasses.replace(sk, weights=w))


def object_shot(obj, scene, constraints, *, path=None):
    """The object's :class:`~kdfaces.shots.Shot` (:func:`object_shot_table` parsed with the object's rig):
    what "Export shot file" writes, in memory. ``path`` names it in messages (default ``<object>.toml``)."""
    from kdfaces.shots.shotfile import parse_shot

    from .scene import object_rig

    table = object_shot_table(obj, scene, constraints)
    where = Path(path) if path is not None else Path(f"{shot_name(obj.name)}.toml")
    return parse_shot(table, where, rig=as_rig_file_gives_back(object_rig(obj, scene)))
