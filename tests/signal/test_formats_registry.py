"""File formats as plug-ins (issue 30): one module per format, one registry, and the readers,
the service's upload checks and the command line's suffix filters all asking it."""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_support import DT, shot_samples

from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.problems import Problem
from solitonde.instrument.service.settings import Settings
from solitonde.instrument.service.uploads import (
    FORMATS as UPLOAD_FORMATS,
)
from solitonde.instrument.service.uploads import (
    check_self_contained,
    declared_values,
    pick_format,
)
from solitonde.signal import formats
from solitonde.signal import io as signal_io
from solitonde.signal.errors import WaveformError
from solitonde.signal.formats.base import FileFormat
from solitonde.signal.formats.registry import AMBIGUOUS, EXTENSIONS, FORMATS, resolve
from solitonde.signal.waveform import Waveform

SPELLINGS = sorted({*FORMATS, *(a for f in FORMATS.values() for a in f.aliases)})
"""Every name and alias, as a user may type them."""


def test_every_format_module_is_registered_once() -> None:
    """A module of signal/formats that declares a FORMAT is in the registry, under its name."""
    declared = {}
    for info in pkgutil.iter_modules(formats.__path__):
        module = importlib.import_module(f"{formats.__name__}.{info.name}")
        fmt = getattr(module, "FORMAT", None)
        if isinstance(fmt, FileFormat):
            declared[fmt.name] = fmt
    assert declared == FORMATS
    assert signal_io.FORMATS == tuple(FORMATS) == ("csv", "npy", "npz", "hdf5", "tdms", "json")


def test_extensions_and_options_come_from_the_formats() -> None:
    assert signal_io.EXTENSIONS == EXTENSIONS == {
        ".csv": "csv", ".npy": "npy", ".npz": "npz", ".h5": "hdf5", ".hdf5": "hdf5",
        ".hdf": "hdf5", ".tdms": "tdms", ".json": "json"}
    assert signal_io.READER_OPTIONS["hdf5"][-1] == "dataset"
    assert signal_io.READER_OPTIONS["tdms"][-2:] == ("group", "channel")
    assert {ext for ext in AMBIGUOUS} & set(EXTENSIONS) == set()


@pytest.mark.parametrize("spelling", [*SPELLINGS, *(s.upper() for s in SPELLINGS)])
def test_the_reader_and_the_upload_take_the_same_format_names(spelling: str) -> None:
    """``hdf`` was a format to the reader and unknown to the upload form; now one lookup."""
    assert pick_format(spelling, None) == signal_io.detect_format("x", spelling) \
        == resolve(spelling)
    assert pick_format(f" {spelling} ", None) == resolve(spelling)  # form values are stripped


@pytest.mark.parametrize("suffix", sorted(EXTENSIONS))
def test_the_reader_and_the_upload_take_the_same_suffixes(suffix: str) -> None:
    for name in (f"shot{suffix}", f"SHOT{suffix.upper()}"):
        assert pick_format(None, name) == signal_io.detect_format(name) == EXTENSIONS[suffix]
    assert UPLOAD_FORMATS[EXTENSIONS[suffix]] == FORMATS[EXTENSIONS[suffix]].extensions[0]


@pytest.mark.parametrize("name", ["wav", "hdf4", ""])
def test_an_unknown_format_is_refused_by_both_naming_the_field(name: str) -> None:
    with pytest.raises(WaveformError) as err:
        signal_io.detect_format("x", name)
    assert err.value.field == "format" and err.value.allowed == ", ".join(FORMATS)
    with pytest.raises(Problem) as problem:
        pick_format(name or None, "shot.txt")
    assert problem.value.status == 422 and problem.value.field == "format"
    assert "allowed: csv, npy, npz, hdf5, tdms, json" in str(problem.value.detail)


def _shot(i: int = 0) -> Waveform:
    return Waveform(0.0, DT, shot_samples(i), "N", None, {"plate_id": "P1", "position": "A"})


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_each_format_writes_what_it_reads_and_sizes_it_from_its_headers(
        fmt: str, tmp_path: Path) -> None:
    """Write two shots with the format's writer, read them with its reader; a format with a
    size header declares at least the samples it holds (never fewer: the limit would miss)."""
    plugin = FORMATS[fmt]
    path = tmp_path / f"two{plugin.extensions[0]}"
    shots = [_shot(0), _shot(1)]
    signal_io.write(path, shots)
    back = signal_io.read(path)
    assert len(back) == 2
    for a, b in zip(shots, back, strict=True):
        np.testing.assert_allclose(b.force, a.force, rtol=1e-8)
        assert b.dt == pytest.approx(a.dt, rel=1e-9)
    size = declared_values(path, fmt)
    if fmt in ("csv", "json"):
        assert size is None  # text: the body limit bounds it
    else:
        assert size is not None and size >= sum(s.n for s in shots)
        assert size <= 3 * sum(s.n for s in shots)  # the time column and metadata at most


def test_only_hdf5_can_reach_outside_itself(tmp_path: Path) -> None:
    """An HDF5 external link is named by the format's check and refused as a 422 on upload;
    a self-contained file and the other formats pass."""
    import h5py

    target = tmp_path / "elsewhere.h5"
    with h5py.File(target, "w") as fh:
        fh.create_dataset("secret", data=np.arange(10.0))
    linked = tmp_path / "linked.h5"
    with h5py.File(linked, "w") as fh:
        fh["shot"] = h5py.ExternalLink(str(target), "/secret")
    assert FORMATS["hdf5"].outside_references(linked) == ["'shot' is an external link"]
    assert FORMATS["hdf5"].outside_references(target) == []
    with pytest.raises(Problem) as problem:
        check_self_contained(linked, "hdf5")
    assert problem.value.status == 422 and problem.value.field == "file"
    assert "only self-contained HDF5 files are accepted" in str(problem.value.detail)
    for fmt in ("csv", "npy", "npz", "tdms", "json"):
        assert FORMATS[fmt].outside_references(linked) == []


def test_an_upload_named_by_the_alias_hdf_is_read(tmp_path: Path) -> None:
    """POST a file with format=hdf (before: 422 unknown format; the reader took it): 201."""
    import h5py

    path = tmp_path / "shot.bin"
    with h5py.File(path, "w") as fh:
        ds = fh.create_dataset("shot", data=shot_samples(0))
        ds.attrs["dt"] = DT
    settings = Settings(store_path=tmp_path / "store.sqlite", max_samples_per_shot=50_000)
    with TestClient(build_app(settings)) as client:
        for name in ("hdf", "h5", "HDF5"):
            r = client.post("/v1/measurements", files={"file": ("shot.bin", path.read_bytes())},
                            data={"format": name, "sphere_diameter": "0.00953",
                                  "allow_duplicate": "true"})  # the same shot, read each way
            assert r.status_code == 201, (name, r.text)
        r = client.post("/v1/measurements", files={"file": ("shot.bin", path.read_bytes())},
                        data={"format": "hdf4"})
        assert r.status_code == 422 and r.json()["field"] == "format"
