"""What the benchmarks share: machine facts for their reports, and writing their results."""
from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np

import skinkit


def machine_info() -> dict:
    cpu = "unknown"
    try:
        with open("/proc/cpuinfo") as stream:
            cpu = next((line.split(":", 1)[1].strip() for line in stream if line.startswith("model name")), cpu)
    except OSError:
        pass
    return {"machine": platform.machine(), "cpu": cpu, "cores": os.cpu_count(),
            "usable_cores": len(os.sched_getaffinity(0)),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "command": " ".join(sys.argv), "python": platform.python_version(),
            "bpy": blender_version(), "numpy": np.__version__, "skinkit": skinkit.__version__}


def blender_version() -> str:
    """Blender's version where the benchmark uses it; benchmarks without Blender report "not used"."""
    if "bpy" not in sys.modules:
        return "not used"
    return sys.modules["bpy"].app.version_string


def parallel_speedup() -> float:
    """How much faster two CPU-bound processes finish together than one after the other: 2.0 on two real
    cores, 1.0 when the 'cores' share one CPU's time. Explains how much threads can help here."""
    code = "x = 0\nfor i in range(10_000_000):\n    x += i"

    def wall(count: int) -> float:
        started = time.perf_counter()
        for process in [subprocess.Popen([sys.executable, "-S", "-c", code]) for _ in range(count)]:
            process.wait()
        return time.perf_counter() - started

    wall(1)
    return 2 * wall(1) / wall(2)


def machine_line(info: dict) -> str:
    """The start of a report's machine line: date, machine, CPU and how well its cores ran two processes side by
    side before and after the run; each report closes the parenthesis with what it adds."""
    return (f"{info['date']} · {info['machine']} · {info['cpu']} · {info['cores']} cores (two CPU-bound processes "
            f"ran {info['parallel_speedup_before']:.2f}x as fast as one before the run, "
            f"{info['parallel_speedup_after']:.2f}x after")


def write_outputs(results: dict, json_path: str | None, markdown_path: str | None, markdown_report) -> None:
    """The results as JSON and as the Markdown report markdown_report(results) builds, where asked."""
    if json_path:
        with open(json_path, "w") as stream:
            json.dump(results, stream, indent=1)
    if markdown_path:
        with open(markdown_path, "w") as stream:
            stream.write(markdown_report(results))


def finish_run(results: dict, arguments, markdown_report, speedup_before: float) -> int:
    """A benchmark's last steps: the machine with the parallel speed-up before and after the run (how loaded it
    was), the outputs asked for (--json, --markdown), and the report printed when neither was asked for."""
    results["machine"] = machine_info() | {"parallel_speedup_before": speedup_before,
                                           "parallel_speedup_after": parallel_speedup()}
    write_outputs(results, arguments.json, arguments.markdown, markdown_report)
    if not arguments.json and not arguments.markdown:
        print(markdown_report(results))
    return 0


