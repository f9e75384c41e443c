"""Session-wide test settings.

- numba runs single-threaded unless the caller says otherwise (the tests' numbers do not depend on it).
- Under CI (``CI=true``), the real measured files in ``../shared/data`` are required: their absence
  stops the run at once, and any test that would skip because a shared file is missing fails
  instead, so that a green CI run has really read them. Elsewhere those tests skip.
"""

import os
from pathlib import Path

import pytest

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in {"true", "1", "yes"}


def pytest_sessionstart(session):
    measured = SHARED_DATA / "measured"
    if _in_ci() and not (measured.is_dir() and any(measured.iterdir())):
        pytest.exit(f"CI=true but the shared measured files are missing: {measured} is absent or empty "
                    f"(the measured-file tests would skip; CI must run them)", returncode=pytest.ExitCode.TESTS_FAILED)


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
