"""Session-wide test settings.

- numba and OpenBLAS run single-threaded unless the caller says otherwise (the tests' numbers do not depend
  on it).
- The longest modules are collected first, so that with `make test`'s two processes (pytest-xdist,
  ``--dist loadfile --no-loadscope-reorder``: a module runs whole on one process, in collection order)
  they do not start last and leave one core idle at the end.
- Under CI (``CI=true``), the real measured files in ``../shared/data`` are required: their absence
  stops the run at once, and any test that would skip because a shared file is missing fails
  instead, so that a green CI run has really read them. Elsewhere those tests skip.
"""

import os
from pathlib import Path

import pytest

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
# OpenBLAS threads too (before numpy is imported): two test processes on two cores, each with a BLAS thread
# pool of two, spin against each other on the loop's many small matrix products
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# measured 2026-11-30 (`pytest --durations`, beside a two-process bench): in the default run the tiny main
# job ~11 min and the four magnum.np comparisons ~6.5 min; among the slow tests the effects bench's two
# end-to-end cases 14 and 8 min. The Slurm test (CI only: FORCDECODE_SLURM_TEST=1) runs the same tiny
# main job through Slurm, so it goes first: collected as it was, alphabetically near the end, it started
# among the last and could run alone on one core at the end (CI keeps no log of a passing run to show it)
LONGEST_MODULES_FIRST = ("workflow/test_slurm.py", "workflow/test_workflow.py", "reference/test_independent.py",
                         "bench/test_effects_independent.py", "bench/test_effects_cases.py",
                         "bench/test_effects_user.py")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in {"true", "1", "yes"}


def pytest_sessionstart(session):
    measured = SHARED_DATA / "measured"
    if _in_ci() and not (measured.is_dir() and any(measured.iterdir())):
        pytest.exit(f"CI=true but the shared measured files are missing: {measured} is absent or empty "
                    f"(the measured-file tests would skip; CI must run them)", returncode=pytest.ExitCode.TESTS_FAILED)


def pytest_collection_modifyitems(config, items):
    """Stable reorder: the modules of LONGEST_MODULES_FIRST first, in that order, the rest as collected."""
    def rank(item) -> int:
        path = item.nodeid.split("::", 1)[0]
        return next((i for i, name in enumerate(LONGEST_MODULES_FIRST) if path.endswith(name)),
                    len(LONGEST_MODULES_FIRST))
    items.sort(key=rank)


@pytest.fixture
def evaluate_slurm_resource():
    """`evaluate(text, config_path)`: a string resource of profiles/slurm evaluated the way Snakemake
    evaluates a `--set-resources` / profile string per job, on the job's `input` built the way Snakemake
    builds simulate_family's: `config` a list-valued named input (it is `rules.resolve_config.output`),
    then `params` and `screen`."""
    import asyncio

    from snakemake.iocontainers import InputFiles
    from snakemake.resources import Resource

    def evaluate(text: str, config_path):
        job_input = InputFiles([str(config_path), "params.parquet", "screen.parquet"])
        job_input._set_name("config", 0, end=1)
        job_input._set_name("params", 1)
        job_input._set_name("screen", 2)
        return Resource.cli_evaluator("resource", text, wildcards=None, input=job_input, attempt=1, threads=1,
                                      async_run=asyncio.run)

    return evaluate


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if _in_ci() and report.skipped and "shared/data" in str(report.longrepr):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        report.outcome = "failed"
        report.longrepr = f"CI=true: a shared data file this test needs is missing ({reason})"
