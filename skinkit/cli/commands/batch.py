"""skinkit batch: a library of characters through their pipelines (JOBS.toml) on Dask, on this machine or a farm."""
import os
import sys

from ...model import SkinkitError
from .. import progress

HELP = "run the pipelines of JOBS.toml's characters on Dask (a local cluster or a farm's scheduler)"
STAGE = "Batch"


def add_parser(subparsers, common):
    parser = subparsers.add_parser(
        "batch", help=HELP, parents=[common["json"]],
        description="Run each character of JOBS.toml through its steps (skinkit commands, each in its own process) on "
                    "Dask: a LocalCluster of --workers processes by default, or the cluster of --scheduler. Failed "
                    "characters are retried (retries in JOBS.toml) and reported; outputs appear only complete; a "
                    "re-run skips characters whose inputs' content hashes are unchanged (manifest.json).")
    parser.add_argument("jobs", metavar="JOBS.toml")
    parser.add_argument("--scheduler", help="an existing scheduler, e.g. tcp://HOST:8786 (default: a local cluster)")
    parser.add_argument("--workers", type=int, default=max(1, min(4, len(os.sched_getaffinity(0)))),
                        help="worker processes of the local cluster (default: the cores, at most 4)")
    return parser


def run(arguments) -> dict:
    from ...batch import load_jobs, run_batch

    if arguments.workers < 1:
        raise SkinkitError(f"--workers must be at least 1 (got {arguments.workers})")
    characters = load_jobs(arguments.jobs)
    return run_batch(characters, scheduler=arguments.scheduler, workers=arguments.workers, progress=progress.update,
                     announce=lambda text: print(text, file=sys.stderr))
