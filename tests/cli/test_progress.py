"""Progress bars of long commands: drawn on a terminal's stderr with the operators' stage names, never with --json
or off a terminal (skinkit/cli/progress.py)."""
import io
import os
import pty
import subprocess
import sys

from skinkit.cli import progress
from tests.conftest import ROOT, sample_path


class FakeTerminal(io.StringIO):
    def isatty(self):
        return True


def test_a_bar_shows_the_stage_its_fraction_and_steps(monkeypatch):
    monkeypatch.setattr(progress, "REDRAW_INTERVAL", 0.0)  # every update drawn
    terminal = FakeTerminal()
    with progress.session(True, terminal):
        progress.stage("Fit from Example Poses")
        assert progress.update(0.5) is False  # never cancels
        progress.update(3, 3)
        progress.stage("Saving")
    text = terminal.getvalue()
    assert "Fit from Example Poses [" + "#" * 15 + "." * 15 + "]" in text
    assert "#" * progress.BAR_WIDTH + "] 100%" in text
    assert "Saving ..." in text and text.endswith("\n")


def test_no_bar_with_json_or_off_a_terminal():
    assert not progress.wanted(True, FakeTerminal())
    assert not progress.wanted(False, io.StringIO())
    assert progress.wanted(False, FakeTerminal())
    quiet = io.StringIO()
    with progress.session(False, quiet):
        progress.stage("Bake")
        progress.update(1, 2)
    assert quiet.getvalue() == ""


def run_on_a_terminal(*arguments) -> tuple[int, str, str]:
    """Runs the CLI with stderr on a pseudo-terminal; returns (status, stdout, what the terminal showed)."""
    controller, terminal = pty.openpty()
    process = subprocess.Popen([sys.executable, "-m", "skinkit.cli", *arguments], cwd=ROOT, stdout=subprocess.PIPE,
                               stderr=terminal, text=True)
    os.close(terminal)
    shown = b""
    while True:
        try:
            chunk = os.read(controller, 65536)
        except OSError:  # the terminal closed: the process has exited
            break
        if not chunk:
            break
        shown += chunk
    stdout = process.stdout.read()
    status = process.wait(timeout=300)
    os.close(controller)
    return status, stdout, shown.decode(errors="replace")


def test_bake_draws_its_bar_on_a_terminal_and_none_with_json(tmp_path):
    converted = str(tmp_path / "arm.blend")
    status, _, _ = run_on_a_terminal("convert", sample_path("arm"), "--out", converted)
    assert status == 0
    status, _, shown = run_on_a_terminal("bake", converted, "--frames", "1:6", "--pc2", str(tmp_path / "a.pc2"))
    assert status == 0
    assert "Bake [" + "#" * progress.BAR_WIDTH + "] 100%" in shown
    status, stdout, shown = run_on_a_terminal("bake", converted, "--frames", "1:6", "--pc2", str(tmp_path / "b.pc2"),
                                              "--json")
    assert status == 0 and stdout.count("{") >= 1
    assert "Bake [" not in shown
