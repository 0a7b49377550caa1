"""Every exception class of the package: one base per layer with ``field`` and ``message``, and
a pickling round trip (issue 30: an error raised in a process pool or a Dask worker must reach
the caller as itself).

The classes are found by walking the package, so a new one without an example below fails
:func:`test_every_exception_class_has_an_example`.
"""

from __future__ import annotations

import importlib
import inspect
import pickle
import pkgutil
from collections.abc import Callable
from typing import Any

import pytest

from solitonde.instrument.errors import InstrumentError
from solitonde.model.errors import ModelError
from solitonde.signal.errors import SignalError

BASES = {"solitonde.model": ModelError, "solitonde.signal": SignalError,
         "solitonde.instrument": InstrumentError}

EXAMPLES: dict[str, Callable[[type], BaseException]] = {
    # class name: how it is raised in the code
    "ModelError": lambda c: c("chain.diameter", "must be > 0"),
    "SignalError": lambda c: c("samples", "empty"),
    "InstrumentError": lambda c: c("--table", "not a model table", "an HDF5 table file"),
    "MessageError": lambda c: c("the file names its own subject"),
    "SceneError": lambda c: c("plate.thickness", "must be > 0", "a positive length in m"),
    "SimulationError": lambda c: c("step_budget_exceeded: output.duration needs 2e9 steps"),
    "WaveformError": lambda c: c("dt", "must be > 0", "a positive time step in s"),
    "OptionNeeded": lambda c: c("calibration", "samples in volts", "N/V",
                                field="shots[2].calibration"),
    "TableError": lambda c: c("diameter_m", "no such sphere size"),
    "CalibrationError": lambda c: c("arr_factor", "must be > 0"),
    "InversionError": lambda c: c("tof_s", "must be finite"),
    "TableChoiceError": lambda c: c("plate_material", "no table of that family"),
    "ValidationInputError": lambda c: c("seed", "must be >= 0"),
    "JointMapError": lambda c: c("tie", "unknown prior"),
    "StudyInputError": lambda c: c("scans", "must be >= 1"),
    "SettingsError": lambda c: c("port", "must be 1-65535"),
    "EstimateUnavailable": lambda c: c("no model table loaded"),
    "QueueLocked": lambda c: c("--state: /tmp/x is in use by another watch"),
    "ManifestError": lambda c: c("manifest.csv row 3: plate_id is empty"),
    "StoreError": lambda c: c("'s.sqlite' fails its integrity check"),
    "StoreFull": lambda c: c("the store at 's.sqlite' cannot grow"),
    "SchemaTooOld": lambda c: c("'s.sqlite' has store schema 1"),
    "KeyTaken": lambda c: c("key-123"),
    "ClientGone": lambda c: c(),
    "ShotInputError": lambda c: c("shots.0.metadata.sphere_diameter", "'abc' is not a sphere "
                                  "diameter", "a number of metres, 0 < D <= 1"),
    "ShotLimitError": lambda c: c("metadata.plate_id", "201 characters; at most 200"),
    "ServerError": lambda c: c("404: setup_id: no set-up 'rig'"),
    "NoSuchPlate": lambda c: c("no measurement of plate 'P7'"),
    "SetupConflict": lambda c: c("set-up 'rig' has revision 3 now; this change was based on "
                                 "revision 2"),
    "SetupGone": lambda c: c("set-up 'rig' revision 2 is no longer stored"),
    "SetupError": lambda c: c("shots.0.metadata.sphere_diameter", "0.01905 m contradicts "
                              "setup 'rig' (revision 2)", "one of the set-up's sizes"),
    "Problem": lambda c: c(422, "shots[0].dt: must be > 0", kind="invalid-input",
                           field="shots[0].dt", headers={"Retry-After": "5"}),
}


def _exception_classes() -> list[type[BaseException]]:
    found: dict[str, type[BaseException]] = {}
    names = [info.name for layer in BASES
             for info in pkgutil.walk_packages(importlib.import_module(layer).__path__,
                                               f"{layer}.")]
    for name in names:
        module = importlib.import_module(name)
        for _, obj in inspect.getmembers(module, inspect.isclass):
            if issubclass(obj, BaseException) and obj.__module__ == module.__name__:
                found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return [found[k] for k in sorted(found)]


CLASSES = _exception_classes()


def test_every_exception_class_has_an_example() -> None:
    names = {c.__name__ for c in CLASSES}
    assert names == set(EXAMPLES), (names - set(EXAMPLES), set(EXAMPLES) - names)


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_one_base_per_layer_with_field_and_message(cls: type[BaseException]) -> None:
    layer = ".".join(cls.__module__.split(".")[:2])
    assert issubclass(cls, BASES[layer]), f"{cls.__module__}.{cls.__name__}"
    exc: Any = EXAMPLES[cls.__name__](cls)
    assert isinstance(exc.field, str | type(None)) and exc.message
    assert exc.message in str(exc)


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_pickling_round_trip(cls: type[BaseException]) -> None:
    exc: Any = EXAMPLES[cls.__name__](cls)
    back: Any = pickle.loads(pickle.dumps(exc))
    assert type(back) is cls
    assert str(back) == str(exc)
    assert back.args == exc.args
    assert vars(back) == vars(exc)


def test_an_error_raised_in_a_worker_process_arrives_as_itself() -> None:
    """What a process pool (table builds, validate) does with an error: pickle it back."""
    from concurrent.futures import ProcessPoolExecutor

    from solitonde.instrument.tables.table import TableError

    with ProcessPoolExecutor(max_workers=1) as pool:
        future = pool.submit(_raise_table_error)
        with pytest.raises(TableError) as info:
            future.result()
    assert info.value.field == "diameter_m"
    assert info.value.message == "no such sphere size"
    assert str(info.value) == "diameter_m: no such sphere size"


def _raise_table_error() -> None:
    from solitonde.instrument.tables.table import TableError

    raise TableError("diameter_m", "no such sphere size")
