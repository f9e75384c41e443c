"""Every relative link of the front door (README.md, config/README.md) and of docs/ reaches a file, and
every #anchor a heading of that file (GitHub's heading ids: lower case, spaces to hyphens, punctuation
dropped, a repeated heading numbered -1, -2, …)."""

import re
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", ROOT / "config" / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
CODE_BLOCK = re.compile(r"```.*?```", re.S)
LINK = re.compile(r"\]\(([^)\s]+)\)")


def heading_id(text: str) -> str:
    """GitHub's id of a Markdown heading."""
    kept = []
    for ch in text.strip().lower():
        if ch == " ":
            kept.append("-")
        elif ch in "-_" or unicodedata.category(ch)[0] in "LN":
            kept.append(ch)
    return "".join(kept)


def heading_ids(page: Path) -> set[str]:
    ids, seen = set(), {}
    for line in CODE_BLOCK.sub("", page.read_text()).splitlines():
        match = re.match(r"^#{1,6}\s+(.*)$", line)
        if match:
            base = heading_id(match.group(1))
            n = seen.get(base, 0)
            ids.add(base if n == 0 else f"{base}-{n}")
            seen[base] = n + 1
    return ids


def broken_links(page: Path) -> list[str]:
    broken = []
    for link in LINK.findall(CODE_BLOCK.sub("", page.read_text())):
        if re.match(r"[a-z][a-z+.-]*:", link):  # http:, https:, mailto:
            continue
        target, _, anchor = link.partition("#")
        path = (page.parent / target).resolve() if target else page
        if not path.exists():
            broken.append(f"{link} (no such file)")
        elif anchor and path.suffix == ".md" and anchor not in heading_ids(path):
            broken.append(f"{link} (no such heading in {path.name})")
    return broken


def test_heading_ids_follow_githubs_rule():
    assert heading_id("Where the information is: a Fisher map (2026-11-28)") == \
        "where-the-information-is-a-fisher-map-2026-11-28"
    assert heading_id("The sealed set: figures nobody tuned on (since 2026-11-28)") == \
        "the-sealed-set-figures-nobody-tuned-on-since-2026-11-28"


def test_a_broken_link_is_found(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Top\n[ok](#top) [gone](nowhere.md) [bad anchor](#bottom)\n```\n[in code](skipped.md)\n```\n")
    assert broken_links(page) == ["nowhere.md (no such file)", "#bottom (no such heading in page.md)"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    assert broken_links(page) == []
