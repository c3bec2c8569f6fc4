"""The KD settings of an object (``obj.kdfaces``), a Blender PropertyGroup; defaults from :mod:`kdfaces.defaults`.

Read them through :func:`kdfaces.blender.scene.kd_settings`, which turns them into a plain
:class:`~kdfaces.blender.scene.KDSettings`. Imported by the extension's ``register()`` only (it imports ``bpy``).
"""

from __future__ import annotations

import bpy

from kdfaces import defaults


def _redraw(self, context):
    """A changed setting recomputes the current frame (the per-object cache sees the new settings' hash)."""
    from . import handlers

    handlers.refresh(context.scene)


class KDObjectSettings(bpy.types.PropertyGroup):
    """Kinodynamics of one mesh object with shape keys."""

    enabled: bpy.props.BoolProperty(
        name="Kinodynamics", default=False, update=_redraw,
        description="Show this object's history-free KD state on every frame (a KD shape key holds x_KD - x_K)")
    stiff_s: bpy.props.FloatProperty(
        name="Settle (stiff)", default=defaults.SETTLE_TIME_S, min=1e-3, soft_max=2.0, unit="TIME_ABSOLUTE",
        update=_redraw, description="Settle time over bone [s]: 90% of a tracking error is gone after this long")
    loose_s: bpy.props.FloatProperty(
        name="Settle (loose)", default=defaults.SETTLE_TIME_S, min=1e-3, soft_max=2.0, unit="TIME_ABSOLUTE",
        update=_redraw, description="Settle time in cheeks and lips [s] (equal to stiff: one settle time everywhere)")
    damping_ratio: bpy.props.FloatProperty(
        name="Damping ratio", default=defaults.DAMPING_RATIO, min=1e-3, soft_max=2.0, update=_redraw,
        description="Damping ratio zeta (1 = critically damped; below 1 overshoots)")
    shape_matching_alpha: bpy.props.FloatProperty(
        name="Shape matching", default=defaults.SHAPE_MATCHING_ALPHA, min=0.0, max=1.0, update=_redraw,
        description="Shape-matching stiffness alpha (0 switches it off)")
    window_mode: bpy.props.EnumProperty(
        name="Window", default=defaults.WINDOW_S, update=_redraw,
        items=[("auto", "Auto", "The automatic window of the whole shot (paper 5.2)"),
               ("adaptive", "Adaptive", "Each frame's smallest window whose truncation error is below epsilon"),
               ("seconds", "Seconds", "A fixed window in seconds")],
        description="How long each frame's history-free KD window reaches back")
    window_s: bpy.props.FloatProperty(
        name="Window", default=defaults.FIXED_WINDOW_S, min=1e-3, soft_max=5.0, unit="TIME_ABSOLUTE",
        update=_redraw, description="The KD window [s] when the window mode is Seconds")


CLASSES = (KDObjectSettings,)


def register_extra() -> None:
    bpy.types.Object.kdfaces = bpy.props.PointerProperty(type=KDObjectSettings)


def unregister_extra() -> None:
    del bpy.types.Object.kdfaces
