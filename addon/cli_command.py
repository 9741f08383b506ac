# SPDX-License-Identifier: GPL-3.0-or-later
"""`blender --command skinkit COMMAND ...`: the `skinkit` command line inside the user's own Blender (4.2+), the
same commands, options and --json output as the `skinkit` program (skinkit.cli.main), e.g.

    blender --background --command skinkit convert character.blend --out converted.blend --json
"""
import bpy

COMMAND = "skinkit"
classes = ()
_handle = None


def execute(argv) -> int:
    """Blender's entry point for the command: argv holds what follows `--command skinkit`."""
    from skinkit.cli import main

    try:
        return main(list(argv))
    except SystemExit as done:  # --help and --version exit through argparse
        return done.code if isinstance(done.code, int) else 0


def register():
    global _handle
    _handle = bpy.utils.register_cli_command(COMMAND, execute)


def unregister():
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None
