# SPDX-License-Identifier: GPL-3.0-or-later
"""What the family modules' operators and panels share: the poll check on the mode, and the sidebar panel's place."""


def object_mode_problem(context) -> str | None:
    """Why an operator that writes new objects cannot run in this mode (None in Object Mode)."""
    return None if context.mode == "OBJECT" else "Switch to Object Mode"


class SidebarPanel:
    """A collapsed panel in the 3D view's skinkit sidebar tab (a family's own, or a sub-panel by bl_parent_id)."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "skinkit"
    bl_options = {"DEFAULT_CLOSED"}
