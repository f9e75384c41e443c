"""tests/conftest.py under CI: missing shared data fails the run instead of skipping the tests."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

CONFTEST = Path(__file__).resolve().parents[1] / "conftest.py"
NEEDS_DATA = '''
from pathlib import Path
import pytest
DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "measured" / "file.frc"
def test_reads_a_shared_file():
    if not DATA.exists():
        pytest.skip(f"{DATA} is absent")
    assert DATA.read_text() == "data"
'''


def run_pytest(repo: Path, ci: str | None):
    env = {k: v for k, v in os.environ.items() if k != "CI"} | {"PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1"}
    if ci is not None:
        env["CI"] = ci
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests"], cwd=repo,
                          env=env, capture_output=True, text=True, timeout=120)


@pytest.fixture
def repo(tmp_path):
    """A checkout (tmp/work/repo) with the project's conftest and one test that needs ../shared/data."""
    repo = tmp_path / "work" / "repo"
    (repo / "tests").mkdir(parents=True)
    shutil.copy(CONFTEST, repo / "tests" / "conftest.py")
    (repo / "tests" / "test_needs_data.py").write_text(NEEDS_DATA)
    return repo


def test_without_ci_a_missing_data_folder_skips(repo):
    run = run_pytest(repo, None)
    assert run.returncode == 0 and "1 skipped" in run.stdout, run.stdout


def test_under_ci_a_missing_data_folder_fails_loudly(repo):
    run = run_pytest(repo, "true")
    assert run.returncode == 1 and "shared measured files are missing" in run.stdout + run.stderr, run.stdout


def test_under_ci_a_missing_file_fails_instead_of_skipping(repo):
    measured = repo.parent / "shared" / "data" / "measured"
    measured.mkdir(parents=True)
    (measured / "README.md").write_text("other files only")
    run = run_pytest(repo, "true")
    assert run.returncode == 1 and "1 failed" in run.stdout and "shared data file" in run.stdout, run.stdout
    (measured / "file.frc").write_text("data")
    assert run_pytest(repo, "true").returncode == 0
