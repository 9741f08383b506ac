"""Batch processing of a library of characters on Dask (`skinkit batch JOBS.toml`): a pipeline of skinkit commands
per character, each step in a process of its own, retried when it fails, its outputs made visible only once the
whole pipeline is complete, and skipped on a re-run while its inputs' content hashes are unchanged.

    from skinkit.batch import load_jobs, run_batch
    results = run_batch(load_jobs("jobs.toml"), workers=2)
"""
from .jobs import Character, Step, load_jobs
from .pipeline import MANIFEST_NAME, is_current, run_character
from .runner import run_batch

__all__ = ["Character", "Step", "load_jobs", "run_character", "is_current", "run_batch", "MANIFEST_NAME"]
