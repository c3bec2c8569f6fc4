"""Export entry points: point caches of trajectories by kind, and rigs for other tools.

``export_trajectory`` is what ``kdfaces demo/run/render/punch --export usd|pc2`` call for the final trajectory;
``add_export_option`` adds that repeatable option to a parser; ``export_rig`` writes a rig as an OBJ folder and
glTF (the ``kdfaces export-rig`` verb).

Every cache numbers frames alike: shot frame k is scene frame :data:`~kdfaces.defaults.FRAME_START` + k. A PC2
holds one mesh's vertices in its order: ``pc2`` the rig's (the OBJ export, an FBX rig, the USD cache), ``pc2-gltf``
the glTF export's (``<name>.gltf.pc2``: the rig's vertices, then the copies ``save_gltf`` splits at UV seams,
:func:`~kdfaces.io.gltf.gltf_vertex_map`), so that Blender's Mesh Cache modifier drives the mesh each importer
creates.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import KDInputError
from .pointcache import write_pc2, write_usd

__all__ = ["EXPORT_KINDS", "export_trajectory", "export_chunks", "open_export", "add_export_option", "export_rig"]

EXPORT_KINDS = {"usd": ".usdc", "usda": ".usda", "pc2": ".pc2", "pc2-gltf": ".gltf.pc2"}
RIG_FORMATS = ("obj", "gltf", "glb")


def export_trajectory(path, positions, times, *, kind: str | None = None, faces=None, fps: float | None = None,
                      name: str = "face", rig=None, unit_m: float = 1.0) -> Path:
    """Write a point cache of ``positions`` [m], shape (F, N, 3), at ``times`` [s], shape (F,).

    Args:
        path: a file, or a folder (existing, or without a suffix) that receives ``<name>.usdc`` / ``<name>.pc2``.
        kind: ``"usd"`` (binary crate), ``"usda"`` (text), ``"pc2"`` (the rig's vertex order) or ``"pc2-gltf"``
            (the vertex order of the rig's glTF export; needs ``rig``); inferred from the file suffix if None.
        faces: triangles (M, 3), for USD when no ``rig`` is given (PC2 stores none); with neither, USD stores
            the points as ``UsdGeom.Points``.
        fps: frame rate [1/s]; inferred from ``times`` if None.
        name: file stem inside a folder, and the USD prim name.
        rig: the rig the positions belong to: USD then keeps its polygons (quads stay quads) and UVs; ``pc2-gltf``
            takes its glTF vertex order from it.
        unit_m: metres per written unit: 1 writes metres, ``rig.source_unit_m`` the rig's own unit (0.01: cm).

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
        return write_pc2(p, positions, times, fps=fps, unit_m=unit_m)
    if kind == "pc2-gltf":
        return write_pc2(p, positions, times, fps=fps, unit_m=unit_m, vertex_map=_gltf_map(p, rig))
    if rig is not None:
        return write_usd(p, positions, times, rig.faces, fps=fps, prim_name=name, unit_m=unit_m,
                         polygons=(rig.polygon_counts, rig.polygon_corners), uvs=rig.uvs)
    return write_usd(p, positions, times, faces, fps=fps, prim_name=name, unit_m=unit_m)


def export_chunks(path, chunks, times, *, kind: str, num_vertices: int, fps: float | None = None,
                  name: str = "face", rig=None, faces=None, unit_m: float = 1.0) -> Path:
    """:func:`export_trajectory` from ``chunks``, an iterable of consecutive (k, N, 3) blocks of positions [m] in
    frame order (a bake store read chunk by chunk), so a long take is never held whole: ``path`` is the file,
    ``times`` (F,) [s] every frame's times, ``num_vertices`` N. A PC2 file is the same bytes as
    :func:`export_trajectory` of the whole array writes (a USD file the same stage, saved in steps)."""
    with open_export(path, times, kind=kind, num_vertices=num_vertices, fps=fps, name=name, rig=rig, faces=faces,
                     unit_m=unit_m) as writer:
        for block in chunks:
            writer.write(block)
    return writer.path


def open_export(path, times, *, kind: str, num_vertices: int, fps: float | None = None, name: str = "face",
                rig=None, faces=None, unit_m: float = 1.0):
    """The point-cache writer of :func:`export_chunks` for pushing blocks as they are computed (``kdfaces run``
    streams a take's frames into every cache in one pass): a context manager whose ``write(block)`` takes the
    next (k, N, 3) frames [m]; the file appears at ``path`` (its ``.path``) when the ``with`` block ends
    without an exception after every frame of ``times`` (F,) [s]. Arguments as :func:`export_chunks`."""
    from .pointcache import PC2Writer, USDWriter

    p = Path(path)
    if kind not in EXPORT_KINDS:
        raise KDInputError(f"export kind {kind!r}: expected one of {sorted(EXPORT_KINDS)}")
    if kind == "pc2":
        return PC2Writer(p, times, num_vertices=num_vertices, fps=fps, unit_m=unit_m)
    if kind == "pc2-gltf":
        return PC2Writer(p, times, num_vertices=num_vertices, fps=fps, unit_m=unit_m, vertex_map=_gltf_map(p, rig))
    if rig is not None:
        return USDWriter(p, times, rig.faces, num_vertices=num_vertices, fps=fps, prim_name=name, unit_m=unit_m,
                         polygons=(rig.polygon_counts, rig.polygon_corners), uvs=rig.uvs)
    return USDWriter(p, times, faces, num_vertices=num_vertices, fps=fps, prim_name=name, unit_m=unit_m)


def _gltf_map(p: Path, rig):
    """The glTF vertex order of ``rig`` for a ``pc2-gltf`` cache at ``p``."""
    from .gltf import gltf_vertex_map

    if rig is None:
        raise KDInputError(f"{p}: a pc2-gltf cache needs the rig (its glTF vertex order)")
    return gltf_vertex_map(rig)


def add_export_option(parser) -> None:
    """Add the repeatable ``--export {usd,usda,pc2,pc2-gltf}`` option (``args.export``: list of kinds, default
    empty) and ``--export-unit {m,rig}`` (``args.export_unit``)."""
    parser.add_argument("--export", action="append", default=[], choices=sorted(EXPORT_KINDS),
                        help="also write a point cache of the final trajectory (repeatable): usd/usda, pc2 (the "
                             "rig's vertices: OBJ, FBX), pc2-gltf (the glTF export's vertices, <name>.gltf.pc2)")
    parser.add_argument("--export-unit", default="m", choices=("m", "rig"),
                        help="point caches in metres (default) or in the rig file's own unit")


def export_rig(rig, out, *, formats=("obj", "gltf"), animation=None, unit_m: float = 1.0) -> list[Path]:
    """Write ``rig`` to ``out``: ``obj/`` (neutral.obj + one OBJ per shape, in units of ``unit_m`` metres) and/or
    ``<name>.gltf`` / ``.glb`` (metres, the glTF standard), with ``animation`` (a
    :class:`~kdfaces.motion.FaceAnimation`) as morph-weight animation when given."""
    from .gltf import save_gltf
    from .rigfiles import save_obj_folder

    out = Path(out)
    bad = sorted(set(formats) - set(RIG_FORMATS))
    if bad or not formats:
        raise KDInputError(f"export-rig formats {list(formats)}: expected some of {list(RIG_FORMATS)}")
    written = []
    for fmt in dict.fromkeys(formats):
        if fmt == "obj":
            written.append(save_obj_folder(rig, out / "obj", unit_m=unit_m))
        else:
            written.append(save_gltf(rig, out / f"{rig.name}.{fmt}", animation=animation))
    return written


