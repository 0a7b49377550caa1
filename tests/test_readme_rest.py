"""The README's REST examples, run as written (curl, the raw shot file, post twice) against a real
uvicorn process with the bundled table."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from service_support import start_uvicorn, stop_group

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
README_URL = "http://127.0.0.1:8000"


def readme_commands(section: str) -> list[str]:
    """The ``$ `` lines of the code blocks of a README section, continuations joined."""
    text = README.read_text()
    body = text.split(f"## {section}\n", 1)[1].split("\n## ", 1)[0]
    commands: list[str] = []
    for block in re.findall(r"```[a-z]*\n(.*?)```", body, flags=re.S):
        pending = None
        for line in block.splitlines():
            if pending is not None:
                pending += " " + line.strip()
            elif line.startswith("$ "):
                pending = line[2:]
            else:
                continue
            if pending.endswith("\\"):
                pending = pending[:-1].rstrip()
                continue
            commands.append(pending)
            pending = None
    return commands


@pytest.mark.skipif(shutil.which("curl") is None, reason="no curl on this machine")
def test_the_rest_examples_work_as_written(tmp_path):
    commands = readme_commands("The REST service")
    assert [c.split()[0] for c in commands] == ["curl", "python", "curl", "solitonde",
                                                "solitonde"], commands
    (tmp_path / "data_samples").symlink_to(ROOT / "data_samples")
    env = {k: v for k, v in os.environ.items() if not k.startswith("SOLITONDE_")}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    proc, url = start_uvicorn(tmp_path / "store.sqlite",
                              env={"SOLITONDE_TABLE": str(ROOT / "data_samples" /
                                                          "default_table.h5")})
    try:
        outs = []
        for command in commands:
            run = subprocess.run(["bash", "-c", command.replace(README_URL, url)], cwd=tmp_path,
                                 env=env, capture_output=True, text=True, timeout=180)
            assert run.returncode == 0, (command, run.stdout, run.stderr)
            outs.append(run.stdout)
    finally:
        stop_group(proc)
    upload, raw = json.loads(outs[0]), json.loads(outs[2])
    assert upload["n_shots"] == 2 and upload["plate_id"] == "synthetic-t4.83mm"
    assert upload["estimate"]["thickness_m"]["status"] == "constrained"
    assert raw["n_shots"] == 1 and raw["position"] == "A3"
    # the raw shot is the file's first shot: the same TOF to the last bit of float32
    assert raw["shots"][0]["features"]["tof_s"] == pytest.approx(
        upload["shots"][0]["features"]["tof_s"], rel=1e-6)
    first, second = outs[3].strip(), outs[4].strip()
    assert first.startswith("stored: ") and second.startswith("replayed: ")
    assert first.split("-> ")[1] == second.split("-> ")[1], (first, second)
