"""The `skinkit` command line, for headless and batch use.

Commands that read .blend files need Blender's Python module (`bpy`, installed by `make venv`) or must
run inside Blender. With --json a command prints exactly one JSON object on stdout (Blender's own
messages are sent to stderr meanwhile), also on failure: {"error": "..."} with exit status 1.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from contextlib import contextmanager

from . import __version__
from .model import SkinkitError


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    arguments = parser.parse_args(argv)
    if not getattr(arguments, "command", None):
        parser.print_help()
        return 2
    try:
        with stdout_to_stderr(arguments.json):
            result = arguments.command(arguments)
    except (SkinkitError, OSError) as error:
        return report_failure(str(error), arguments.json)
    report(result, arguments.json)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="skinkit", description="Animation-space skinning for Blender scenes.")
    parser.add_argument("--version", action="version", version=f"skinkit {__version__}")
    commands = parser.add_subparsers(metavar="COMMAND")

    convert = add_command(commands, "convert", run_convert,
                          "convert an object's linear blend skinning to animation space and save the scene")
    convert.add_argument("--out", required=True, help="the .blend to write (the input is not modified)")
    convert.add_argument("--ignore-unmatched-groups", action="store_true",
                         help="ignore vertex groups that name no bone instead of refusing the mesh")

    evaluate = add_command(commands, "eval", run_eval,
                           "evaluate the model over frames beside Blender's Armature modifier")
    evaluate.add_argument("--frames", help="A:B, inclusive (default: the scene's frame range)")

    bake = add_command(commands, "bake", run_bake, "bake the model's animation to a PC2 cache and/or shape keys")
    bake.add_argument("--frames", help="A:B, inclusive (default: the scene's frame range)")
    bake.add_argument("--pc2", help="write a PC2 point cache here")
    bake.add_argument("--out", help="write the scene with a shape-key baked copy of the object here")
    return parser


def add_command(commands, name: str, function, help_text: str) -> argparse.ArgumentParser:
    command = commands.add_parser(name, help=help_text, description=help_text)
    command.add_argument("scene", metavar="SCENE.blend")
    command.add_argument("--object", help="the mesh (default: the only mesh with an Armature modifier)")
    command.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    command.set_defaults(command=function)
    return command


def run_convert(arguments) -> dict:
    bpy, operations = open_scene(arguments.scene)
    mesh_object = find_object(arguments)
    result = operations.convert_object(mesh_object, arguments.ignore_unmatched_groups)
    save_scene(bpy, arguments.out)
    return {**result, "out": os.path.abspath(arguments.out)}


def run_eval(arguments) -> dict:
    _, operations = open_scene(arguments.scene)
    from .blender import storage

    mesh_object = find_object(arguments)
    converted = not storage.has_model(mesh_object.data)
    if converted:  # in memory only: the file is not written
        operations.convert_object(mesh_object)
    result = operations.compare_with_armature(mesh_object, frame_range(arguments.frames))
    return {**result, "converted_in_memory": converted}


def run_bake(arguments) -> dict:
    if not arguments.pc2 and not arguments.out:
        raise SkinkitError("bake needs --pc2 FILE, --out FILE.blend, or both")
    bpy, operations = open_scene(arguments.scene)
    from .blender import storage

    mesh_object = find_object(arguments)
    if not storage.has_model(mesh_object.data):
        raise SkinkitError(f"'{mesh_object.name}' has no animation-space model; run `skinkit convert` first")
    frames = frame_range(arguments.frames)
    positions = operations.positions_over_frames(mesh_object, frames)
    result = {"object": mesh_object.name, "frames": len(frames), "vertices": len(mesh_object.data.vertices)}
    if arguments.pc2:
        operations.bake_mesh_cache(mesh_object, os.path.abspath(arguments.pc2), frames, positions, add_object=False)
        result["pc2"] = os.path.abspath(arguments.pc2)
    if arguments.out:
        result["baked_object"] = operations.bake_shape_keys(mesh_object, frames, positions).name
        save_scene(bpy, arguments.out)
        result["out"] = os.path.abspath(arguments.out)
    return result


def open_scene(path: str):
    """Loads a .blend with Blender's Python module; returns (bpy, skinkit.blender.operations)."""
    try:
        import bpy
    except ImportError:
        raise SkinkitError("this command needs Blender's Python module: `pip install bpy==4.5.4`, "
                           "or run it inside Blender") from None
    if not os.path.isfile(path):
        raise SkinkitError(f"{path}: no such file")
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False)
    except RuntimeError as error:
        raise SkinkitError(f"{path}: Blender could not open it ({str(error).strip()})") from None
    from .blender import operations

    return bpy, operations


def find_object(arguments):
    import bpy

    from .blender.rig import find_skinned_mesh

    return find_skinned_mesh(bpy.context.scene.objects, arguments.object)


def save_scene(bpy, path: str) -> None:
    if not path.endswith(".blend"):
        raise SkinkitError(f"{path}: the output must be a .blend file")
    bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(path), check_existing=False)


def frame_range(text: str | None) -> range:
    """'A:B' (inclusive) or the scene's own range."""
    import bpy

    if text is None:
        scene = bpy.context.scene
        return range(scene.frame_start, scene.frame_end + 1)
    try:
        first, last = (int(part) for part in text.split(":"))
    except ValueError:
        raise SkinkitError(f"--frames {text!r}: expected A:B with whole numbers, e.g. 1:48") from None
    if last < first:
        raise SkinkitError(f"--frames {text!r}: the range is empty (B < A)")
    return range(first, last + 1)


@contextmanager
def stdout_to_stderr(active: bool):
    """Sends everything written to file descriptor 1 (Blender prints from C) to stderr while inside."""
    if not active:
        yield
        return
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def report(result: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(result, sort_keys=True))
        return
    for key, value in result.items():
        print(f"{key}: {value}")


def report_failure(message: str, as_json: bool) -> int:
    print(f"skinkit: error: {message}", file=sys.stderr)
    if as_json:
        print(json.dumps({"error": message}))
    return 1


if __name__ == "__main__":
    sys.exit(main())
