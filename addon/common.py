# SPDX-License-Identifier: GPL-3.0-or-later
"""What the family modules' operators, panels and handlers share: the poll check on the mode, the sidebar panel's
place, and the guard that keeps a scene handler from running inside itself."""
import functools


def object_mode_problem(context) -> str | None:
    """Why an operator that writes new objects cannot run in this mode (None in Object Mode)."""
    return None if context.mode == "OBJECT" else "Switch to Object Mode"


class SidebarPanel:
    """A collapsed panel in the 3D view's skinkit sidebar tab (a family's own, or a sub-panel by bl_parent_id)."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "skinkit"
    bl_options = {"DEFAULT_CLOSED"}


def not_reentrant(handler):
    """A handler whose own changes (a redraw tagging objects, a refresh writing a shape key) fire the handlers
    again: a call made while it runs returns at once."""
    running = False

    @functools.wraps(handler)
    def guarded(*arguments, **keywords):
        nonlocal running
        if running:
            return None
        running = True
        try:
            return handler(*arguments, **keywords)
        finally:
            running = False

    return guarded
