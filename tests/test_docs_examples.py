"""Every shown output of README.md and docs/ is what running it prints (how a block is read:
tests/support/doc_examples.py). A change that moves a shown number fails until the text follows."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from doc_examples import (
    ROOT,
    Block,
    blocks,
    console_script,
    console_steps,
    figure_paragraphs,
    figure_values,
    markdown_files,
    mismatch,
    run_pycon,
    split_outputs,
    unbacked_numbers,
)
from service_support import start_uvicorn, stop_group

MARKER = "@@doc-step-"
SHOWN_URL = "http://127.0.0.1:8000"
ALL = [b for path in markdown_files() for b in blocks(path)]
CONSOLE = [b for b in ALL if b.lang == "console"]
PYCON = [b for b in ALL if b.lang == "pycon"]
FIGURES = [(path, *item) for path in markdown_files() for item in figure_paragraphs(path)]


def _param(block: Block) -> object:
    marks = []
    if block.options[:1] == ("slow",):
        marks.append(pytest.mark.slow)
    if block.options[:1] == ("skip",):
        marks.append(pytest.mark.skip(reason=" ".join(block.options[1:]) or "marked skip"))
    return pytest.param(block, id=block.where, marks=marks)


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("SOLITONDE_")}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["COLUMNS"] = "100"
    return env


def run_console(block: Block, cwd: Path, url: str | None = None) -> list[str]:
    """Run a console block's commands in one bash script; each step's printed text."""
    steps = console_steps(block)
    script = console_script(steps, MARKER)
    if url is not None:
        script = script.replace(SHOWN_URL, url)
    (cwd / "data_samples").symlink_to(ROOT / "data_samples")
    run = subprocess.run(["bash", "-c", script], cwd=cwd, env=_env(), capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, (block.where, run.stdout[-3000:], run.stderr[-3000:])
    return split_outputs(run.stdout, MARKER, len(steps))


def check_console(block: Block, printed: list[str]) -> None:
    for step, text in zip(console_steps(block), printed, strict=True):
        if step.shown:
            problem = mismatch(step.shown, text)
            assert problem is None, f"{block.where}: `{step.command}`: {problem}\n{text}"


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory):
    proc, url = start_uvicorn(tmp_path_factory.mktemp("service") / "store.sqlite",
                              env={"SOLITONDE_TABLE": str(ROOT / "data_samples" /
                                                          "default_table.h5")})
    try:
        yield url
    finally:
        stop_group(proc)


@pytest.mark.parametrize("block", [_param(b) for b in CONSOLE if "server" not in b.options])
def test_a_console_block_prints_what_it_shows(block: Block, tmp_path: Path) -> None:
    check_console(block, run_console(block, tmp_path))


@pytest.mark.skipif(shutil.which("curl") is None, reason="no curl on this machine")
@pytest.mark.parametrize("block", [_param(b) for b in CONSOLE if "server" in b.options])
def test_a_service_block_prints_what_it_shows(block: Block, tmp_path: Path, service: str) -> None:
    check_console(block, run_console(block, tmp_path, url=service))


@pytest.mark.parametrize("block", [_param(b) for b in PYCON])
def test_a_python_session_prints_what_it_shows(block: Block, monkeypatch) -> None:
    monkeypatch.chdir(ROOT)
    report = run_pycon(block, {})
    assert report is None, report


@pytest.mark.parametrize("path,line,files,paragraph", FIGURES,
                         ids=[f"{p.relative_to(ROOT)}:{n}" for p, n, _, _ in FIGURES])
def test_a_studys_figures_are_its_files(path: Path, line: int, files: tuple[Path, ...],
                                        paragraph: str) -> None:
    """The text shows the figures its study wrote (the study reruns under -m slow)."""
    values = [v for f in files for v in figure_values(f)]
    missing = unbacked_numbers(paragraph, values)
    assert not missing, f"{path.name}:{line}: {missing} are in none of {[f.name for f in files]}"


def test_the_docs_show_outputs_to_check() -> None:
    """The runner finds the README's examples: a checker that finds nothing passes everything."""
    readme = [b for b in CONSOLE + PYCON if b.path.name == "README.md"]
    assert len(readme) >= 3, [b.where for b in readme]
    assert all(any(s.shown for s in console_steps(b)) for b in CONSOLE if b.path == ROOT /
               "README.md")


def test_a_changed_digit_fails_and_the_shown_text_passes() -> None:
    """The comparison is digit for digit where the text shows digits, loose only at ``...``."""
    printed = ("thickness: 4.867 mm (MAP 4.859; 68 % 4.189..5.143; 95 % 3.502..5.422 mm)\n"
               "fit: p = 0.92")
    assert mismatch(["thickness: 4.867 mm (MAP ...)", "fit: p = 0.92"], printed) is None
    assert mismatch(["thickness: 4.868 mm (MAP ...)", "fit: p = 0.92"], printed) is not None
    assert mismatch(["thickness: 4.867 mm (MAP ...)", "fit: p = 0.93"], printed) is not None
    assert mismatch(["thickness: 4.867 mm (MAP ...)"], printed) is not None  # a line left out
