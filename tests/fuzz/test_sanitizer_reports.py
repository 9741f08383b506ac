"""make fuzz-sanitized fails on a sanitizer report: the checker notices one planted in its folder, and a real one
written by a sanitized program (built here with gcc's -fsanitize=address, when gcc can)."""
import os
import shutil
import subprocess
import sys

import pytest

from tests.fuzz import sanitizer_reports

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def check(folder) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tests.fuzz.sanitizer_reports", str(folder)], cwd=ROOT,
                          capture_output=True, text=True)


def test_no_report_passes(tmp_path):
    (tmp_path / "unrelated.log").write_text("not a sanitizer report")
    result = check(tmp_path)
    assert result.returncode == 0 and "0 sanitizer reports" in result.stdout
    assert check(tmp_path / "missing").returncode == 0


def test_a_planted_report_fails_and_is_shown(tmp_path):
    (tmp_path / "ubsan.12345").write_text("csrc/common/sk_mesh.c:10:5: runtime error: signed integer overflow\n")
    result = check(tmp_path)
    assert result.returncode == 1
    assert "1 sanitizer reports" in result.stdout and "signed integer overflow" in result.stdout


@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc to build a sanitized program")
def test_a_real_heap_overflow_report_is_caught(tmp_path):
    """The same ASAN_OPTIONS log_path as the Makefile's: a heap overflow's report lands where the checker looks."""
    source = tmp_path / "overflow.c"
    source.write_text("#include <stdlib.h>\nint main(void) { volatile char *p = malloc(4); p[4] = 1;"
                      " free((void *)p); return 0; }\n")
    program = tmp_path / "overflow"
    built = subprocess.run(["gcc", "-fsanitize=address", "-g", str(source), "-o", str(program)],
                           capture_output=True)
    if built.returncode != 0:
        pytest.skip("gcc cannot build with AddressSanitizer here")
    reports = tmp_path / "reports"
    reports.mkdir()
    env = dict(os.environ, ASAN_OPTIONS=f"detect_leaks=0:log_path={reports}/asan")
    assert subprocess.run([str(program)], env=env, capture_output=True).returncode != 0
    assert sanitizer_reports.reports(str(reports))
    result = check(reports)
    assert result.returncode == 1 and "heap-buffer-overflow" in result.stdout
