"""JOBS.toml: the characters of a batch and the pipeline each one goes through.

    out = "processed"          # where each character's folder goes (relative to this file); default "out"
    retries = 2                # extra tries of a character that fails (default 1)

    [[character]]
    name = "arm"               # its output folder: out/arm
    input = "arm.blend"        # the first step's input (a .blend, or a sequence for decompose)

    [[character.step]]
    command = "convert"        # any skinkit command: convert, fit, decompose, unwrap, lod, bake, ...
    output = "arm_converted.blend"

    [[character.step]]
    command = "unwrap"
    input = "arm.blend"        # optional: this step's own input instead of the previous scene
    output = "arm.obj"
    options = { charts = 6, texture-size = 1024 }   # --charts 6 --texture-size 1024; true: a bare flag

Each step is `skinkit COMMAND INPUT [--out OUTPUT] OPTIONS --json`; its output becomes the next step's input when it
is a .blend (a later step reads the converted scene). Input paths are relative to JOBS.toml; outputs are file
names in the character's folder. A command that writes its output through another flag names it:
`output-flag = "--pc2"` (bake).
"""
from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field

from .._checks import INPUT_FILE, checked
from ..model import SkinkitError

DEFAULT_RETRIES = 1
#: The commands whose output flag is not --out.
OUTPUT_FLAGS = {"bake": "--pc2"}


@dataclass(frozen=True)
class Step:
    command: str
    output: str | None = None
    input: str | None = None         # absolute; None: the previous step's scene (or the character's input)
    options: tuple = ()              # ((flag, value), ...) in the file's order
    output_flag: str = "--out"


@dataclass(frozen=True)
class Character:
    name: str
    input: str                       # absolute
    steps: tuple = field(default_factory=tuple)
    out: str = ""                    # the batch's output folder (absolute); the character's is out/name
    retries: int = DEFAULT_RETRIES
    base: str = ""                   # JOBS.toml's folder: the steps run there, so relative options resolve alike

    @property
    def folder(self) -> str:
        return os.path.join(self.out, self.name)


@checked(path=INPUT_FILE)
def load_jobs(path: str) -> list[Character]:
    """The characters of JOBS.toml, checked: a SkinkitError names the character, the step and what is wrong."""
    try:
        with open(path, "rb") as file:
            document = tomllib.load(file)
    except tomllib.TOMLDecodeError as error:
        raise SkinkitError(f"{path}: not valid TOML ({error})") from None
    except UnicodeDecodeError as error:  # tomllib decodes UTF-8 before it parses: a binary file fails there
        raise SkinkitError(f"{path}: not a UTF-8 text file, so not TOML (byte {error.start})") from None
    base = os.path.dirname(os.path.abspath(path))
    out = os.path.join(base, str(document.get("out", "out")))
    retries = document.get("retries", DEFAULT_RETRIES)
    if not isinstance(retries, int) or retries < 0:
        raise SkinkitError(f"{path}: retries must be a whole number >= 0 (got {retries!r})")
    characters = [character_from(entry, index, base, out, retries, path)
                  for index, entry in enumerate(document.get("character", []))]
    if not characters:
        raise SkinkitError(f"{path}: no [[character]] tables")
    names = [c.name for c in characters]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise SkinkitError(f"{path}: character names must be unique (repeated: {', '.join(duplicates)})")
    return characters


def character_from(entry: dict, index: int, base: str, out: str, retries: int, path: str) -> Character:
    name = entry.get("name")
    where = f"{path}: character {index + 1}"
    if not isinstance(name, str) or not name or os.sep in name or name.startswith("."):
        raise SkinkitError(f"{where}: needs a name usable as a folder name (got {name!r})")
    where = f"{path}: character '{name}'"
    if not isinstance(entry.get("input"), str):
        raise SkinkitError(f"{where}: needs input = \"FILE\"")
    steps = entry.get("step", [])
    if not steps:
        raise SkinkitError(f"{where}: needs at least one [[character.step]]")
    return Character(name, os.path.join(base, entry["input"]),
                     tuple(step_from(step, number + 1, base, where) for number, step in enumerate(steps)), out,
                     int(entry.get("retries", retries)), base)


def command_names() -> set[str]:
    """The names `skinkit COMMAND` accepts (batch itself excluded: a batch does not nest)."""
    import argparse

    from ..cli import build_parser

    choices = next(action.choices for action in build_parser()._actions
                   if isinstance(action, argparse._SubParsersAction))
    return set(choices) - {"batch"}


def step_from(entry: dict, number: int, base: str, where: str) -> Step:
    known = command_names()
    command = entry.get("command")
    if command not in known:
        raise SkinkitError(f"{where}, step {number}: command must be one of {', '.join(sorted(known))} "
                           f"(got {command!r})")
    output = entry.get("output")
    if output is not None and (not isinstance(output, str) or os.path.basename(output) != output or not output):
        raise SkinkitError(f"{where}, step {number}: output must be a file name (in the character's folder), "
                           f"got {output!r}")
    options = entry.get("options", {})
    if not isinstance(options, dict):
        raise SkinkitError(f"{where}, step {number}: options must be a table")
    return Step(command, output, os.path.join(base, entry["input"]) if "input" in entry else None,
                tuple((f"--{key}", value) for key, value in options.items()),
                entry.get("output-flag", OUTPUT_FLAGS.get(command, "--out")))
