"""Write the study figures that docs/ shows: each docs/figures/NAME.json is one command's JSON.

    python tests/support/doc_figures.py [--only NAME] [--out DIR] [--measurements DIR]

Each file is ``{"command": ..., "figures": ...}``; the text that shows its numbers is marked
``<!-- doc-figures: docs/figures/NAME.json -->`` and the default test run checks the text against
the file (tests/test_docs_examples.py). The studies take minutes to hours on 2 cores, so they run
here or under ``-m slow`` (tests/test_docs_figures.py), never in the default run.
``--measurements DIR`` keeps each validation's simulated shots in DIR/NAME.measurements.json
and reuses them when they match the draw: scoring again is then seconds, and the figures are
the same as from a fresh simulation.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIGURES_DIR = ROOT / "docs" / "figures"
VALIDATE = "solitonde validate --diameters 9.53e-3 --json --no-progress"
COMMANDS: dict[str, str] = {
    **{f"validate-seed{s}": f"{VALIDATE} --n 200 --seed {s}" for s in (0, 1, 2)},
    **{f"validate-near-support-seed{s}":
       f"{VALIDATE} --n 60 --shots 1 --near-support 0.05 --seed {s}" for s in (0, 1, 2)},
    **{f"validate-near-support-3d-seed{s}":
       f"{VALIDATE} --n 60 --shots 1 --near-support 0.05 --truth-plate-theory 3d --workers 2 "
       f"--seed {s}" for s in (0, 1, 2)},
    **{f"validate-map-seed{s}":
       f"solitonde validate-map --scans 30 --seed {s} --no-sequential --workers 2 --json"
       for s in (0, 1, 2)},
}


VOLATILE = ("simulation_wall_s", "wall_s", "table", "timings_s")


def run(name: str, measurements: Path | None = None) -> dict[str, object]:
    """Run one study's command; its figures file's content."""
    command = COMMANDS[name]
    args = shlex.split(command)
    if measurements is not None and args[1] in ("validate", "validate-map"):
        args += ["--measurements", str(measurements / f"{name}.measurements.json")]
    env = {k: v for k, v in os.environ.items() if not k.startswith("SOLITONDE_")}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    done = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True, check=True)
    figures = json.loads(done.stdout)
    for volatile in VOLATILE:  # the machine's times, this checkout's path
        if isinstance(figures, dict):
            figures.pop(volatile, None)
    return {"command": command, "figures": figures}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", action="append", choices=sorted(COMMANDS))
    parser.add_argument("--out", type=Path, default=FIGURES_DIR)
    parser.add_argument("--measurements", type=Path)
    opts = parser.parse_args()
    opts.out.mkdir(parents=True, exist_ok=True)
    for name in opts.only or sorted(COMMANDS):
        data = run(name, opts.measurements)
        (opts.out / f"{name}.json").write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
        print(f"wrote {opts.out / name}.json: {data['command']}")


if __name__ == "__main__":
    main()
