"""Which source produced a result: the git commit of the running forcdecode package."""

from __future__ import annotations

import subprocess
from functools import lru_cache
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parents[1]


@lru_cache(maxsize=None)
def source_commit(package_dir: str = str(PACKAGE_DIR)) -> str:
    """The commit (40 hex digits) of the git checkout that holds ``package_dir``, with ``+modified``
    appended where the package's files differ from it (uncommitted edits); ``unknown`` outside a git
    checkout (an installed wheel). Read once per process: a long run records the code it started with."""
    def git(*args):
        return subprocess.run(["git", "-C", package_dir, *args], capture_output=True, text=True, timeout=30)

    try:
        head = git("rev-parse", "HEAD")
        if head.returncode != 0:
            return "unknown"
        modified = git("diff", "--quiet", "HEAD", "--", ".").returncode != 0
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head.stdout.strip() + ("+modified" if modified else "")
