"""The package a user installs: the wheel carries the bundled tables and samples, serves them
from any folder, and `make run` passes HOST and PORT through to `serve`."""

from __future__ import annotations

import os
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import httpx
import pytest
from service_support import free_port, stop_group, wait_ready

ROOT = Path(__file__).resolve().parents[1]

WHEEL_MAX_BYTES = 5 * 1024 * 1024
"""The wheel stays small: code, the two bundled tables and the sample files, not the figures."""


def test_make_run_passes_host_and_port_to_serve() -> None:
    """`make run PORT=8001 HOST=0.0.0.0` runs `serve --host 0.0.0.0 --port 8001` (whose key
    rule then applies: a non-loopback host needs SOLITONDE_API_KEY)."""
    out = subprocess.run(["make", "-n", "run", "PORT=8001", "HOST=0.0.0.0"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    serve = [line for line in out.stdout.splitlines() if "solitonde serve" in line]
    assert len(serve) == 1 and "--host '0.0.0.0' --port '8001'" in serve[0], out.stdout
    default = subprocess.run(["make", "-n", "run"], cwd=ROOT, capture_output=True, text=True,
                             timeout=60).stdout
    assert "--host '127.0.0.1' --port '8000'" in default


def test_bundled_data_is_found_through_the_package(tmp_path: Path) -> None:
    """From a folder that is not the checkout, the bundled tables and samples are found."""
    code = ("from solitonde.instrument.tables.bundled import bundled_tables, sample_waveforms\n"
            "from solitonde.instrument.service.settings import DEFAULT_TABLE\n"
            "print(DEFAULT_TABLE); print(*bundled_tables()); "
            "print(*sorted(p.name for p in sample_waveforms().iterdir()))")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    default, tables, samples = out.stdout.splitlines()
    assert Path(default).is_file() and Path(default).name == "default_table.h5"
    assert {Path(t).name for t in tables.split()} == {"default_table.h5", "steel_table.h5"}
    assert {"truth.tsv", "synthetic_D9.53_t4.83_snr40.csv"} <= set(samples.split())


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``pip wheel .`` of this checkout (no dependencies)."""
    out_dir = tmp_path_factory.mktemp("wheel")
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                            str(out_dir), str(ROOT)], capture_output=True, text=True,
                           timeout=600, cwd=out_dir)
    assert build.returncode == 0, build.stderr[-3000:]
    (found,) = out_dir.glob("solitonde-*.whl")
    return found


def test_the_wheel_carries_the_tables_and_samples(wheel: Path) -> None:
    """The files the commands read by default are in the wheel; the figures are not."""
    names = set(zipfile.ZipFile(wheel).namelist())
    data = sorted((ROOT / "data_samples").rglob("*"))
    wanted = {f"solitonde/data/{p.relative_to(ROOT / 'data_samples').as_posix()}" for p in data
              if p.is_file() and p.parent.name != "figures"}
    assert wanted <= names, sorted(wanted - names)
    assert not any(n.startswith("solitonde/data/figures/") for n in names)
    assert "solitonde/model/zener_table.json" in names
    assert "solitonde/signal/formats/registry.py" in names  # the format plug-ins' sub-folder
    assert any(n.startswith("solitonde/instrument/service/webpage/") for n in names)
    assert wheel.stat().st_size < WHEEL_MAX_BYTES


@pytest.mark.slow
def test_the_installed_wheel_serves_the_bundled_table_from_anywhere(wheel: Path,
                                                                    tmp_path: Path) -> None:
    """A fresh venv with the wheel (its dependencies borrowed from this environment, so no
    index is needed), `serve` started in an empty folder: /v1/tables lists the bundled table,
    and `samples --out` writes the sample waveforms there."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    purelib = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_path("
                              "'purelib'))"], capture_output=True, text=True, check=True
                             ).stdout.strip()
    # the dependencies: this environment's site-packages as a plain path (its .pth files, the
    # editable install of the checkout among them, are not processed from there)
    deps = [p for p in site.getsitepackages() if Path(p).is_dir()]
    (Path(purelib) / "zz_deps.pth").write_text("\n".join(deps) + "\n")
    subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                    str(wheel)], check=True, timeout=300, capture_output=True)
    where = tmp_path / "elsewhere"
    where.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SOLITONDE_", "PYTHON"))}
    env["SOLITONDE_CACHE_DIR"] = str(tmp_path / "numba-cache")
    check = subprocess.run([str(py), "-c", "import solitonde.model; print(solitonde.model."
                            "__file__)"], cwd=where, env=env, capture_output=True, text=True,
                           timeout=120)
    assert Path(check.stdout.strip()).is_relative_to(Path(purelib)), check.stdout + check.stderr
    port = free_port()
    proc = subprocess.Popen([str(venv / "bin" / "solitonde"), "serve", "--port", str(port),
                             "--store", str(where / "m.sqlite")], cwd=where, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        wait_ready(url, proc, timeout=600)
        tables = httpx.get(f"{url}/v1/tables", timeout=30).json()
    finally:
        stop_group(proc)
    ids = [t["id"] for t in tables["items"]]
    assert ids == ["default_table"], tables
    out = subprocess.run([str(venv / "bin" / "solitonde"), "samples", "--out",
                          str(where / "w")], cwd=where, env=env, capture_output=True, text=True,
                         timeout=900)
    assert out.returncode == 0, out.stdout + out.stderr
    assert (where / "w" / "truth.tsv").is_file()
