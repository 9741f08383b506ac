"""`make test-blender-matrix`: the Blender-facing tests under every Blender the manifest promises (4.2 on).

    python tests/matrix/blender_matrix.py [--versions 4.2.23 5.0.1] [--tests PATH ...] [-- PYTEST_ARGUMENTS]

For each bpy release in BLENDER_RELEASES (the newest of its series with a cp311 wheel) a virtual environment
.venv-bpy-SERIES-HASH is made from requirements-dev.txt with that bpy pinned instead; HASH is the hash of those
requirements, so an environment is made once and reused until the requirements change (CI caches them). The
tree's skinkit (built in place by `make build`, an abi3 extension) is put on PYTHONPATH, and pytest runs every
test under TEST_DIRECTORIES, whatever tests they hold today: the extension zip's install, the operators, the CLI,
and the batch smoke (SMOKE_TESTS).
"""
from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
#: The newest bpy of each supported Blender series that ships a cp311 wheel (checked with `pip index versions bpy`),
#: but the one requirements-dev.txt pins (4.5.15): `make test` already runs the whole suite under it, so the matrix
#: does not run its Blender-facing part a second time (that keeps CI under 20 minutes).
BLENDER_RELEASES = ("4.2.23", "5.0.1")
#: The Blender-facing tests, by directory, so tests added there later run under every Blender too.
TEST_DIRECTORIES = ("tests/blender", "tests/cli")
#: tests/batch takes about 3 min per release, too long for CI's 20 minutes; its smoke (one sample and one bad input
#: on a 2-worker LocalCluster, each step a `skinkit` process under the release's bpy) takes about 35 s.
SMOKE_TESTS = ("tests/matrix/batch_smoke.py",)
PIN = re.compile(r"^bpy==.*$", re.MULTILINE)


def requirements_for(release: str) -> str:
    """requirements-dev.txt with bpy pinned to release."""
    with open(os.path.join(ROOT, "requirements-dev.txt"), encoding="utf-8") as file:
        pinned = file.read()
    if not PIN.search(pinned):
        raise SystemExit("requirements-dev.txt pins no bpy==... line to replace")
    return PIN.sub(f"bpy=={release}", pinned)


def environment_path(release: str, requirements: str) -> str:
    series = ".".join(release.split(".")[:2])
    digest = hashlib.sha256(requirements.encode()).hexdigest()[:12]
    return os.path.join(ROOT, f".venv-bpy-{series}-{digest}")


def ensure_environment(release: str) -> str:
    """The cached environment's python for release, made (into a scratch folder, then renamed) when missing."""
    requirements = requirements_for(release)
    path = environment_path(release, requirements)
    python = os.path.join(path, "bin", "python")
    if os.path.exists(python):
        return python
    series_prefix = path.rsplit("-", 1)[0] + "-"
    for stale in os.listdir(ROOT):  # an older environment of the same series: its requirements changed
        if os.path.join(ROOT, stale).startswith(series_prefix):
            shutil.rmtree(os.path.join(ROOT, stale))
    scratch = path + ".partial"
    shutil.rmtree(scratch, ignore_errors=True)
    subprocess.run([sys.executable, "-m", "venv", scratch], check=True)
    requirements_file = os.path.join(scratch, "requirements.txt")
    with open(requirements_file, "w", encoding="utf-8") as file:
        file.write(requirements)
    pip = [os.path.join(scratch, "bin", "python"), "-m", "pip", "install", "-q"]
    subprocess.run([*pip, "--upgrade", "pip"], check=True)
    subprocess.run([*pip, "-r", requirements_file], check=True)
    # A venv's scripts name their own folder; made in scratch, it is renamed, so fix the shebangs' paths.
    os.rename(scratch, path)
    for name in os.listdir(os.path.join(path, "bin")):
        script = os.path.join(path, "bin", name)
        if os.path.isfile(script) and not os.path.islink(script):
            with open(script, "rb") as file:
                text = file.read()
            if text.startswith(b"#!") and scratch.encode() in text:
                with open(script, "wb") as file:
                    file.write(text.replace(scratch.encode(), path.encode()))
    return python


def run_tests(release: str, python: str, paths: list[str], extra: list[str]) -> tuple[int, float]:
    environment = dict(os.environ, PYTHONPATH=ROOT)
    directories = [d for d in paths if os.path.exists(os.path.join(ROOT, d.split("::")[0]))]
    started = time.perf_counter()
    print(f"== bpy {release}: pytest {' '.join(directories)}", flush=True)
    runner = os.path.join(ROOT, "tests", "matrix", "run_pytest.py")
    completed = subprocess.run([python, runner, "-q", "-p", "no:cacheprovider", *directories, *extra],
                               cwd=ROOT, env=environment)
    return completed.returncode, time.perf_counter() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--versions", nargs="+", default=list(BLENDER_RELEASES), help="bpy releases to test")
    parser.add_argument("--tests", nargs="+", default=[*TEST_DIRECTORIES, *SMOKE_TESTS],
                        help="test paths (default: the Blender-facing directories and the batch smoke)")
    parser.add_argument("pytest_arguments", nargs="*", help="passed to pytest (after --)")
    arguments = parser.parse_args()
    outcomes = []
    for release in arguments.versions:
        started = time.perf_counter()
        python = ensure_environment(release)
        made = time.perf_counter() - started
        status, seconds = run_tests(release, python, arguments.tests, arguments.pytest_arguments)
        outcomes.append((release, status, made, seconds))
    print("== Blender matrix")
    for release, status, made, seconds in outcomes:
        verdict = "passed" if status == 0 else f"FAILED (pytest exit {status})"
        print(f"bpy {release}: {verdict}; environment {made:.0f} s, tests {seconds:.0f} s")
    return 0 if all(status == 0 for _, status, _, _ in outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
