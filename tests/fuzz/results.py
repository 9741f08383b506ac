"""The fuzz passes' results file: per harness ("binding", "api") and entry point, the calls made so far of one
seed (calls 0 .. calls-1), how many were refused, the raw (non-SkinkitError) exceptions by kind, the crashes,
hangs and library complaints (their reproducers' names) and the children's CPU seconds. A pass started with
--results FILE --resume goes on from each entry point's recorded calls, so a long pass can be made in pieces on a
shared machine, and the file says what has been reached."""
from __future__ import annotations

import datetime
import json
import os

FIELDS = ("calls", "refused", "raw", "crashes", "hangs", "complaints", "cpu_seconds")


def load(path: str) -> dict:
    if path and os.path.exists(path):
        with open(path) as file:
            return json.load(file)
    return {"harnesses": {}, "runs": []}


def recorded(results: dict, harness: str, entry: str, seed: int) -> dict | None:
    record = results["harnesses"].get(harness, {}).get(entry)
    return record if record and record["seed"] == seed else None


def add(results: dict, harness: str, entry: str, seed: int, calls: int, refused: int = 0, raw_kinds=None,
        crashes=(), hangs=(), complaints=(), cpu_seconds: float = 0.0) -> dict:
    """Adds one piece of a pass (calls made after those recorded) to the entry point's record."""
    record = recorded(results, harness, entry, seed) or {"seed": seed, "calls": 0, "refused": 0, "raw": 0,
                                                         "raw_kinds": {}, "crashes": [], "hangs": [],
                                                         "complaints": [], "cpu_seconds": 0.0}
    record["calls"] += calls
    record["refused"] += refused
    for kind, count in (raw_kinds or {}).items():
        record["raw_kinds"][kind] = record["raw_kinds"].get(kind, 0) + count
        record["raw"] += count
    record["crashes"] += [os.path.basename(p) for p in crashes]
    record["hangs"] += [os.path.basename(p) for p in hangs]
    record["complaints"] += [os.path.basename(p) for p in complaints]
    record["cpu_seconds"] = round(record["cpu_seconds"] + cpu_seconds, 2)
    results["harnesses"].setdefault(harness, {})[entry] = record
    return record


def start_run(results: dict, harness: str, command: str) -> dict:
    """The record of this invocation in results["runs"]; save() stamps it each time."""
    run = {"harness": harness, "command": command}
    results["runs"].append(run)
    return run


def save(path: str, results: dict, run: dict) -> None:
    run["finished"] = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    run["load_average"] = [round(x, 1) for x in os.getloadavg()]
    results["harnesses"] = {h: dict(sorted(entries.items())) for h, entries in sorted(results["harnesses"].items())}
    temporary = path + ".tmp"
    with open(temporary, "w") as file:
        json.dump(results, file, indent=1)
        file.write("\n")
    os.replace(temporary, path)


def failing(results: dict, harness: str, entries) -> list[str]:
    """The entry points whose record (every piece so far) has a crash, a hang, a complaint or a raw exception."""
    records = results["harnesses"].get(harness, {})
    return [e for e in entries if e in records and
            (records[e]["crashes"] or records[e]["hangs"] or records[e]["complaints"] or records[e]["raw"])]


def markdown(results: dict) -> str:
    """A table per harness: one row per entry point."""
    lines = []
    for harness, entries in results["harnesses"].items():
        lines += [f"## {harness}", "", "| entry point | calls | refused | raw | crashes | hangs | complaints | CPU s |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for entry, r in entries.items():
            kinds = ", ".join(f"{k} {v}" for k, v in sorted(r["raw_kinds"].items()))
            raw = f"{r['raw']} ({kinds})" if kinds else "0"
            lines.append(f"| {entry} | {r['calls']:,} | {r['refused']:,} | {raw} "
                         f"| {len(r['crashes'])} | {len(r['hangs'])} | {len(r['complaints'])} | {r['cpu_seconds']} |")
        total = sum(r["calls"] for r in entries.values())
        short = sum(r["calls"] < 100000 for r in entries.values())
        lines += ["", f"{len(entries)} entry points, {total:,} calls; {short} below 100,000 calls.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    import sys

    print(markdown(load(sys.argv[1])))
