"""One way for the tests to run this checkout's workflow: ``snakemake_process(workdir, *args)`` is
``python -m snakemake --snakefile <repo>/Snakefile --directory WORKDIR --cores N ARGS…`` in WORKDIR, its
jobs importing this checkout's ``src/`` (importable from any test module: pytest puts ``tests/``, the
directory of the top conftest, on ``sys.path``)."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SNAKEFILE = ROOT / "Snakefile"
CONFIG_DIR = ROOT / "config"


def checkout_env() -> dict:
    """The environment with this checkout's ``src/`` first on PYTHONPATH, output unbuffered."""
    return {**os.environ, "PYTHONUNBUFFERED": "1",
            "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), *filter(None, [os.environ.get("PYTHONPATH")])])}


def snakemake_process(workdir, *args, cores: int = 1, timeout: int = 300) -> subprocess.CompletedProcess:
    """Snakemake on the repository's Snakefile in ``workdir`` (created if missing) with ``args`` (targets,
    ``--configfile``, ``--config``, ``-n``, …; a target before ``--configfile``, or after ``--``, since
    ``--configfile`` takes every value that follows it); stdout and stderr captured as text."""
    Path(workdir).mkdir(parents=True, exist_ok=True)
    return subprocess.run([sys.executable, "-m", "snakemake", "--snakefile", str(SNAKEFILE), "--directory",
                           str(workdir), "--cores", str(cores), *map(str, args)],
                          cwd=workdir, capture_output=True, text=True, timeout=timeout, env=checkout_env())
