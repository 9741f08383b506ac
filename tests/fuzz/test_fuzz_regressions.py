"""What the long fuzz pass found (issue 16's `make fuzz` over the families merged last): each finding's call,
made again, now answers with an error instead of a crash or a raw exception. A call that crashed runs in a child
process, so that a regression fails this test instead of killing the test run."""
import pickle
import subprocess
import sys

import pytest

from tests.fuzz import binding_fuzz

import skinkit
from skinkit.batch import load_jobs


def call_in_child(function_name: str, arguments: dict) -> tuple[int, str, str]:
    """Calls _core.<function_name>(**arguments) in a fresh interpreter: its exit status, and its stdout (what the
    call raised) and stderr as text."""
    code = ("import pickle, sys\nfrom skinkit import _core\n"
            "arguments = pickle.loads(sys.stdin.buffer.read())\n"
            f"try:\n    _core.{function_name}(**arguments)\n    print('returned')\n"
            "except Exception as error:\n    print(type(error).__name__, error)\n")
    finished = subprocess.run([sys.executable, "-c", code], input=pickle.dumps(arguments), capture_output=True,
                              cwd=binding_fuzz.ROOT, timeout=120)
    return finished.returncode, finished.stdout.decode(errors="replace"), finished.stderr.decode(errors="replace")


def test_simplify_with_uv_out_but_no_uv_is_refused():
    """Seed 1, call 1179: simplify copied the output UVs from a NULL uv (a segfault)."""
    arguments = binding_fuzz.generate("simplify", 1, 1179)
    arguments["uv"] = None
    assert arguments["uv_out"] is not None
    status, out, err = call_in_child("simplify", arguments)
    assert status == 0, f"the call killed the process (status {status}): {err[-400:]!r}"
    assert out.startswith("Error uv_out is given but uv is null"), out


def test_a_binary_jobs_file_is_a_skinkit_error(tmp_path):
    """batch.load_jobs raised a raw UnicodeDecodeError on a file that is not UTF-8."""
    path = tmp_path / "JOBS.toml"
    path.write_bytes(b"out = 'x'\n" + bytes(range(128, 256)))
    with pytest.raises(skinkit.SkinkitError, match="not a UTF-8 text file"):
        load_jobs(str(path))
