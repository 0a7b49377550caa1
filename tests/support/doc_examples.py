"""The shown outputs of README.md and docs/, found and compared with what running them prints.

Three kinds of example are checked:

* a ```` ```console ```` block: ``$ `` lines are commands (a trailing ``\\`` continues one), the
  lines up to the next ``$ `` are what it prints. A block runs as one bash script (a ``cd`` or a
  variable carries to the next command) from a scratch folder where ``data_samples`` is the
  repository's. The shown text must match the printed text line for line, except that ``...``
  stands for any text and runs of spaces for any spaces: every digit shown is compared.
* a ```` ```pycon ```` block: a doctest (the standard library's), with ``...`` as its ellipsis.
* a ``<!-- doc-figures: FILE [FILE...] -->`` comment before a paragraph, table or list: a
  command too slow for the default run (a study, a table build) wrote those files (JSON, or a
  CSV of numbers); every decimal number of the paragraph must be one of their values shown to
  that many decimals (also read as a percentage, or in milli- or micro-units). A figures file
  under docs/figures/ is ``{"command": ..., "figures": ...}``: the slow test runs its command
  again and the text must still hold.

A ``<!-- doc-test: OPTION -->`` comment right before a block sets how it runs: ``server`` (a
uvicorn process with the bundled table answers at the address the block names), ``slow`` (only
under ``-m slow``), ``skip REASON`` (not run: the reason is printed).
"""

from __future__ import annotations

import csv
import doctest
import json
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```", re.S | re.M)
OPTION = re.compile(r"<!--\s*doc-test:\s*(.*?)\s*-->\s*$")
FIGURES = re.compile(r"<!--\s*doc-figures:\s*(.*?)\s*-->")
NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")
DECIMAL = re.compile(r"(?<![\w.])\d+\.\d+(?:e-?\d+)?(?!\w|\.\d)")


@dataclass(frozen=True)
class Block:
    """One fenced block of a Markdown file, with the options of the comment just before it."""

    path: Path
    line: int
    lang: str
    text: str
    options: tuple[str, ...] = ()

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


@dataclass
class Step:
    """One ``$ `` command of a console block and the text shown after it."""

    command: str
    shown: list[str] = field(default_factory=list)


def markdown_files() -> list[Path]:
    """README.md and every Markdown file under docs/."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def blocks(path: Path) -> Iterator[Block]:
    """The fenced blocks of one file, in order."""
    text = path.read_text()
    for match in FENCE.finditer(text):
        before = text[: match.start()].rstrip("\n").rsplit("\n", 1)[-1]
        option = OPTION.search(before)
        yield Block(path, text.count("\n", 0, match.start()) + 1, match.group(1),
                    match.group(2), tuple(option.group(1).split(None, 1)) if option else ())


def console_steps(block: Block) -> list[Step]:
    """The commands of a console block, continuations joined, each with its shown output."""
    steps: list[Step] = []
    pending: str | None = None
    for line in block.text.splitlines():
        if pending is not None:
            pending += "\n" + line
        elif line.startswith("$ "):
            pending = line[2:]
        else:
            if not steps:
                raise ValueError(f"{block.where}: output before the first '$ ' command")
            steps[-1].shown.append(line)
            continue
        if pending.endswith("\\"):
            continue
        steps.append(Step(pending))
        pending = None
    if pending is not None:
        raise ValueError(f"{block.where}: a command ends in a continuation")
    return steps


def shown_pattern(shown: list[str]) -> re.Pattern[str]:
    """The shown lines as a pattern: ``...`` any text, a run of spaces any spaces.

    A shown line break may stand for none (a long JSON line is shown folded)."""
    parts = []
    for line in shown:
        pieces = [r"\s+".join(re.escape(w) for w in chunk.split()) for chunk in line.split("...")]
        parts.append(".*?".join(pieces))
    return re.compile(r"\s*" + r"\s*".join(parts) + r"\s*", re.S)


def mismatch(shown: list[str], printed: str) -> str | None:
    """None when the printed text is what is shown, else the first shown line that differs."""
    if shown_pattern(shown).fullmatch(printed.strip("\n")):
        return None
    lines = printed.strip("\n").splitlines()
    for i, want in enumerate(shown):
        got = lines[i] if i < len(lines) else "<nothing>"
        if not shown_pattern([want]).fullmatch(got):
            return f"line {i + 1}: shown {want!r}, printed {got!r}"
    return f"printed {len(lines)} lines, shown {len(shown)}"


def console_script(steps: list[Step], marker: str) -> str:
    """One bash script that runs the steps in turn, a marker line before each one's output."""
    lines = ["set -e"]
    for i, step in enumerate(steps):
        lines += [f"printf '\\n{marker}{i}\\n'", step.command]
    return "\n".join(lines) + "\n"


def split_outputs(stdout: str, marker: str, n: int) -> list[str]:
    """The script's output cut at the markers: one text per step."""
    chunks = re.split(rf"\n{re.escape(marker)}\d+\n", stdout)[1:]
    return chunks + [""] * (n - len(chunks))


def run_pycon(block: Block, globs: dict[str, object]) -> str | None:
    """Run a pycon block as a doctest; None when it passes, else the report of what differed."""
    parser = doctest.DocTestParser()
    test = parser.get_doctest(block.text, globs, block.where, str(block.path), block.line)
    flags = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
    out: list[str] = []
    runner = doctest.DocTestRunner(optionflags=flags)
    runner.run(test, out=out.append)
    return "".join(out) if runner.failures else None


def figure_paragraphs(path: Path) -> Iterator[tuple[int, tuple[Path, ...], str]]:
    """(line, figures files, text) for every paragraph marked with a doc-figures comment."""
    text = path.read_text()
    for match in FIGURES.finditer(text):
        rest = text[match.end():].lstrip("\n")
        paragraph = rest.split("\n\n", 1)[0]
        files = tuple(ROOT / name for name in match.group(1).split())
        yield text.count("\n", 0, match.start()) + 1, files, paragraph


def json_numbers(value: object) -> list[float]:
    """Every number of a JSON document (bools left out)."""
    if isinstance(value, bool):
        return []
    if isinstance(value, int | float):
        return [float(value)]
    if isinstance(value, dict):
        return [x for v in value.values() for x in json_numbers(v)]
    if isinstance(value, list):
        return [x for v in value for x in json_numbers(v)]
    return []


SCALES = (1.0, 100.0, 1e3, 1e6)


def decimals(text: str) -> list[str]:
    """The decimal numbers of a text as written: ``3.502..5.422`` is two, a full stop ends one."""
    return DECIMAL.findall(text.replace("..", " .. "))


def shows(value: float, token: str) -> bool:
    """Whether ``value`` (or its size) written with the token's digits is the token."""
    mantissa, _, exponent = token.partition("e")
    decimals = len(mantissa.split(".")[1])
    if exponent:
        return float(f"{abs(value):.{decimals}e}") == float(token)
    return f"{abs(value):.{decimals}f}" == token


def unbacked_numbers(paragraph: str, values: list[float]) -> list[str]:
    """The decimal numbers of a paragraph (signs and range hyphens aside) that no value shows."""
    finite = [v * s for v in values if math.isfinite(v) for s in SCALES]
    return [token for token in decimals(paragraph)
            if not any(shows(v, token) for v in finite)]


def figure_values(path: Path) -> list[float]:
    """Every number of a figures file: a JSON document, or the numeric cells of a CSV."""
    if path.suffix == ".csv":
        with path.open(newline="") as f:
            cells = [c for row in csv.reader(f) for c in row]
        return [float(c) for c in cells if NUMBER.fullmatch(c.strip())]
    data = json.loads(path.read_text())
    if path.parent == ROOT / "docs" / "figures" and not (
            isinstance(data, dict) and {"command", "figures"} <= data.keys()):
        raise ValueError(f"{path}: a figures file of docs/ holds 'command' and 'figures'")
    return json_numbers(data)
