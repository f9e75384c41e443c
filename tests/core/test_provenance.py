"""core.provenance: the commit a result was made with, and whether the package differed from it."""

import subprocess

from forcdecode.core.provenance import source_commit


def _git(repo, *args):
    return subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                          capture_output=True, text=True, check=True).stdout.strip()


def test_a_checkout_gives_its_commit_and_marks_uncommitted_edits(tmp_path):
    package = tmp_path / "src" / "pkg"
    package.mkdir(parents=True)
    (package / "a.py").write_text("x = 1\n")
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", ".")
    _git(tmp_path, "commit", "-qm", "one")
    head = _git(tmp_path, "rev-parse", "HEAD")
    assert source_commit.__wrapped__(str(package)) == head
    (tmp_path / "elsewhere.txt").write_text("not the package\n")  # outside the package: not a modification
    assert source_commit.__wrapped__(str(package)) == head
    (package / "a.py").write_text("x = 2\n")
    assert source_commit.__wrapped__(str(package)) == head + "+modified"


def test_outside_a_checkout_the_commit_is_unknown(tmp_path):
    assert source_commit.__wrapped__(str(tmp_path)) == "unknown"
