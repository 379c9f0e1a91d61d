"""README.md and docs/: every relative link reaches a file (and its #anchor a heading), and
the README stays a short front page (issue 26: at most 250 lines; the rest by task in docs/)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


def _headings(path: Path) -> set[str]:
    """GitHub's anchors of a Markdown file's headings (outside fenced code)."""
    out, fenced = set(), False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("#"):
            text = line.lstrip("#").strip().lower()
            out.add(re.sub(r"[^\w\- ]", "", text).replace(" ", "-"))
    return out


@pytest.mark.parametrize("doc", DOCS, ids=[str(p.relative_to(REPO)) for p in DOCS])
def test_every_relative_link_reaches_its_file_and_heading(doc):
    for target, anchor in re.findall(r"\]\(([^)#\s]*)(#[^)\s]*)?\)", doc.read_text(encoding="utf-8")):
        if target.startswith(("http://", "https://", "mailto:")):
            continue
        path = (doc.parent / target) if target else doc
        assert path.exists(), f"{doc.name}: link to {target} (no such file)"
        if anchor and path.suffix == ".md":
            assert anchor[1:] in _headings(path), f"{doc.name}: {target}{anchor} (no such heading)"


def test_the_readme_is_a_front_page():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    for doc in (REPO / "docs").glob("*.md"):
        if doc.name not in ("bench.md", "error-model.md", "fuzzing.md"):   # reached from the others
            assert f"docs/{doc.name}" in text, f"README does not link docs/{doc.name}"
