"""One character's pipeline, as a Dask task runs it: every step a `skinkit COMMAND ... --json` process of its own
(a crash in Blender ends that process, not the worker), all outputs written into a scratch folder beside the
character's and renamed onto it only when every step succeeded, with a manifest of the inputs' content hashes so
that a re-run finds the outputs current and skips them."""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
import uuid

from .. import __version__
from .._checks import checked, optional
from ..model import SkinkitError
from .jobs import Character

MANIFEST_NAME = "manifest.json"
PARTIAL_MARK = ".partial-"
#: The longest one step may run (seconds) before it counts as hung and fails.
STEP_TIMEOUT = 3600


class StepFailed(SkinkitError):
    """A step's process exited with an error (its message is in the text); the task fails and Dask retries it."""


def content_hash(path: str) -> str:
    """sha256 of a file, or of a folder's files (names and contents, sorted): what a step reads from it."""
    digest = hashlib.sha256()
    if os.path.isdir(path):
        for folder, subfolders, names in sorted(os.walk(path)):
            subfolders.sort()
            for name in sorted(names):
                digest.update(os.path.relpath(os.path.join(folder, name), path).encode() + b"\0")
                digest.update(content_hash(os.path.join(folder, name)).encode())
        return digest.hexdigest()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def fingerprint(character: Character) -> dict:
    """What the outputs depend on: the inputs' content hashes (the character's input, each step's own, and every
    option naming an existing file or folder), the steps as written, and skinkit's version."""
    inputs = [character.input] + [step.input for step in character.steps if step.input]
    for step in character.steps:
        inputs += [os.path.join(character.base, value) for _, value in step.options
                   if isinstance(value, str) and os.path.exists(os.path.join(character.base, value))]
    missing = [path for path in inputs if not os.path.exists(path)]
    if missing:
        raise SkinkitError(f"character '{character.name}': input {missing[0]} does not exist")
    return {"inputs": {path: content_hash(path) for path in sorted(set(inputs))},
            "steps": [[step.command, step.input, step.output, [list(o) for o in step.options], step.output_flag]
                      for step in character.steps],
            "skinkit": __version__}


def read_manifest(folder: str) -> dict | None:
    try:
        with open(os.path.join(folder, MANIFEST_NAME), encoding="utf-8") as file:
            return json.load(file)
    except (OSError, ValueError):
        return None


@checked(character=Character, expected=optional(dict))
def is_current(character: Character, expected: dict | None = None) -> bool:
    """Whether the character's folder holds every output of a run on inputs with today's content hashes."""
    manifest = read_manifest(character.folder)
    if manifest is None:
        return False
    expected = expected or fingerprint(character)
    return manifest.get("fingerprint") == expected and all(
        os.path.exists(os.path.join(character.folder, name)) for name in manifest.get("outputs", []))


def step_arguments(step, input_path: str, folder: str) -> list[str]:
    arguments = [step.command, input_path]
    if step.output:
        arguments += [step.output_flag, os.path.join(folder, step.output)]
    for flag, value in step.options:
        if value is True:
            arguments.append(flag)
        elif value is not False:
            arguments += [flag, str(value)]
    return arguments + ["--json"]


def run_step(character: Character, number: int, step, input_path: str, folder: str) -> dict:
    """Runs one step in its own process; returns its JSON report, or raises StepFailed naming the step."""
    arguments = step_arguments(step, input_path, folder)
    where = f"character '{character.name}', step {number} ({step.command})"
    try:
        completed = subprocess.run([sys.executable, "-m", "skinkit.cli", *arguments], cwd=character.base or None,
                                   capture_output=True, text=True, timeout=STEP_TIMEOUT)
    except subprocess.TimeoutExpired:
        raise StepFailed(f"{where}: ran past {STEP_TIMEOUT} s") from None
    lines = [line for line in completed.stdout.splitlines() if line.startswith("{")]
    report = json.loads(lines[-1]) if lines else {}
    if completed.returncode != 0:
        reason = report.get("error") or (f"the process ended with signal {-completed.returncode}"
                                         if completed.returncode < 0 else completed.stderr.strip()[-500:])
        raise StepFailed(f"{where}: {reason}")
    return report


def run_character(character: Character) -> dict:
    """The whole pipeline of one character (a Dask task): skipped when its outputs are current; else run into a
    scratch folder that replaces the character's folder once complete. Raises on failure (Dask retries)."""
    started = time.perf_counter()
    expected = fingerprint(character)
    if is_current(character, expected):
        return {"name": character.name, "status": "skipped", "seconds": time.perf_counter() - started,
                "outputs": output_paths(character)}
    os.makedirs(character.out, exist_ok=True)
    scratch = os.path.join(character.out, f".{character.name}{PARTIAL_MARK}{uuid.uuid4().hex}")
    os.makedirs(scratch)
    try:
        scene, reports = character.input, []
        for number, step in enumerate(character.steps, 1):
            reports.append(run_step(character, number, step, step.input or scene, scratch))
            if step.output and step.output.lower().endswith(".blend"):
                scene = os.path.join(scratch, step.output)
        outputs = [step.output for step in character.steps if step.output]
        with open(os.path.join(scratch, MANIFEST_NAME), "w", encoding="utf-8") as file:
            json.dump({"fingerprint": expected, "outputs": outputs, "steps": reports}, file, indent=1, default=str)
        publish(character, scratch, expected)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return {"name": character.name, "status": "done", "seconds": time.perf_counter() - started,
            "outputs": output_paths(character)}


def publish(character: Character, scratch: str, expected: dict) -> None:
    """Renames the complete scratch folder onto the character's; a copy of this task that finished first (a worker
    presumed dead that was not) already put the same outputs there, and then this one is dropped."""
    if os.path.exists(character.folder):
        if is_current(character, expected):
            return
        retired = os.path.join(character.out, f".{character.name}.old-{uuid.uuid4().hex}")
        os.rename(character.folder, retired)
        os.rename(scratch, character.folder)
        shutil.rmtree(retired, ignore_errors=True)
    else:
        os.rename(scratch, character.folder)


def output_paths(character: Character) -> list[str]:
    manifest = read_manifest(character.folder) or {}
    return [os.path.join(character.folder, name) for name in manifest.get("outputs", [])]


def remove_scratch_folders(out: str, names) -> None:
    """Scratch folders of tasks that died with their worker (their copies that ran again finished elsewhere)."""
    if not os.path.isdir(out):
        return
    for entry in os.listdir(out):
        if any(entry.startswith(f".{name}{PARTIAL_MARK}") or entry.startswith(f".{name}.old-") for name in names):
            shutil.rmtree(os.path.join(out, entry), ignore_errors=True)
