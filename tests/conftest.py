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


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if _in_ci() and report.skipped and "shared/data" in str(report.longrepr):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        report.outcome = "failed"
        report.longrepr = f"CI=true: a shared data file this test needs is missing ({reason})"
