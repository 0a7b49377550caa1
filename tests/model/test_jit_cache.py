"""Compiled kernels never outlive their source: numba's cache folder follows the package's source.

numba checks a cached kernel only against its own file; a helper it inlines from another module
can change under it (first test, plain numba). solitonde keys the cache folder by a hash of the
kernel packages' source, so an edited helper is compiled again (second test, a copy of the
package with the contact law edited between two runs)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from solitonde.model import jit_cache

ROOT = Path(__file__).resolve().parents[2]


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "SOLITONDE_CACHE_DIR", "PYTHONPATH")}
    env.update(extra)
    return env


def _run(code: str, cwd: Path, env: dict[str, str]) -> dict:
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_plain_numba_keeps_a_kernel_whose_inlined_helper_changed(tmp_path: Path) -> None:
    """The premise: numba's own cache returns the old machine code after the helper's edit."""
    (tmp_path / "helper.py").write_text(textwrap.dedent("""
        from numba import njit
        @njit(cache=True, inline="always")
        def law(x):
            return 2.0 * x
    """))
    (tmp_path / "kernel.py").write_text(textwrap.dedent("""
        from numba import njit
        from helper import law
        @njit(cache=True)
        def kernel(x):
            return law(x) + 1.0
    """))
    code = """
        import json
        from kernel import kernel
        print(json.dumps({"value": kernel(1.0),
                          "hits_all": sum(kernel.stats.cache_hits.values())}))
    """
    env = _env(NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(tmp_path))
    first = _run(code, tmp_path, env)
    helper = tmp_path / "helper.py"
    helper.write_text(helper.read_text().replace("2.0 * x", "3.0 * x"))
    second = _run(code, tmp_path, env)
    assert first["value"] == 3.0
    assert second["hits_all"] == 1, "numba loaded the kernel from its cache"
    assert second["value"] == 3.0, "stale: the edited helper would give 4.0"


@pytest.fixture
def package_copy(tmp_path: Path) -> Path:
    """The kernel packages copied under ``tmp/pkg/solitonde`` (no cache files)."""
    dest = tmp_path / "pkg" / "solitonde"
    for folder in ("model", "signal"):
        shutil.copytree(ROOT / folder, dest / folder,
                        ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    return tmp_path / "pkg"


def test_an_edited_helper_is_compiled_again(package_copy: Path, tmp_path: Path) -> None:
    """Edit ``laws.hertz`` (inlined into ``chain.contact_forces``) between runs: the second run
    after the edit gets the new law, and an unchanged source is served from the cache."""
    code = f"""
        import json, numpy as np
        import solitonde.model as m
        assert m.__file__.startswith({str(package_copy)!r}), m.__file__
        from solitonde.model.chain import contact_forces
        u = np.array([0.0, -1e-6, -3e-6]); f = np.zeros(2)
        contact_forces(u, 1e9, 1e9, f)
        import os
        print(json.dumps({{"f": f.tolist(), "dir": os.environ["NUMBA_CACHE_DIR"],
                          "hits": sum(contact_forces.stats.cache_hits.values())}}))
    """
    env = _env(PYTHONPATH=str(package_copy), SOLITONDE_CACHE_DIR=str(tmp_path / "cache"))
    first = _run(code, tmp_path, env)
    again = _run(code, tmp_path, env)
    assert first["hits"] == 0 and again["hits"] == 1, "unchanged source: loaded from the cache"
    assert again["f"] == first["f"]
    assert first["f"][0] == pytest.approx(1e9 * 1e-6**1.5)

    laws = package_copy / "solitonde" / "model" / "laws.py"
    text = laws.read_text()
    assert "return a * d * sqrt(d)" in text
    laws.write_text(text.replace("return a * d * sqrt(d)", "return 2.0 * a * d * sqrt(d)", 1))
    edited = _run(code, tmp_path, env)
    assert edited["dir"] != first["dir"], "the source changed: a new cache folder"
    assert edited["hits"] == 0
    assert edited["f"] == [2.0 * x for x in first["f"]]


def test_workers_inherit_the_folder_and_a_users_folder_is_the_root(tmp_path: Path) -> None:
    """A child with the parent's NUMBA_CACHE_DIR keeps it; a user's own NUMBA_CACHE_DIR becomes
    the root the keyed folder goes in; SOLITONDE_CACHE_DIR wins over both."""
    code = """
        import json, os
        import solitonde.model
        print(json.dumps({"dir": os.environ["NUMBA_CACHE_DIR"]}))
    """
    mine = _run(code, tmp_path, _env(NUMBA_CACHE_DIR=str(tmp_path / "user")))["dir"]
    assert Path(mine).parent == tmp_path / "user"
    assert Path(mine).name.startswith(jit_cache.PREFIX)
    assert _run(code, tmp_path, _env(NUMBA_CACHE_DIR=mine))["dir"] == mine
    ours = _run(code, tmp_path, _env(NUMBA_CACHE_DIR=mine,
                                      SOLITONDE_CACHE_DIR=str(tmp_path / "s")))["dir"]
    assert Path(ours).parent == tmp_path / "s"


def test_a_clone_at_another_path_loads_the_compiled_kernels(package_copy: Path,
                                                            tmp_path: Path) -> None:
    """The same source at another path (a second clone, a moved checkout) finds its kernels in
    the cache: files are named by their place in the package, not by the absolute path."""
    code = """
        import json, os, numpy as np
        import solitonde.model as m
        from solitonde.model.chain import contact_forces
        u = np.array([0.0, -1e-6, -3e-6]); f = np.zeros(2)
        contact_forces(u, 1e9, 1e9, f)
        print(json.dumps({"file": m.__file__, "f": f.tolist(),
                          "hits": sum(contact_forces.stats.cache_hits.values())}))
    """
    moved = tmp_path / "elsewhere" / "checkout"
    shutil.copytree(package_copy, moved)
    for path in moved.rglob("*.py"):  # a clone's files are new files: other times than the first's
        os.utime(path, (1.7e9, 1.7e9))
    cache = str(tmp_path / "cache")
    first = _run(code, tmp_path, _env(PYTHONPATH=str(package_copy), SOLITONDE_CACHE_DIR=cache))
    there = _run(code, tmp_path, _env(PYTHONPATH=str(moved), SOLITONDE_CACHE_DIR=cache))
    assert first["file"] != there["file"] and there["file"].startswith(str(moved))
    assert first["hits"] == 0 and there["hits"] == 1, "the other clone compiled again"
    assert there["f"] == first["f"]


def test_a_clone_at_another_path_loads_the_inference_kernels(tmp_path: Path) -> None:
    """The inference's kernels (outside the model and the signal packages) are filed by their
    place in the package too: another clone of the same source loads them compiled."""
    code = """
        import json
        from solitonde.instrument.inference import likelihood_kernel as k
        k.warm()
        print(json.dumps({"file": k.__file__,
                          "hits": sum(k.add_terms.stats.cache_hits.values())}))
    """
    clones = []
    for name in ("first", "second"):
        dest = tmp_path / name / "solitonde"
        for folder in ("model", "signal", "instrument"):
            shutil.copytree(ROOT / folder, dest / folder,
                            ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
        clones.append(dest.parent)
    cache = str(tmp_path / "cache")
    first = _run(code, tmp_path, _env(PYTHONPATH=str(clones[0]), SOLITONDE_CACHE_DIR=cache))
    there = _run(code, tmp_path, _env(PYTHONPATH=str(clones[1]), SOLITONDE_CACHE_DIR=cache))
    assert there["file"].startswith(str(clones[1]))
    assert first["hits"] == 0 and there["hits"] == 1, "the other clone compiled again"


def test_the_background_compile_files_the_kernels_where_this_process_looks() -> None:
    """The extractor's background compile imports only solitonde.signal: it gets this process's
    locators through its environment, ours first, so it files the kernels under the package's
    names (not numba's path-keyed ones, where nothing would find them)."""
    import numba  # noqa: F401  (loads numba's caching module: the locator is registered)

    from solitonde.signal import kernel_choice

    locators = kernel_choice._compile_env()["NUMBA_CACHE_LOCATOR_CLASSES"].split(",")
    assert locators[0] == "solitonde.model.jit_locator.PackageLocator"
    assert "UserProvidedCacheLocator" in locators[1:]
    assert "NUMBA_CACHE_LOCATOR_CLASSES" not in os.environ  # this process's own: unchanged
