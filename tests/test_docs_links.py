"""Every relative link of README.md and docs/ reaches a file, and its #anchor a heading there."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from doc_examples import ROOT, markdown_files

LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def anchors(path: Path) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces as hyphens."""
    out = set()
    for line in path.read_text().splitlines():
        if line.startswith("#") and not line.startswith("#!"):
            title = line.lstrip("#").strip().lower()
            out.add(re.sub(r"[^\w\- ]", "", title).replace(" ", "-"))
    return out


def prose(path: Path) -> str:
    """A file's text without its code blocks and code spans."""
    return re.sub(r"`[^`\n]*`", "", re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M))


def links() -> list[tuple[Path, str]]:
    return [(path, target) for path in markdown_files()
            for target in LINK.findall(prose(path))
            if not re.match(r"[a-z]+:", target) and not target.startswith("#")]


@pytest.mark.parametrize("path,target", links(),
                         ids=[f"{p.relative_to(ROOT)}->{t}" for p, t in links()])
def test_a_relative_link_resolves(path: Path, target: str) -> None:
    file, _, anchor = target.partition("#")
    dest = (path.parent / file).resolve()
    assert dest.exists(), f"{path.relative_to(ROOT)}: {target} does not exist"
    if anchor and dest.suffix == ".md":
        assert anchor in anchors(dest), f"{path.relative_to(ROOT)}: no heading #{anchor}"


def test_the_docs_are_laid_out_by_purpose() -> None:
    """A tutorial, how-to guides, the reference and the explanations, and an index of them."""
    docs = ROOT / "docs"
    assert (docs / "tutorial.md").exists() and (docs / "README.md").exists()
    for part in ("how-to", "reference", "explanation"):
        assert list((docs / part).glob("*.md")), part
    index = (docs / "README.md").read_text()
    for page in docs.rglob("*.md"):
        if page.name != "README.md":
            assert str(page.relative_to(docs)) in index, f"docs/README.md does not list {page}"
