"""Progress bars for long CLI commands: on stderr, and only when stderr is a terminal and --json is off.

main() runs every command inside one `session`; outside a terminal (or with --json) the session draws nothing, so
the calls below cost nothing there. A command opts in by naming each stage as the add-on's operator labels it and
handing `update` to the bridge's progress parameter, which takes either progress(fraction) or
progress(step, total) and never cancels:

    from .. import progress
    progress.stage("Fit from Example Poses")
    fitting.fit_object(mesh_object, examples, progress=progress.update, ...)
    progress.stage("Saving")                       # a stage without steps shows its name and its seconds
"""
from __future__ import annotations

import sys
import time
from contextlib import contextmanager

BAR_WIDTH = 30
#: Redraws at most this often (seconds): a fast loop must not spend its time on the terminal.
REDRAW_INTERVAL = 0.1


class TerminalBar:
    """One line per stage: `Stage [#######.......]  47%  3.2 s`, rewritten in place."""

    def __init__(self, stream):
        self.stream = stream
        self.name = None
        self.fraction = None
        self.started = self.drawn_at = 0.0

    def stage(self, name: str) -> None:
        self.finish_line()
        self.name, self.fraction, self.started = name, None, time.monotonic()
        self.draw()

    def update(self, done, total=None) -> bool:
        fraction = done / total if total else done
        self.fraction = min(max(float(fraction), 0.0), 1.0)
        if time.monotonic() - self.drawn_at >= REDRAW_INTERVAL or self.fraction >= 1.0:
            self.draw()
        return False

    def draw(self) -> None:
        if self.name is None:
            return
        seconds = time.monotonic() - self.started
        if self.fraction is None:
            line = f"{self.name} ... {seconds:.1f} s"
        else:
            filled = int(round(self.fraction * BAR_WIDTH))
            line = f"{self.name} [{'#' * filled}{'.' * (BAR_WIDTH - filled)}] {self.fraction:4.0%}  {seconds:.1f} s"
        self.stream.write("\r\x1b[K" + line)
        self.stream.flush()
        self.drawn_at = time.monotonic()

    def finish_line(self) -> None:
        if self.name is not None:
            self.draw()
            self.stream.write("\n")
            self.stream.flush()
            self.name = None


class Silent:
    def stage(self, name: str) -> None:
        pass

    def update(self, done, total=None) -> bool:
        return False

    def finish_line(self) -> None:
        pass


_current = Silent()


def stage(name: str) -> None:
    """Starts the stage `name` (ending the one before)."""
    _current.stage(name)


def update(done, total=None) -> bool:
    """The progress callback: update(fraction) or update(step, total). Returns False: the CLI never cancels."""
    return _current.update(done, total)


def wanted(as_json: bool, stream=None) -> bool:
    stream = stream or sys.stderr
    return not as_json and hasattr(stream, "isatty") and stream.isatty()


@contextmanager
def session(active: bool, stream=None):
    """Bars on stream (stderr) while inside when active; nothing otherwise."""
    global _current
    previous = _current
    _current = TerminalBar(stream or sys.stderr) if active else Silent()
    try:
        yield _current
    finally:
        _current.finish_line()
        _current = previous
