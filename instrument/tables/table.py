"""The model table: simulated features over a grid of sphere diameter, plate thickness and distance.

One HDF5 file (h5py) holds

``axes/``        ``diameter_m``, ``thickness_m``, ``distance_m`` (increasing), the grid
``features/``    per point (shape ``(nD, nT, nL)``): ``tof_s``, ``arr``, ``incident_time_s``,
                 ``incident_peak_N``, ``reflected_peak_N``, ``snr_db``, ``arr_upper_bound``; and
                 ``secondary_times_s`` / ``secondary_ratios`` (shape ``(nD, nT, nL, K)``,
                 NaN-padded): what :func:`solitonde.signal.features.extract` reads from the
                 simulated sensor trace, exactly as from a measurement
``status``       per point: 0 ok, 1 no reflection detected, 2 failed (``messages`` says why),
                 -1 not computed yet
``done``         per point: the build's resume mask
``flags``        per point: bitmask of the signal package's quality flags (``attrs['flag_names']``)
``plate_model``  per point: index into ``attrs['plate_model_names']`` (the tier ``auto`` chose)
``diagnostics/`` ``wall_s``, ``energy_drift`` per point
``traces/``      optional: per point the sensor samples (variable length) with ``t0_s``, ``dt_s``

and, in the root attributes, the sweep that defines the grid and the provenance (JSON strings):
solitonde version, scene defaults, tiers, mesh, step, build time, machine, git revision.
Missing values are NaN, never a number made up.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypedDict

import h5py
import numpy as np

from solitonde.instrument.errors import InstrumentError
from solitonde.model.scene import PLATE_MODELS, SceneDict
from solitonde.signal.pulses import DetectKeywords

if TYPE_CHECKING:
    from solitonde.instrument.tables.family import Family

FORMAT = "solitonde-model-table"
FORMAT_VERSION = 1
AXES = ("diameter_m", "thickness_m", "distance_m")
ScalarFeature = Literal["tof_s", "arr", "incident_time_s", "incident_peak_N", "reflected_peak_N",
                        "snr_db", "arr_upper_bound"]
SecondaryFeature = Literal["secondary_times_s", "secondary_ratios"]
SCALAR_FEATURES: tuple[ScalarFeature, ...] = (
    "tof_s",
    "arr",
    "incident_time_s",
    "incident_peak_N",
    "reflected_peak_N",
    "snr_db",
    "arr_upper_bound",
)
SECONDARY_FEATURES: tuple[SecondaryFeature, ...] = ("secondary_times_s", "secondary_ratios")
MAX_SECONDARY = 4
STATUS_PENDING, STATUS_OK, STATUS_NO_REFLECTION, STATUS_FAILED = -1, 0, 1, 2
STATUS_NAMES = {
    STATUS_PENDING: "pending",
    STATUS_OK: "ok",
    STATUS_NO_REFLECTION: "no_reflection",
    STATUS_FAILED: "failed",
}
PLATE_MODEL_NAMES = (*(m for m in PLATE_MODELS if m != "auto"), "unknown")


class TableError(InstrumentError, ValueError):
    """A table file that cannot be used; ``field`` names what is wrong."""



LAYER = "dissipation"
"""The group holding the table's features simulated with contact damping (``table build
--dissipation-layer`` and ``table dissipation`` write it: instrument.tables.dissipation)."""
LAYER_FEATURES = ("tof_s", "arr", "arr_upper_bound")


@dataclass(frozen=True)
class DissipationLayer:
    """The table's features simulated at contact dampings ``damping_s`` (increasing, one slice
    each, on the table's grid)."""

    damping_s: tuple[float, ...]
    features: dict[str, np.ndarray]
    """name -> array of shape ``(K,) + the table's shape``."""
    status: np.ndarray

    def merged(self, other: DissipationLayer) -> DissipationLayer:
        """Both layers' slices, sorted; ``other``'s replaces a slice at the same damping."""
        keep = [k for k, tau in enumerate(self.damping_s)
                if all(abs(tau - t) > 1e-9 * t for t in other.damping_s)]
        taus = [self.damping_s[k] for k in keep] + list(other.damping_s)
        order = np.argsort(taus)
        feats = {n: np.concatenate([self.features[n][keep], other.features[n]])[order]
                 for n in LAYER_FEATURES}
        status = np.concatenate([self.status[keep], other.status])[order]
        return DissipationLayer(tuple(float(taus[i]) for i in order), feats, status)


def read_layer(fh: h5py.File, shape: tuple[int, ...]) -> DissipationLayer | None:
    """The stored layer, or None for a table without one. TableError for a malformed group."""
    if LAYER not in fh:
        return None
    group = fh[LAYER]
    try:
        taus = tuple(float(x) for x in np.atleast_1d(group.attrs["damping_s"]))
    except (KeyError, TypeError, ValueError):
        raise TableError(f"{LAYER}.damping_s", "attribute missing or not numbers") from None
    if not taus or not all(np.isfinite(t) and t > 0 for t in taus) or any(
            b <= a for a, b in itertools.pairwise(taus)):
        raise TableError(f"{LAYER}.damping_s", f"must be increasing and > 0, got {list(taus)}")
    want = (len(taus), *shape)
    arrays: dict[str, np.ndarray] = {}
    for name, dtype in (*((f, float) for f in LAYER_FEATURES), ("status", np.int8)):
        values = np.asarray(group[name][...], dtype=dtype) if name in group else None
        if values is None or values.shape != want:
            raise TableError(f"{LAYER}/{name}", f"expected shape {want}, got "
                             f"{None if values is None else values.shape}")
        arrays[name] = values
    status = arrays.pop("status")
    return DissipationLayer(taus, arrays, status)


class SweepDict(TypedDict):
    """A table's sweep as its file stores it (the attribute ``sweep``, JSON): the grid axes, the
    base scene (any scene keys), whether traces are kept, the extractor's options
    (:class:`~.sweep.Sweep`)."""

    diameters_m: list[float]
    thicknesses_m: list[float]
    distances_m: list[float]
    scene: SceneDict
    traces: bool
    detect: DetectKeywords


class BuildMachine(TypedDict):
    """The machine a table was built on."""

    node: str
    system: str
    processor: str
    cpus: int | None
    python: str


class StepRange(TypedDict):
    """The smallest and largest integration step the table's points took, s."""

    min: float
    max: float


class Session(TypedDict):
    """One build session (a resumed build has several), in the attribute ``sessions``."""

    started_at: str
    git_revision: str | None
    runner: str
    points_done_before: int


class TableProvenance(TypedDict, total=False):
    """How, where and from what code a table was built (the attribute ``provenance``). Every key
    may be missing: a table written before a key was recorded lacks it, and a later version may
    add keys."""

    solitonde_version: str
    git_revision: str | None
    sessions: list[Session]
    """The build's sessions (resumed builds have several)."""
    built_at: str
    """ISO 8601, UTC."""
    build_wall_s: float
    point_cpu_s: float
    runner: str
    command: str | None
    machine: BuildMachine
    scene_defaults: SceneDict
    """The base scene with every default spelled out (:meth:`Scene.to_dict`)."""
    table_id: str
    tiers: list[str]
    mesh: dict[str, Any] | None
    """The plate mesh's description, as the meshed tier reports it."""
    step_s: StepRange | None
    pretrigger_fraction: float
    feature_extractor: str


class AxisSummary(TypedDict):
    values: list[float]
    min: float
    max: float
    n: int


class DissipationSummary(TypedDict):
    damping_s: list[float]


class TableSummary(TypedDict):
    """A table as :meth:`ModelTable.summary` describes it (``table info --json``, and the
    service's ``GET /v1/table``), in this order."""

    id: str
    path: str | None
    family: Family | None
    format: str
    format_version: int
    reading_version: int
    complete: bool
    shape: list[int]
    n_points: int
    axes: dict[str, AxisSummary]
    features: list[str]
    status_counts: dict[str, int]
    plate_models: dict[str, int]
    sweep: SweepDict
    provenance: TableProvenance
    dissipation_layer: DissipationSummary | None


@dataclass
class ModelTable:
    """A loaded model table (everything in memory; a table is a few MB).

    Attributes
    ----------
    axes: grid axes by name (:data:`AXES`), increasing, SI units.
    features: per-point arrays by name (:data:`SCALAR_FEATURES`, :data:`SECONDARY_FEATURES`).
    status: per-point status codes (:data:`STATUS_NAMES`).
    flags: per-point bitmask over ``flag_names``.
    plate_model: per-point index into ``plate_model_names``.
    diagnostics: per-point ``wall_s`` and ``energy_drift``.
    sweep: the sweep definition the table was built from.
    provenance: how and where it was built.
    complete: every point was computed.
    """

    axes: dict[str, np.ndarray]
    features: dict[str, np.ndarray]
    status: np.ndarray
    flags: np.ndarray
    plate_model: np.ndarray
    diagnostics: dict[str, np.ndarray]
    sweep: SweepDict
    provenance: TableProvenance
    complete: bool
    flag_names: tuple[str, ...] = ()
    plate_model_names: tuple[str, ...] = PLATE_MODEL_NAMES
    path: Path | None = None
    material_slopes: dict[str, np.ndarray] | None = None
    """The features' slopes along ``ln E'`` and ``ln rho`` far from the supports, per sphere
    size and thickness (:mod:`.material_slopes`); None for a table built before them."""
    dissipation: DissipationLayer | None = None
    """The features simulated with contact damping (:mod:`.dissipation`), or None for a table
    without that layer."""
    reading_version: int = 1
    """How the table's points were read (:data:`solitonde.signal.features.EXTRACTOR_VERSION` of the
    build; 1 for a table that does not say)."""
    model_variance: dict[str, np.ndarray] | None = None
    """Per-node variance of ``tof_s`` and ``arr`` the inversion adds to the table's
    interpolation error (a table read at a fitted damping: :func:`.dissipation.damped`)."""
    _cache: dict[Any, Any] = field(default_factory=dict, repr=False)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.axes[a].size for a in AXES)

    @property
    def table_id(self) -> str:
        """The id given at build (``table build --id``), else the file's stem."""
        given = self.provenance.get("table_id")
        return str(given) if given else (self.path.stem if self.path else "table")

    @property
    def content_sha256(self) -> str | None:
        """SHA-256 of the file's bytes when it was loaded (None for a table built in memory):
        results name the exact table they were computed with."""
        return self._cache.get("sha256")

    @property
    def family(self) -> Family | None:
        """The plate family the table was built for (instrument.family), None if unrecorded."""
        if "family" not in self._cache:
            from solitonde.instrument.tables.family import family_of_table

            self._cache["family"] = family_of_table(self.provenance)
        return self._cache["family"]

    @classmethod
    def load(cls, path: str | Path) -> ModelTable:
        """Read a table file written by :mod:`solitonde.instrument.tables.table_build`.

        Raises
        ------
        TableError
            When the file is missing, is not a model table, has a newer format, or lacks a
            dataset or attribute, has one of the wrong shape, or an axis that is not finite and
            strictly increasing (the field names the dataset, e.g. ``features/arr``).
        """
        path = Path(path)
        if not path.is_file():
            raise TableError("table", f"no such file: {str(path)!r}")
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        try:
            fh = h5py.File(path, "r")
        except OSError as exc:
            raise TableError("table", f"{str(path)!r} is not an HDF5 file ({exc})") from None
        with fh:
            if fh.attrs.get("format") != FORMAT:
                raise TableError("table", f"{str(path)!r} is not a solitonde model table")
            try:
                version = int(fh.attrs.get("format_version", 0))
            except (TypeError, ValueError):
                raise TableError("format_version", f"expected an integer, got "
                                 f"{fh.attrs.get('format_version')!r}") from None
            if version > FORMAT_VERSION:
                raise TableError("format_version", f"table format {version} is newer than this "
                                 f"solitonde reads (up to {FORMAT_VERSION})")
            axes = {a: _axis(fh, a) for a in AXES}
            grid = tuple(axes[a].size for a in AXES)
            features: dict[str, np.ndarray] = {
                k: _dataset(fh, f"features/{k}", float, grid) for k in SCALAR_FEATURES}
            features |= {k: _dataset(fh, f"features/{k}", float, grid, trailing=True)
                         for k in SECONDARY_FEATURES}
            diag = {}
            if "diagnostics" in fh:
                diag = {k: _dataset(fh, f"diagnostics/{k}", None, grid)
                        for k in fh["diagnostics"]}
            table = cls(
                axes=axes,
                features=features,
                status=_dataset(fh, "status", np.int8, grid),
                flags=_dataset(fh, "flags", np.int32, grid),
                plate_model=_dataset(fh, "plate_model", np.int8, grid),
                diagnostics=diag,
                sweep=_json_attr(fh, "sweep", None, dict),
                provenance=_json_attr(fh, "provenance", "{}", dict),
                complete=bool(fh.attrs.get("complete", False)),
                flag_names=tuple(_json_attr(fh, "flag_names", "[]", list)),
                plate_model_names=tuple(_json_attr(fh, "plate_model_names", "[]", list))
                or PLATE_MODEL_NAMES,
                path=path,
                material_slopes=read_slopes(fh, grid),
                dissipation=read_layer(fh, grid),
                reading_version=reading_version_of(fh),
            )
            table._cache["sha256"] = digest
            return table

    def simulated_on(self, i_d: int, models: Sequence[str]) -> np.ndarray:
        """(n_t, n_l) mask of sphere size ``i_d``'s nodes simulated on one of the plate
        ``models`` (names of :attr:`plate_model_names`; names the table lacks match nothing)."""
        codes = [self.plate_model_names.index(m) for m in models if m in self.plate_model_names]
        return np.isin(self.plate_model[i_d], codes)

    def diameter_index(self, diameter: float, rel_tol: float = 0.01) -> int:
        """Index of ``diameter`` (m) on the diameter axis.

        Raises
        ------
        TableError
            When no table diameter lies within ``rel_tol`` of it (the table is not interpolated
            across sphere sizes: that would be extrapolating the physics).
        """
        d = self.axes["diameter_m"]
        i = int(np.argmin(np.abs(d - diameter)))
        if not np.isfinite(diameter) or abs(d[i] - diameter) > rel_tol * d[i]:
            listed = ", ".join(f"{x * 1e3:.4g}" for x in d)
            raise TableError("diameter_m", f"{diameter!r} m is not a sphere size of this table "
                             f"(table diameters: {listed} mm)")
        return i

    def status_counts(self) -> dict[str, int]:
        values, counts = np.unique(self.status, return_counts=True)
        return {STATUS_NAMES.get(int(v), str(int(v))): int(c) for v, c in zip(values, counts,
                                                                              strict=True)}

    def summary(self) -> TableSummary:
        """JSON-ready description: axes (values and ranges), point counts, provenance."""
        models, counts = np.unique(self.plate_model, return_counts=True)
        return {
            "id": self.table_id,
            "path": str(self.path) if self.path else None,
            "family": self.family,
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "reading_version": self.reading_version,
            "complete": self.complete,
            "shape": list(self.shape),
            "n_points": int(np.prod(self.shape)),
            "axes": {a: {"values": self.axes[a].tolist(), "min": float(self.axes[a][0]),
                         "max": float(self.axes[a][-1]), "n": int(self.axes[a].size)}
                     for a in AXES},
            "features": [*SCALAR_FEATURES, *SECONDARY_FEATURES],
            "status_counts": self.status_counts(),
            "plate_models": {self.plate_model_names[int(m)] if 0 <= m < len(self.plate_model_names)
                             else str(int(m)): int(c) for m, c in zip(models, counts, strict=True)},
            "sweep": self.sweep,
            "provenance": self.provenance,
            "dissipation_layer": (None if self.dissipation is None
                                  else {"damping_s": list(self.dissipation.damping_s)}),
        }


# Reading and checking a table file ---------------------------------------------------------------


def reading_version_of(fh: h5py.File) -> int:
    """The table's ``reading_version`` attribute (1 where it has none)."""
    raw = fh.attrs.get("reading_version", 1)
    try:
        return int(raw)
    except (TypeError, ValueError):
        raise TableError("reading_version", f"expected an integer, got {raw!r}") from None


MATERIAL_SLOPES = "material_slopes"
"""The group holding how the features move with the plate material (``table build`` writes it:
instrument.tables.material_slopes)."""
SLOPE_COMPONENTS = ("ln_e_prime", "ln_rho")


def require_complete(path: str | Path) -> None:
    """TableError unless ``path`` is a complete table file (before work that would be lost)."""
    with h5py.File(path, "r") as fh:
        if fh.attrs.get("format") != FORMAT or not fh.attrs.get("complete", False):
            raise TableError("table", f"{str(path)!r} is not a complete solitonde model table")


def add_to_file(path: str | Path, suffix: str, write: Callable[[h5py.File], None],
                check: Callable[[h5py.File], object]) -> None:
    """Add a group to the complete table file at ``path``: ``write`` on a copy (``<name><suffix>``),
    ``check`` reading it back, then the copy renamed onto the file, so an interrupted or failed
    run leaves the table as it was. TableError when ``path`` is not a complete table."""
    path = Path(path)
    require_complete(path)
    part = path.with_name(path.name + suffix)
    shutil.copyfile(path, part)
    try:
        with h5py.File(part, "r+") as fh:
            write(fh)
        with h5py.File(part, "r") as fh:
            check(fh)
        os.replace(part, path)
    finally:
        part.unlink(missing_ok=True)


def read_slopes(fh: h5py.File, shape: tuple[int, ...]) -> dict[str, np.ndarray] | None:
    """The stored slopes, or None for a table built before they were (the inversion then uses
    the exchange rates alone). Raises TableError for a group of the wrong shape."""
    if MATERIAL_SLOPES not in fh:
        return None
    want = (shape[0], shape[1], len(SLOPE_COMPONENTS))
    out = {}
    for name in ("tof_s", "arr"):
        group = fh[MATERIAL_SLOPES]
        values = np.asarray(group[name][...], dtype=float) if name in group else None
        if values is None or values.shape != want:
            raise TableError(f"{MATERIAL_SLOPES}/{name}", f"expected shape {want}, got "
                             f"{None if values is None else values.shape}")
        out[name] = values
    return out


def _read(fh: h5py.File, name: str, dtype: Any) -> np.ndarray:
    """Dataset ``name`` as an array of ``dtype`` (None: as stored); TableError naming it when it
    is absent or cannot be read so."""
    obj = fh.get(name)
    if not isinstance(obj, h5py.Dataset):
        raise TableError(name, "missing from the table file (not a complete solitonde table; "
                         "rebuild it with `solitonde table build`)")
    try:
        return np.asarray(obj[...], dtype=dtype)
    except (TypeError, ValueError, OSError) as exc:
        kind = "numbers" if dtype is None else np.dtype(dtype).name
        raise TableError(name, f"cannot be read as {kind} ({exc})") from None


def _dataset(fh: h5py.File, name: str, dtype: Any, grid: tuple[int, ...],
             trailing: bool = False) -> np.ndarray:
    """Dataset ``name`` as an array of ``dtype`` (None: as stored) with shape ``grid`` (plus one
    trailing axis when ``trailing``); TableError naming it when absent or of another shape."""
    data = _read(fh, name, dtype)
    if data.shape[:3] != grid or data.ndim != (4 if trailing else 3):
        want = f"{grid} + (K,)" if trailing else str(grid)
        raise TableError(name, f"has shape {data.shape}, but the axes give {want} "
                         "(diameter_m, thickness_m, distance_m)")
    return data


def _axis(fh: h5py.File, name: str) -> np.ndarray:
    """Axis ``name``: one or more finite values, strictly increasing; sizes positive, distances
    non-negative."""
    field_name = f"axes/{name}"
    values = _read(fh, field_name, float)
    if values.ndim != 1 or values.size < 1:
        raise TableError(field_name, f"must be a 1-D axis of at least one value, got shape "
                         f"{values.shape}")
    if not np.all(np.isfinite(values)):
        raise TableError(field_name, "holds a non-finite value")
    if np.any(np.diff(values) <= 0):
        raise TableError(field_name, f"must be strictly increasing, got {values.tolist()}")
    if name == "distance_m" and values[0] < 0:
        raise TableError(field_name, f"must be >= 0 m, got {values[0]!r}")
    if name != "distance_m" and values[0] <= 0:
        raise TableError(field_name, f"must be > 0 m, got {values[0]!r}")
    return values


def _json_attr(fh: h5py.File, name: str, default: str | None, kind: type) -> Any:
    """Root attribute ``name`` decoded from JSON, of type ``kind``; required when no default."""
    raw = fh.attrs.get(name, default)
    if raw is None:
        raise TableError(name, "attribute missing from the table file (not a complete solitonde "
                         "table; rebuild it with `solitonde table build`)")
    try:
        value = json.loads(raw)
    except (TypeError, ValueError) as exc:
        raise TableError(name, f"attribute is not JSON ({exc})") from None
    if not isinstance(value, kind):
        raise TableError(name, f"attribute must be a JSON {'object' if kind is dict else 'list'},"
                         f" got {type(value).__name__}")
    return value
