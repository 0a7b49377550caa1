"""From request to stored measurement: waveforms, features, aggregates, estimate, store.

Everything here is synchronous and CPU-bound; the routes run it in a worker thread so the event
loop keeps serving other requests. Bad input raises :class:`~.problems.Problem` (422 naming the
field) before anything is written, so a rejected request never leaves a trace in the store.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from types import EllipsisType
from typing import Any

import numpy as np

from solitonde.instrument.inference import measured_shots
from solitonde.instrument.inference.calibration import Calibration
from solitonde.instrument.inference.loaded_table import EstimateUnavailable, LoadedTable
from solitonde.instrument.inference.measured_shots import ShotInputError
from solitonde.instrument.inference.pipeline import SizeSummary
from solitonde.instrument.inference.pipeline import estimate as estimate_from
from solitonde.instrument.inference.setups import Setup, SetupError
from solitonde.instrument.inference.table_set import TableChoiceError, TableSet
from solitonde.instrument.service.api_models import ShotMetadata
from solitonde.instrument.service.measurement_json import (
    EarlierEntry,
    EarlierResult,
    MeasurementJSON,
    MetadataDifference,
    Provenance,
    ShotJSON,
    StoredResult,
    TableRef,
)
from solitonde.instrument.service.problems import Problem
from solitonde.instrument.service.settings import Settings
from solitonde.instrument.service.store import (
    MeasurementRecord,
    ShotRecord,
    Store,
    samples_digest,
)
from solitonde.signal.errors import WaveformError
from solitonde.signal.features import Features
from solitonde.signal.json_ready import json_ready
from solitonde.signal.waveform import Waveform


def waveform_error(exc: WaveformError, prefix: str) -> Problem:
    """422 for a signal-layer error, with the field under the request's own path."""
    field = f"{prefix}.{exc.field}" if prefix else exc.field
    return Problem(422, f"{field}: {exc.full_message}", kind="invalid-input", field=field)


RESERVED_EXTRA = frozenset(ShotMetadata.model_fields) | {"source"}
"""Keys ``metadata.extra`` may not carry: the validated fields themselves (an extra value would
bypass their checks, e.g. a negative or textual sphere_diameter, or a null plate_id) and those the
service sets itself (``source`` names the upload's file)."""


def _meta(metadata: Any, where: str) -> dict[str, Any]:
    """A request's metadata model as a flat dict; ``where`` is its field path for errors."""
    if metadata is None:
        return {}
    meta = {k: v for k, v in metadata.model_dump(exclude={"extra"}).items() if v is not None}
    for key in metadata.extra:
        if key in RESERVED_EXTRA:
            field = f"{where}.extra.{key}"
            how = ("is set by the service" if key not in ShotMetadata.model_fields
                   else f"must be given as the field {where}.{key} itself")
            raise Problem(422, f"{field}: {key!r} is not a free-form key; it {how} (extra "
                          f"holds other keys; reserved: {', '.join(sorted(RESERVED_EXTRA))})",
                          kind="invalid-input", field=field)
    meta.update(metadata.extra)
    return meta


def waveforms_from_shots(shots: Sequence[Any], common: Any = None) -> list[Waveform]:
    """Validated request shots (``ShotIn`` models) as waveforms; ``common`` metadata (the
    request's top-level ``metadata``) applies to every shot unless the shot says otherwise."""
    out = []
    shared = _meta(common, "metadata")
    for i, shot in enumerate(shots):
        meta = {**shared, **_meta(shot.metadata, f"shots.{i}.metadata")}
        try:
            # fromiter: a third less time than asarray on a list of 10^4 floats
            samples = np.fromiter(shot.samples, np.float64, len(shot.samples))
            out.append(Waveform(t0=shot.t0, dt=shot.dt, samples=samples,
                                units=shot.units, calibration=shot.calibration, metadata=meta))
        except WaveformError as exc:
            raise waveform_error(exc, f"shots.{i}") from None
    return out


def waveforms_from_records(shots: Sequence[ShotRecord]) -> list[Waveform]:
    """Stored shots (with their samples) as waveforms again, for a reanalysis."""
    return [Waveform(t0=s.t0, dt=s.dt, samples=s.samples, units=s.units,
                     calibration=s.calibration, metadata=dict(s.metadata)) for s in shots]


def read_file(path: Path, fmt: str, options: Mapping[str, Any],
              client_name: str | None = None) -> list[Waveform]:
    """Read an uploaded file (instrument.inference.measured_shots); every failure becomes a 422
    on ``file``. ``options["calibration"]`` is the reader's override.

    Messages name ``client_name`` (the client's file name) where the readers name ``path``, the
    server's temporary file."""
    try:
        waveforms, _ = measured_shots.read_shots(path, fmt, options)
    except WaveformError as exc:
        name = client_name or "the upload"
        raise waveform_error(WaveformError(
            exc.field, exc.message.replace(path.name, name),
            exc.allowed.replace(path.name, name) if exc.allowed else None), "file") from None
    except TypeError as exc:
        raise Problem(422, f"file: reader options not accepted for {fmt}: {exc}",
                      kind="invalid-input", field="file") from None
    except Exception as exc:  # an untrusted file that breaks a parser is the client's error
        raise Problem(422, f"file: could not be read as {fmt} ({type(exc).__name__}: {exc})",
                      kind="invalid-input", field="file") from None
    if not waveforms:
        raise Problem(422, "file: holds no shots", kind="invalid-input", field="file")
    return waveforms


def check_counts(waveforms: Sequence[Waveform], settings: Settings, prefix: str) -> None:
    """Enforce shots per request, samples per shot and per request (the schema states them)."""
    if len(waveforms) > settings.max_shots_per_request:
        raise Problem(422, f"{prefix}: {len(waveforms)} shots; at most "
                      f"{settings.max_shots_per_request} per request", kind="limit",
                      field=prefix)
    for i, wf in enumerate(waveforms):
        if wf.n > settings.max_samples_per_shot:
            raise Problem(422, f"{prefix}.{i}.samples: {wf.n:,} samples; at most "
                          f"{settings.max_samples_per_shot:,} per shot", kind="limit",
                          field=f"{prefix}.{i}.samples")
    total = sum(wf.n for wf in waveforms)
    if total > settings.max_samples_per_request:
        raise Problem(422, f"{prefix}: {total:,} samples in all; at most "
                      f"{settings.max_samples_per_request:,} per request", kind="limit",
                      field=prefix)


def shot_problem(exc: ShotInputError) -> Problem:
    """422 for metadata the measured-shot road refuses, naming its field."""
    return Problem(422, str(exc), kind=exc.kind, field=exc.field)


def check_metadata(waveforms: Sequence[Waveform], prefix: str,
                   plate_size: Sequence[float] | None = None) -> None:
    """The measured-shot road's metadata checks (sizes, sphere size, position within
    ``plate_size``) on every shot, whatever set its metadata; a 422 naming the field under
    ``prefix``."""
    try:
        measured_shots.check_metadata([wf.metadata for wf in waveforms],
                                      measured_shots.shot_fields(prefix), plate_size)
    except ShotInputError as exc:
        raise shot_problem(exc) from None


def location_of(waveforms: Sequence[Waveform], prefix: str) -> tuple[str | None, str | None]:
    """The plate and position every shot shares; one measurement is one position."""
    try:
        return measured_shots.one_position([wf.metadata for wf in waveforms],
                                           measured_shots.shot_fields(prefix))
    except ShotInputError as exc:
        raise shot_problem(exc) from None


def measure_shots(waveforms: Sequence[Waveform], prefix: str
                  ) -> tuple[list[Features], list[str], list[SizeSummary]]:
    """Features per shot, the baseline each was measured on, and a summary per sphere
    diameter (the measured-shot road's :func:`~measured_shots.measure_waveform`)."""
    feats: list[Features] = []
    baselines: list[str] = []
    for i, wf in enumerate(waveforms):
        try:
            feat, baseline = measured_shots.measure_waveform(wf)
        except WaveformError as exc:  # an empty prefix: a lone shot whose fields are top-level
            raise waveform_error(exc, f"{prefix}.{i}" if prefix else "") from None
        feats.append(feat)
        baselines.append(baseline)
    return feats, baselines, measured_shots.summarise_shots(waveforms, feats)


def apply_setup(waveforms: Sequence[Waveform], setup: Setup | None,
                prefix: str) -> list[Waveform]:
    """The shots as ``setup`` completes them (:meth:`Setup.apply`: its size and table); a
    shot that contradicts it is a 422 naming the shot's field and the set-up's."""
    if setup is None:
        return list(waveforms)
    try:
        metas = setup.apply([wf.metadata for wf in waveforms], measured_shots.shot_fields(prefix))
    except SetupError as exc:
        raise Problem(422, str(exc), kind="invalid-input", field=exc.field) from None
    return [Waveform(t0=wf.t0, dt=wf.dt, samples=wf.samples, units=wf.units,
                     calibration=wf.calibration, metadata=meta)
            for wf, meta in zip(waveforms, metas, strict=True)]


def warm_up() -> float:
    """Run the feature extractor once on a synthetic shot; returns the seconds it took.

    The signal kernels are numba-compiled (cached on disk, but loaded on first use); doing it in
    the lifespan keeps that out of the first requests' latency. On a fresh install they compile
    in the background and this runs them interpreted (:mod:`solitonde.signal.kernel_choice`), so
    the service is ready in seconds and its first shots are answered before the compile ends.
    """
    import time

    from solitonde.signal.synth import pulse_train

    started = time.perf_counter()
    dt = 5e-7
    samples = pulse_train(4000, dt, [(300e-6, 50.0, 40e-6), (900e-6, 30.0, 40e-6)])
    samples = samples + 0.01 * np.sin(np.arange(samples.size))  # a little "noise"
    wf = Waveform(0.0, dt, samples, metadata={"sphere_diameter": 9.53e-3})
    measure_shots([wf, wf], "warm_up")
    return time.perf_counter() - started


def shot_out(index: int, wf: Waveform, features: Features, baseline: str) -> ShotJSON:
    """A measured shot as the API shows it; its features name the baseline they used."""
    return {"shot_index": index, "metadata": json_ready(wf.metadata), "n_samples": wf.n,
            "t0": wf.t0, "dt": wf.dt, "units": wf.units,
            "features": {**json_ready(features.to_dict()), "baseline": baseline}}


def choose_table(waveforms: Sequence[Waveform], tables: TableSet,
                 prefix: str) -> LoadedTable | None:
    """The table for these shots (their ``table`` / ``plate_material`` and sphere sizes), or
    None when the service has none; a 422 naming ``table`` or ``plate_material`` (under
    ``metadata.`` for a JSON body) when none fits or several could serve."""
    if not tables.loaded:
        return None
    meta = waveforms[0].metadata
    diameters = {float(w.metadata["sphere_diameter"]) for w in waveforms
                 if w.metadata.get("sphere_diameter") is not None}
    try:
        return tables.choose(diameters, meta.get("table"), meta.get("plate_material"))
    except TableChoiceError as exc:
        # a JSON body states it in metadata; an upload's form and the raw route's query as such
        field = f"metadata.{exc.field}" if prefix == "shots" else exc.field
        raise Problem(422, f"{field}: {exc.message}", kind="invalid-input", field=field) from None


def provenance(chosen: LoadedTable | None, waveforms: Sequence[Waveform] = (),
               setup: Setup | None = None,
               calibration: Calibration | None = None) -> Provenance:
    """What a result was computed with: the software version, the feature extractor and its
    settings (the defaults, and the chain's options each stated sphere size added), the table
    (id and SHA-256 of its file) or None, the set-up revision and its chain calibration (or
    None), and when."""
    import dataclasses
    import time

    from solitonde.instrument.inference.chain_geometry import shot_options
    from solitonde.model.version import package_version
    from solitonde.signal.pulses import DetectOptions

    version = package_version()
    table: TableRef | None = None
    if chosen is not None:
        table = {"id": chosen.model.table_id, "sha256": chosen.model.content_sha256}
    return {"software_version": version,
            "extractor": {"function": "solitonde.instrument.inference.chain_geometry.measure_shot",
                          "options": json_ready(dataclasses.asdict(DetectOptions())),
                          "chain_options": {
                              f"{d}": shot_options(d) for d in
                              {wf.metadata.get("sphere_diameter") for wf in waveforms}
                              if shot_options(d)}},
            "table": table,
            "setup": None if setup is None else setup.reference(),
            "chain_calibration": None if calibration is None else calibration.to_dict(),
            "computed_at": time.time()}


def compute_result(waveforms: Sequence[Waveform], tables: TableSet, prefix: str,
                   chosen: LoadedTable | EllipsisType | None = ..., setup: Setup | None = None,
                   calibration: Calibration | None = None
                   ) -> tuple[list[ShotJSON], StoredResult]:
    """Features of every shot (as the API shows them) and the measurement's result: aggregates,
    estimate (or why none), the table, the location, the provenance. ``chosen``: the table a
    caller already chose (:func:`choose_table`) and checked the metadata against; ``setup``:
    the set-up the shots were completed with (:func:`apply_setup`), whose chain calibration
    the estimate applies; ``calibration``: a chain calibration of no set-up (a file's, offline)."""
    if setup is not None and setup.chain_calibration is not None:
        calibration = setup.calibration()  # one calibration: callers refuse a second one
    if chosen is ...:
        chosen = choose_table(waveforms, tables, prefix)
        check_metadata(waveforms, prefix, chosen.plate_size() if chosen else None)
    feats, baselines, summaries = measure_shots(waveforms, prefix)
    estimate, reason = None, tables.reason
    if chosen is not None:
        try:
            estimate = estimate_from(tables, summaries, calibration,
                                     table=chosen,
                                     plate_material=waveforms[0].metadata.get(
                                         "plate_material")).to_dict()
            reason = None
        except EstimateUnavailable as exc:
            reason = str(exc)
        except Exception as exc:  # an inversion that refuses these features (e.g. out of range)
            reason = f"inversion failed: {exc}"
    shots = [shot_out(i, wf, f, b) for i, (wf, f, b)
             in enumerate(zip(waveforms, feats, baselines, strict=True))]
    result: StoredResult = {"aggregates": [m.to_dict() for m in summaries],
                            "estimate": estimate, "estimate_reason": reason,
                            "table": chosen.model.table_id if chosen else None}
    coordinates = {k: float(waveforms[0].metadata[k]) for k in ("x_m", "y_m")
                   if waveforms[0].metadata.get(k) is not None}
    if coordinates:  # where on the plate, for the estimates export
        result["location"] = coordinates
    result["provenance"] = provenance(chosen, waveforms, setup, calibration)
    return shots, result


def measure_and_store(waveforms: Sequence[Waveform], store: Store, tables: TableSet,
                      source: str, prefix: str,
                      idempotency: tuple[str, str] | None = None,
                      allow_duplicate: bool = False,
                      setup: Setup | None = None,
                      calibration: Calibration | None = None) -> MeasurementJSON:
    """Analyse the shots, estimate, store in one transaction; the stored measurement as a dict.

    Shots whose samples are, in order, a stored measurement's are not stored again (unless
    ``allow_duplicate``): the answer is that measurement with ``duplicate_of`` (its id) and
    ``metadata_differences`` (what the request says otherwise, per shot). With ``setup`` the
    shots are completed by it and estimated with its chain calibration, and the measurement
    records the revision."""
    waveforms = apply_setup(waveforms, setup, prefix)
    plate_id, position = location_of(waveforms, prefix)
    chosen = choose_table(waveforms, tables, prefix)  # the checks a new one would get first
    check_metadata(waveforms, prefix, chosen.plate_size() if chosen else None)
    if not allow_duplicate:
        found = store.same_samples([samples_digest(wf.samples) for wf in waveforms])
        record = None if found is None else store.get(found)
        if record is not None:
            return {**measurement_dict(record), "duplicate_of": record.id,
                    "metadata_differences": metadata_differences(waveforms, record)}
    shots, result = compute_result(waveforms, tables, prefix, chosen, setup, calibration)
    records = [ShotRecord(t0=wf.t0, dt=wf.dt, samples=wf.samples, units=wf.units,
                          calibration=wf.calibration, metadata=s["metadata"],
                          features=s["features"], shot_index=i)
               for i, (wf, s) in enumerate(zip(waveforms, shots, strict=True))]
    new_id, created_at = store.add(records, result, source=source, plate_id=plate_id,
                                   position=position, idempotency=idempotency,
                                   setup=None if setup is None else (setup.id, setup.revision))
    return measurement_dict(MeasurementRecord(
        id=new_id, created_at=created_at, plate_id=plate_id, position=position,
        n_shots=len(records), source=source, result=result, shots=records))


def metadata_differences(waveforms: Sequence[Waveform],
                         record: MeasurementRecord) -> list[MetadataDifference]:
    """Per shot, the metadata keys whose value a request states otherwise than the stored
    measurement ``record`` (``stored`` and ``sent``, JSON values)."""
    out: list[MetadataDifference] = []
    for i, (wf, shot) in enumerate(zip(waveforms, record.shots, strict=True)):
        sent, stored = json_ready(dict(wf.metadata)), shot.metadata
        for key in sorted(set(sent) | set(stored)):
            if sent.get(key) != stored.get(key):
                out.append({"shot": i, "key": key, "stored": stored.get(key),
                            "sent": sent.get(key)})
    return out


def measurement_dict(record: MeasurementRecord) -> MeasurementJSON:
    """A stored measurement as the API returns it."""
    return {
        "id": record.id,
        "created_at": record.created_at,
        "plate_id": record.plate_id,
        "position": record.position,
        "n_shots": record.n_shots,
        "source": record.source,
        "shots": [{"shot_index": s.shot_index, "metadata": s.metadata,
                   "n_samples": s.n_samples, "t0": s.t0,
                   "dt": s.dt, "units": s.units, "features": s.features} for s in record.shots],
        "aggregates": record.result.get("aggregates", []),
        "estimate": record.result.get("estimate"),
        "estimate_reason": record.result.get("estimate_reason"),
        "table": record.result.get("table"),
        "location": record.result.get("location"),
        "provenance": record.result.get("provenance"),
        "earlier_results": [_earlier(e) for e in getattr(record, "earlier", [])],
        "links": {"self": f"/v1/measurements/{record.id}",
                  "plot": f"/v1/measurements/{record.id}/plot.png"},
    }


def _earlier(entry: EarlierEntry) -> EarlierResult:
    """An earlier result of a measurement, as the API lists it."""
    result = entry["result"]
    return {"superseded_at": entry["superseded_at"],
            "provenance": result.get("provenance"), "table": result.get("table"),
            "aggregates": result.get("aggregates", []), "estimate": result.get("estimate"),
            "estimate_reason": result.get("estimate_reason"),
            "shot_features": entry["shot_features"]}
