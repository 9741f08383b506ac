"""The `skinkit` command line, for headless and batch use.

Commands that read .blend files need Blender's Python module (`bpy`, installed by `make venv`) or must
run inside Blender. With --json a command prints exactly one JSON object on stdout (Blender's own
messages are sent to stderr meanwhile), also on failure: {"error": "..."} with exit status 1.

Each command is a module of skinkit.cli.commands with `add_parser(subparsers, common)` and `run(arguments)
-> dict`; inputs.py reads what they take in, outputs.py writes what they give out. A command that names a `STAGE`
gets a progress bar on a terminal (progress.py).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from contextlib import contextmanager

from .. import __version__
from .._checks import set_memory_limit
from ..model import SkinkitError
from . import progress
from .commands import COMMANDS
from .outputs import check_output_folder


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    arguments = parser.parse_args(argv)
    if not getattr(arguments, "run", None):
        parser.print_help()
        return 2
    try:
        if getattr(arguments, "out", None):
            check_output_folder(arguments.out)  # before the work, not after it
        set_memory_limit(getattr(arguments, "memory_limit", None))
        with stdout_to_stderr(arguments.json), progress.session(progress.wanted(arguments.json)):
            if arguments.stage:
                progress.stage(arguments.stage)
            result = arguments.run(arguments)
    except (SkinkitError, OSError) as error:
        return report_failure(str(error), arguments.json)
    report(result, arguments.json)
    return 1 if result.get("status") == "failed" else 0  # a result that is no success (e.g. a broken atlas)


def common_parents() -> dict[str, argparse.ArgumentParser]:
    """The flags several commands share, as argparse parents: "json" (--json), "scene" (a .blend and the mesh
    in it, with --json), "sequence_scale" (for sequences read from files)."""
    json_flag = argparse.ArgumentParser(add_help=False)
    json_flag.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    json_flag.add_argument("--memory-limit", type=memory_size, metavar="SIZE",
                           help="refuse, before starting, work that would need more memory than this (e.g. 8G, 512M; "
                                "default: the memory free now), for farm nodes shared with other jobs")
    sequence_scale = argparse.ArgumentParser(add_help=False)
    sequence_scale.add_argument("--sequence-scale", type=float, default=1.0,
                                help="scale applied to a sequence read from an .obj folder or an .abc (e.g. 0.01 when "
                                     "it is in centimetres and the rig in metres); exported frames are divided by it")
    scene = argparse.ArgumentParser(add_help=False, parents=[json_flag])
    scene.add_argument("scene", metavar="SCENE.blend")
    scene.add_argument("--object", help="the mesh (default: the only mesh with an Armature modifier)")
    return {"json": json_flag, "scene": scene, "sequence_scale": sequence_scale}


def memory_size(text: str) -> int:
    """'8G', '512M', '1.5G' or a number of bytes."""
    units = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    number, unit = (text[:-1], units[text[-1].upper()]) if text[-1:].upper() in units else (text, 1)
    try:
        size = float(number) * unit
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a size such as 8G or 512M") from None
    if not 1 <= size < 2**62:
        raise argparse.ArgumentTypeError(f"{text!r} is not a usable memory limit")
    return int(size)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="skinkit", description="Animation-space skinning for Blender scenes.")
    parser.add_argument("--version", action="version", version=f"skinkit {__version__}")
    subparsers = parser.add_subparsers(metavar="COMMAND")
    common = common_parents()
    for command in COMMANDS:
        # STAGE: the name a command's progress bar starts with (skinkit/cli/progress.py); none, no bar.
        command.add_parser(subparsers, common).set_defaults(run=command.run, stage=getattr(command, "STAGE", None))
    return parser


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
