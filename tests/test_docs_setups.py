"""docs/how-to/setups.md's walk, run as written: a plate by its properties, its own table, a damped
chain, a set-up calibrated through the service on two references, measurements through `post
--setup` and `watch --setup`, and `analyze --setup` offline (about 4 minutes on 2 cores: marked
slow, `pytest -m slow tests/test_docs_setups.py`). The printed lines and the table's figures are
the walk's own, and the service's answers equal analyze's to the last bit."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from doc_examples import decimals, figure_paragraphs, json_numbers, unbacked_numbers

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "how-to" / "setups.md"
FIGURES = ROOT / "docs" / "figures" / "setups-walk.json"


def _section() -> str:
    return DOC.read_text().split("## What it looks like\n", 1)[1]


def _fmt(p: dict) -> str:
    return f"{p['median'] * 1e3:.3f} ({p['ci95'][0] * 1e3:.3f}-{p['ci95'][1] * 1e3:.3f})"


@pytest.mark.slow
def test_the_setups_walk_runs_as_written(tmp_path: Path) -> None:
    section = _section()
    script = re.search(r"```bash\n(.*?)```", section, flags=re.S).group(1)
    printed = re.search(r"It prints, among the rest:\n\n(?:<!--.*?-->\n)?```\n(.*?)```", section,
                        flags=re.S).group(1).splitlines()
    env = {k: v for k, v in os.environ.items() if not k.startswith("SOLITONDE_")}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    run = subprocess.run(["bash", "-e", "-c", script], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    lines = run.stdout.splitlines()
    for want in printed:
        if "..." in want:  # a job id
            head, tail = want.split("...")
            assert any(line.startswith(head) and line.endswith(tail) for line in lines), want
        else:
            assert want in lines, (want, run.stdout[-3000:])
    # the store after the walk, and analyze on the same files, against the table shown
    from solitonde.instrument.service.store import Store

    store = Store(tmp_path / "store.sqlite", background_checkpoint=False)
    try:
        by_source = {}
        for m in store.list(plate_id="TI-1"):
            record = store.get(m.id)
            source = Path(record.shots[0].metadata["source"]).stem
            by_source[source] = record
    finally:
        store.close()
    rows = {r.split("|")[1].strip(): [c.strip() for c in r.split("|")[2:5]]
            for r in section.splitlines() if r.startswith("| centre") or " from the clamp |" in r}
    names = {"centre": "centre", "d60": "60 mm from the clamp", "d30": "30 mm from the clamp"}
    figures: dict[str, dict] = {}
    for source, name in names.items():
        record = by_source[source]
        assert record.result["provenance"]["setup"] == {"id": "ti-chain", "revision": 2}
        service = record.result["estimate"]
        analyzed = subprocess.run(
            [sys.executable, "-m", "solitonde.instrument.cli.main", "analyze",
             f"day/{source}.csv", "--setup", "ti_setup.json", "--table", "ti_table.h5",
             "--invert", "--json"], cwd=tmp_path, env=env, capture_output=True, text=True,
            timeout=600)
        offline = json.loads(analyzed.stdout)["estimates"][0]["estimate"]
        for key in ("thickness_m", "distance_m"):
            assert service[key] == offline[key], (source, key)
        t = service["thickness_m"]
        assert t["ci95"][0] <= 3.5e-3 <= t["ci95"][1], (source, t)
        _, after, offline_cell = rows[name]
        assert after == _fmt(t) and offline_cell == _fmt(offline["thickness_m"]), (name, rows)
        figures[source] = {"service": t, "offline": offline["thickness_m"]}
        if source == "centre":
            before = record.earlier[0]["result"]["estimate"]["thickness_m"]
            figures[source]["before"] = before
            assert rows[name][0] == (f"{before['median'] * 1e3:.2f} mm (95 % "
                                     f"{before['ci95'][0] * 1e3:.2f}-"
                                     f"{before['ci95'][1] * 1e3:.2f})")
    write_figures(figures, printed)


def write_figures(figures: dict[str, dict], printed: list[str]) -> None:
    """docs/figures/setups-walk.json: the walk's estimates; the default run checks the page's
    table against it (tests/test_docs_examples.py)."""
    # the shown lines were each found in the walk's output above: their numbers are its own
    numbers = [float(x) for line in printed for x in decimals(line)]
    data = {"command": "pytest -m slow tests/test_docs_setups.py --timeout 0",
            "figures": {"estimates": figures, "printed": numbers}}
    FIGURES.write_text(json.dumps(data, indent=1) + "\n")
    for line, files, paragraph in figure_paragraphs(DOC):
        if FIGURES in files:
            values = json_numbers(data["figures"])
            assert not unbacked_numbers(paragraph, values), (line, paragraph)
