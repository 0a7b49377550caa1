"""The data that ships inside the package: the bundled model tables and the sample waveforms.

The repository keeps them in ``data_samples/``; setuptools maps that folder to the package
``solitonde.data`` (``package-dir`` in pyproject.toml), so an editable install reads the
checkout's folder and a wheel or ``pip install .`` carries the files in site-packages. Found
through the import system, never from the folder a command is started in.
"""

from __future__ import annotations

from importlib import util
from pathlib import Path

DATA_PACKAGE = "solitonde.data"


def data_dir() -> Path:
    """The folder of the bundled data (``data_samples/`` in a checkout)."""
    spec = util.find_spec(DATA_PACKAGE)
    for location in (spec.submodule_search_locations or []) if spec else []:
        if (Path(location) / "default_table.h5").is_file():
            return Path(location).resolve()
    # not installed (the source folders on sys.path by hand): the checkout's own folder
    return Path(__file__).resolve().parents[2] / "data_samples"


def default_table() -> Path:
    """The paper's model table (aluminium, D = 9.53, 19.05 mm), served when none is named."""
    return data_dir() / "default_table.h5"


def bundled_tables() -> list[Path]:
    """Every bundled model table, the default first."""
    first = default_table()
    return [first, *sorted(p for p in data_dir().glob("*.h5") if p != first)]


def sample_waveforms() -> Path:
    """The folder of the synthetic sample waveforms (one file per format) and their truth."""
    return data_dir() / "waveforms"
