"""Independent simulations on several cores, with the same outcome as on one.

The closed loop simulates dozens of independent FORC families of one Hamiltonian (the re-simulation's
disorder profiles, the patch pool's single realisations, the physics-side candidates). Each draws its
disorder from its own named stream (``core.streams``), so the families do not depend on which process
makes them or in what order. ``using_workers(n)`` opens a pool of ``n`` spawned processes for a block
of code; inside it ``map_in_order(fn, items)`` runs ``fn(item)`` on that pool and returns the results
in ``items``' order, so every sum a caller folds over them is made in the same order as with one
process, bit for bit (``tests/core/test_parallel.py``). Outside such a block, or with ``n`` = 1, it
is a plain loop in this process.

Workers are spawned (not forked: numba and FFT threads do not survive a fork), run one numba thread
each, and load the compiled kernels from numba's on-disk cache; ``fn`` must be a module-level function
and its arguments picklable. A spawned worker imports the calling program's main module again, so a
script that opens a pool (``close_loop_on_file(..., workers=2)``) needs the ``if __name__ ==
"__main__":`` guard; the ``forcdecode`` command, pytest and Snakemake's rules (which call the command)
have it.

    with using_workers(2):
        families = map_in_order(simulate_one, [(cfg, params, k) for k in range(16)])
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager

from .._runtime import limit_blas_threads, tune_allocator

_ACTIVE: list[ProcessPoolExecutor | None] = [None]
_WORKERS: list[int] = [1]


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the platform tells it, else the count)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not Linux
        return max(os.cpu_count() or 1, 1)


def _init_worker() -> None:
    """One numba thread per worker process and the command line's allocator tuning."""
    import numba  # a worker's own numba (heavy, and only the workers need its thread setting here)

    tune_allocator()
    limit_blas_threads()
    numba.set_num_threads(1)


@contextmanager
def using_workers(workers: int):
    """A pool of ``workers`` spawned processes for ``map_in_order`` inside the block (1: none, everything
    runs in this process). Nested blocks keep the outer pool. ValueError for ``workers`` < 1."""
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, not {workers}")
    if _ACTIVE[0] is not None or int(workers) == 1:
        yield
        return
    pool = ProcessPoolExecutor(max_workers=int(workers), mp_context=multiprocessing.get_context("spawn"),
                               initializer=_init_worker)
    _ACTIVE[0], _WORKERS[0] = pool, int(workers)
    try:
        yield
    finally:
        _ACTIVE[0], _WORKERS[0] = None, 1
        pool.shutdown(wait=True, cancel_futures=True)


def active_workers() -> int:
    """Processes ``map_in_order`` uses now (1 outside a ``using_workers`` block)."""
    return _WORKERS[0]


def map_in_order(fn: Callable, items: Iterable[tuple], progress: Callable[[int, int], None] | None = None) -> list:
    """``[fn(*item) for item in items]``, on the active pool when there is one; results in ``items``' order.
    ``progress(done, total)`` after each result. An exception in ``fn`` is raised here (the first one
    in ``items``' order among those that failed)."""
    items = list(items)
    pool = _ACTIVE[0]
    if pool is None or len(items) <= 1:
        results = []
        for k, item in enumerate(items):
            results.append(fn(*item))
            if progress is not None:
                progress(k + 1, len(items))
        return results
    futures = {pool.submit(fn, *item): k for k, item in enumerate(items)}
    results: list = [None] * len(items)
    errors: dict[int, BaseException] = {}
    for done, future in enumerate(as_completed(futures), start=1):
        k = futures[future]
        try:
            results[k] = future.result()
        except Exception as error:  # raised below, in the items' order
            errors[k] = error
        if progress is not None:
            progress(done, len(items))
    if errors:
        raise errors[min(errors)]
    return results
