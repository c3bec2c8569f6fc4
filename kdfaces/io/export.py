"""Export entry points: point caches of trajectories by kind, and the ``export-rig`` command verb.

``export_trajectory`` is what ``kdfaces demo/run/render --export usd|pc2`` call for the final trajectory;
``add_export_option`` adds that repeatable option to a parser; ``add_export_rig_parser`` adds the
``kdfaces export-rig`` verb (rig → OBJ folder and glTF).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import KDInputError
from .pointcache import write_pc2, write_usd

__all__ = ["EXPORT_KINDS", "export_trajectory", "add_export_option", "add_export_rig_parser", "export_rig"]

EXPORT_KINDS = {"usd": ".usdc", "usda": ".usda", "pc2": ".pc2"}
RIG_FORMATS = ("obj", "gltf", "glb")


def export_trajectory(path, positions, times, *, kind: str | None = None, faces=None, fps: float | None = None,
                      name: str = "face") -> Path:
    """Write a point cache of ``positions`` [m], shape (F, N, 3), at ``times`` [s], shape (F,).

    Args:
        path: a file, or a folder (existing, or without a suffix) that receives ``<name>.usdc`` / ``<name>.pc2``.
        kind: ``"usd"`` (binary crate), ``"usda"`` (text) or ``"pc2"``; inferred from the file suffix if None.
        faces: triangles (M, 3), required for USD (PC2 stores none).
        fps: frame rate [1/s]; inferred from ``times`` if None.
        name: file stem inside a folder, and the USD prim name.

    Returns:
        The path written.
    """
    p = Path(path)
    by_suffix = {".usd": "usd", ".usdc": "usd", ".usda": "usda", ".pc2": "pc2"}
    if kind is None:
        if p.suffix not in by_suffix:
            raise KDInputError(f"{p}: cannot tell the point-cache kind; pass kind in {sorted(EXPORT_KINDS)} or use "
                               f"a {sorted(by_suffix)} suffix")
        kind = by_suffix[p.suffix]
    if kind not in EXPORT_KINDS:
        raise KDInputError(f"export kind {kind!r}: expected one of {sorted(EXPORT_KINDS)}")
    if p.is_dir() or not p.suffix:
        p = p / f"{name}{EXPORT_KINDS[kind]}"
    if kind == "pc2":
        return write_pc2(p, positions, times, fps=fps)
    return write_usd(p, positions, times, faces, fps=fps, prim_name=name)


def add_export_option(parser) -> None:
    """Add the repeatable ``--export {usd,usda,pc2}`` option (``args.export``: list of kinds, default empty)."""
    parser.add_argument("--export", action="append", default=[], choices=sorted(EXPORT_KINDS),
                        help="also write a point cache of the final trajectory (repeatable)")


def export_rig(rig, out, *, formats=("obj", "gltf")) -> list[Path]:
    """Write ``rig`` to ``out``: ``obj/`` (neutral.obj + one OBJ per shape) and/or ``<name>.gltf`` / ``.glb``."""
    from .gltf import save_gltf
    from .rigfiles import save_obj_folder

    out = Path(out)
    bad = sorted(set(formats) - set(RIG_FORMATS))
    if bad or not formats:
        raise KDInputError(f"export-rig formats {list(formats)}: expected some of {list(RIG_FORMATS)}")
    written = []
    for fmt in dict.fromkeys(formats):
        if fmt == "obj":
            written.append(save_obj_folder(rig, out / "obj"))
        else:
            written.append(save_gltf(rig, out / f"{rig.name}.{fmt}"))
    return written


def _export_rig_command(args) -> dict:
    from .rigfiles import load_rig
    from .summary import write_summary

    if Path(args.rig).suffix in (".gltf", ".glb"):
        from .gltf import load_gltf_rig

        rig = load_gltf_rig(args.rig)
    else:
        rig = load_rig(args.rig)
    out = Path(args.out)
    written = export_rig(rig, out, formats=args.format or ["obj", "gltf"])
    summary = {
        "rig": {"name": rig.name, "vertices": rig.num_vertices, "shapes": rig.num_shapes,
                "diameter_m": rig.diameter, "max_delta_m": float(np.abs(rig.deltas).max())},
        "outputs": [str(p.relative_to(out)) for p in written],
    }
    write_summary(out, summary)
    return summary


def add_export_rig_parser(subparsers) -> None:
    """Add ``kdfaces export-rig [--rig R] [--out DIR] [--format obj|gltf|glb ...] [--json]``."""
    ap = subparsers.add_parser("export-rig", help="write a rig as an OBJ folder and/or glTF for other tools")
    ap.add_argument("--rig", default="default", help="rig: 'default', an .npz, an OBJ folder or a .gltf/.glb")
    ap.add_argument("--out", default="kd-out/rig", help="output folder (default kd-out/rig)")
    ap.add_argument("--format", action="append", choices=RIG_FORMATS,
                    help="obj, gltf or glb (repeatable; default obj and gltf)")
    ap.add_argument("--json", action="store_true", help="print summary.json to stdout")
    ap.set_defaults(func=_export_rig_command)
