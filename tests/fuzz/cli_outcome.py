"""What the `skinkit` command line may do with any arguments, as the coverage-guided pass (fuzz_files.py) judges it:
exactly one JSON object on stdout and exit 0 or 1; or argparse's own answer, a usage error (exit 2) or the help
text a request for it prints (exit 0: `-h`, `--help`, or any prefix of it such as `--h`, which argparse takes as
`--help`). Anything else, a traceback included, fails an assertion."""
import contextlib
import io
import json

from skinkit.cli import main as cli_main


def check_command_line(argv: list[str]) -> None:
    stdout = io.StringIO()
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(io.StringIO()):
            status = cli_main(argv)
    except SystemExit as exit_:  # argparse refusing the arguments, or answering a request for help
        printed_help = exit_.code == 0 and stdout.getvalue().startswith("usage: skinkit")
        assert exit_.code == 2 or printed_help, (exit_.code, stdout.getvalue()[:200])
        return
    assert status in (0, 1), status
    json.loads(stdout.getvalue())
