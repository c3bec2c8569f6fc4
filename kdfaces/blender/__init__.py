"""The kdfaces Blender extension (Blender 4.2+): KD on the timeline, IKD targets as objects, bake and hand-off.

This folder is the extension itself (``blender_manifest.toml`` beside this file; ``scripts/build_blender_extension.py``
zips it with the kdfaces wheel and its dependencies). Nothing here imports ``bpy`` at import time: the modules that
define Blender classes are imported by :func:`register`, which Blender calls when the extension is enabled. The
library-facing API (scene → rig, trajectory, model; one frame's KD state) is :mod:`kdfaces.blender.scene`
(imported as ``from . import scene`` in the extension, where this package is ``bl_ext.<repo>.kdfaces``).
"""

from __future__ import annotations

import importlib

__all__ = ["register", "unregister", "MODULES"]

#: The modules whose ``CLASSES`` tuple is registered, in order (properties first: the panels read them); a module
#: may also have ``register_extra()`` / ``unregister_extra()`` (handlers, menu entries).
MODULES = ("props", "ops", "ui", "handlers", "importer", "ikd", "bake")

_registered: list = []


def _modules():
    return [importlib.import_module(f".{name}", __name__) for name in MODULES]


def register() -> None:
    """Register every module's classes, then its extras (Blender calls this when the extension is enabled)."""
    import bpy

    for module in _modules():
        for cls in getattr(module, "CLASSES", ()):
            bpy.utils.register_class(cls)
            _registered.append(cls)
        extra = getattr(module, "register_extra", None)
        if extra is not None:
            extra()
    from . import ikd, scene

    scene.TRAJECTORY_HOOKS[:] = [ikd.corrected_trajectory]  # the live KD state includes the stored IKD correction


def unregister() -> None:
    """Undo :func:`register` in reverse order."""
    import bpy

    for module in reversed(_modules()):
        extra = getattr(module, "unregister_extra", None)
        if extra is not None:
            extra()
    while _registered:
        bpy.utils.unregister_class(_registered.pop())
    from . import scene

    scene.TRAJECTORY_HOOKS.clear()
