"""The studies docs/ quotes, run again (hours on 2 cores: ``pytest -m slow
tests/test_docs_figures.py --timeout 0``): the text's numbers must hold on the fresh figures too.
The default run checks the text against the committed files (tests/test_docs_examples.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from doc_examples import (
    ROOT,
    figure_paragraphs,
    figure_values,
    json_numbers,
    markdown_files,
    unbacked_numbers,
)
from doc_figures import COMMANDS, FIGURES_DIR, run

MARKED = {(path, line, files, paragraph) for path in markdown_files()
          for line, files, paragraph in figure_paragraphs(path)}


def test_every_figures_file_has_its_command() -> None:
    """docs/figures holds the studies doc_figures.py runs and the slow walks' figures (each
    written by its test), and docs/ quotes each."""
    files = {p.stem for p in FIGURES_DIR.glob("*.json")}
    walks = {name for name in files if json.loads((FIGURES_DIR / f"{name}.json").read_text())
             ["command"].startswith("pytest -m slow tests/")}  # a slow test writes its own
    assert files - walks == set(COMMANDS), (files - walks) ^ set(COMMANDS)
    quoted = {f.stem for _, _, fs, _ in MARKED for f in fs if f.parent == FIGURES_DIR}
    assert quoted == files, files - quoted


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_study_gives_the_figures_the_docs_show(name: str) -> None:
    fresh = json_numbers(run(name)["figures"])
    for path, line, files, paragraph in MARKED:
        if FIGURES_DIR / f"{name}.json" not in files:
            continue
        others = [v for f in files if f.stem != name for v in figure_values(f)]
        missing = unbacked_numbers(paragraph, fresh + others)
        assert not missing, f"{Path(path).relative_to(ROOT)}:{line}: {missing}"
