"""`python -m skinkit.cli`: the same as the `skinkit` command."""
import sys

from . import main

status = main()
if "bpy" in sys.modules:  # a command that loaded Blender ends the way that Blender's module allows
    from ..blender import compat

    compat.exit_process(status)
sys.exit(status)
