"""Runs the characters' pipelines on Dask: a LocalCluster on this machine (one single-threaded worker process per
core asked for) or the cluster of an existing scheduler (a farm), one task per character, retried as JOBS.toml says;
a worker that dies mid-task has its task rescheduled on another by the scheduler."""
from __future__ import annotations

import sys
import time
import uuid

from .pipeline import remove_scratch_folders, run_character

#: How many times the scheduler reschedules a task whose worker died under it before giving up on it.
WORKER_DEATHS_ALLOWED = 3


def run_batch(characters, *, scheduler: str | None = None, workers: int = 2, client=None, progress=None,
              announce=None) -> dict:
    """Runs every character; returns {"characters": [per character: name, status (done, skipped, failed),
    seconds, outputs, error], "done", "skipped", "failed", "seconds", "workers", "scheduler", "dashboard",
    "status"}. progress(done, total) is called as characters finish; announce(text) gets the dashboard address."""
    import dask
    from distributed import Client, LocalCluster, as_completed

    started = time.perf_counter()
    cluster = None
    with dask.config.set({"distributed.scheduler.allowed-failures": WORKER_DEATHS_ALLOWED}):
        if client is None:
            if scheduler:
                client = Client(scheduler)
            else:
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True)
                client = Client(cluster)
            owned = True
        else:
            owned = False
        try:
            dashboard = client.dashboard_link
            if announce:
                announce(f"Dask dashboard: {dashboard}")
            batch = uuid.uuid4().hex  # a key per run: a finished run's keys may still be held by the scheduler
            futures = {client.submit(run_character, character, key=f"skinkit-batch-{character.name}-{batch}",
                                     retries=character.retries, pure=False): character for character in characters}
            results = {}
            for done, future in enumerate(as_completed(futures), 1):
                character = futures[future]
                results[character.name] = outcome(future, character)
                if progress:
                    progress(done, len(futures))
            worker_count = len(client.scheduler_info().get("workers", {}))
            address = client.scheduler.address
        finally:
            if owned:
                client.close()
                if cluster is not None:
                    cluster.close()
    for out in {character.out for character in characters}:
        remove_scratch_folders(out, [character.name for character in characters])
    ordered = [results[character.name] for character in characters]
    counts = {status: sum(r["status"] == status for r in ordered) for status in ("done", "skipped", "failed")}
    return {"characters": ordered, **counts, "seconds": time.perf_counter() - started, "workers": worker_count,
            "scheduler": address, "dashboard": dashboard, "status": "failed" if counts["failed"] else "ok"}


def outcome(future, character) -> dict:
    try:
        return future.result()
    except Exception as error:  # noqa: BLE001 - any failure of one character is reported, the others go on
        print(f"skinkit batch: character '{character.name}' failed: {error}", file=sys.stderr)
        return {"name": character.name, "status": "failed", "seconds": None, "outputs": [],
                "error": f"{type(error).__name__}: {error}" if not str(error).startswith("character") else str(error)}
