"""Whether a sanitized fuzz pass left any AddressSanitizer or UndefinedBehaviorSanitizer report.

`make fuzz-sanitized` points the sanitizers' log_path into one folder (ASAN_OPTIONS, UBSAN_OPTIONS); each report is
a file there named after the prefix and the reporting process's id. A report whose call did not kill its child
(UBSan's recoverable checks, a report in a library's atexit) would pass unseen by the fuzzers' crash accounting, so
the pass fails on any file here, and prints the first lines of each.

    python -m tests.fuzz.sanitizer_reports FOLDER
"""
from __future__ import annotations

import argparse
import os
import sys

#: The log_path prefixes the Makefile gives ASan and UBSan.
PREFIXES = ("asan", "ubsan")
SHOWN_LINES = 12


def reports(folder: str) -> list[str]:
    """The sanitizer report files in folder (none when it does not exist), sorted."""
    if not os.path.isdir(folder):
        return []
    return sorted(os.path.join(folder, name) for name in os.listdir(folder)
                  if name.split(".")[0] in PREFIXES and os.path.getsize(os.path.join(folder, name)) > 0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", help="the sanitizers' log_path folder")
    found = reports(parser.parse_args(argv).folder)
    for path in found:
        with open(path, errors="replace") as file:
            head = file.read().splitlines()[:SHOWN_LINES]
        print(f"--- {path}\n" + "\n".join(head))
    print(f"{len(found)} sanitizer reports")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
