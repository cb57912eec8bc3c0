"""Where the trials of ``reproduce`` run: joblib's processes on this machine, or a Dask
cluster (:func:`backend`), with a progress bar (:func:`run_parallel`)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

from joblib import Parallel, delayed, parallel_config

__all__ = ["backend", "run_parallel"]


@contextlib.contextmanager
def backend(address: str | None) -> Iterator[None]:
    """joblib's default processes, or the Dask cluster at ``address``."""
    if address is None:
        yield
        return
    try:
        from dask.distributed import Client
    except ImportError:  # pragma: no cover - the test extra installs it
        raise ValueError(
            "--dask needs dask.distributed: pip install '.[dask]' in piezocomp's folder."
        ) from None
    try:
        client = Client(address, timeout=10)
    except OSError as exc:
        raise ValueError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
    with client, parallel_config(backend="dask"):
        yield


def _indexed(index: int, func: Any, args: Any, kwargs: Any) -> tuple[int, Any]:
    return index, func(*args, **kwargs)


def run_parallel(workers: int | None, tasks: list[Any], desc: str, progress: bool) -> list[Any]:
    """Run joblib ``delayed`` tasks on ``workers`` processes (``None``: every core), with a
    progress bar that counts them as they finish; the results in the order of ``tasks``
    whatever order they finished in, so that a run sums its figures in one order and gives
    them to the last bit again."""
    from tqdm.auto import tqdm

    n_jobs = -1 if workers is None else workers
    par = Parallel(n_jobs=n_jobs, return_as="generator_unordered")
    indexed = [delayed(_indexed)(i, *task) for i, task in enumerate(tasks)]
    out: list[Any] = [None] * len(tasks)
    for i, r in tqdm(par(indexed), total=len(tasks), desc=desc, disable=not progress, leave=False):
        out[i] = r
    return out
