"""`solitonde post`: send waveform files to a running service, each stored exactly once.

Each file goes up through the REST upload (multipart ``POST /v1/measurements``) with the
metadata analyze takes (``--plate-id``, ``--position``, ``--x``, ``--y``, ``--sphere-diameter``,
``--calibration`` ... or a campaign ``--manifest``) and an ``Idempotency-Key`` made from the
file's content and that metadata (instrument.cli.uploader): posting the same file again answers
with the stored measurement (``replayed``), never a second one. A transient failure (no answer,
429, 503 ...) is retried a few times with a growing pause; the key makes that safe.

Exit codes as analyze: 0 every file stored (or replayed), 1 some failed, 2 usage (a missing
file, a bad option or manifest).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import Any, TypedDict, cast

import typer

from solitonde.instrument.cli.common import sphere_sizes
from solitonde.instrument.cli.uploader import (
    Client,
    Outcome,
    api_key_from,
    fields_for,
    manifest_row_for,
    status_line,
)


class UploadForm(TypedDict, total=False):
    """The command line's metadata as an upload's form fields (only those given)."""

    plate_id: str
    position: str
    x_m: float
    y_m: float
    sphere_diameter: float
    calibration: float
    units: str
    sample_rate: float
    format: str
    channel: str
    group: str
    plate_material: str
    table: str
    setup: str
    allow_duplicate: str


UPLOAD_FORMATS = ("csv", "npy", "npz", "hdf5", "tdms", "json")
"""What the service's upload reads (``--format`` names one)."""

# The options post and watch share (typer takes the same OptionInfo in both signatures).
SERVER = typer.Option(..., "--server", help="The service's base URL, e.g. "
                      "http://192.168.1.20:8000.")
API_KEY_ENV = typer.Option("SOLITONDE_API_KEY", "--api-key-env", help="Environment variable "
                           "that holds the server's API key (sent as X-API-Key when set).")
PLATE_ID = typer.Option(None, "--plate-id", help="Plate, for every file.")
POSITION = typer.Option(None, "--position", help="Position name, for every file.")
X = typer.Option(None, "--x", help="m, the position's x on the plate.")
Y = typer.Option(None, "--y", help="m, the position's y on the plate.")
SPHERE = typer.Option(None, "--sphere-diameter", callback=sphere_sizes, help="m, for every file "
                      "(a file's own must agree).")
CALIBRATION = typer.Option(None, "--calibration", help="N/V, for files in volts that carry "
                           "no calibration.")
UNITS = typer.Option(None, "--units", help="N or V, for data that do not state their units.")
SAMPLE_RATE = typer.Option(None, "--sample-rate", help="Hz, for data without a time axis.")
FORMAT = typer.Option(None, "--format", help="Force a format: " + ", ".join(UPLOAD_FORMATS)
                      + " (default: from each file's suffix).")
CHANNEL = typer.Option(None, "--channel", help="Analyse this channel (a column name, or a "
                       "TDMS channel as group/channel). Default: the sensor traces.")
GROUP = typer.Option(None, "--group", help="Only the channels of this TDMS group.")
MATERIAL = typer.Option(None, "--plate-material", help="The plate's material (a library "
                        "name, or its properties as JSON): the server estimates with the table "
                        "of that family.")
TABLE = typer.Option(None, "--table", help="The server's model table to estimate with, by id "
                     "(GET /v1/tables; where several could serve).")
ALLOW_DUPLICATE = typer.Option(False, "--allow-duplicate", help="Store a file's shots even where "
                               "the service holds the same samples already (by default it "
                               "answers with that measurement: duplicate).")
SETUP = typer.Option(None, "--setup", help="The server's instrument set-up, by id (GET "
                     "/v1/setups): its sphere size, table and chain calibration for every file.")
MANIFEST = typer.Option(None, "--manifest", help="Campaign manifest (.csv or .yaml): per file "
                        "or glob, plate_id, position, x_m, y_m, sphere_diameter_m, "
                        "calibration_N_per_V.")
AS_JSON = typer.Option(False, "--json", help="Print one JSON object per file (id, state, "
                       "estimate) instead of status lines.")


def given_fields(plate_id: str | None, position: str | None, x: float | None,
                 y: float | None, sphere_diameter: float | None, calibration: float | None,
                 units: str | None, sample_rate: float | None, fmt: str | None,
                 channel: str | None, group: str | None, plate_material: str | None,
                 table: str | None = None, allow_duplicate: bool = False,
                 setup: str | None = None) -> UploadForm:
    """The command line's metadata as the upload's form fields; a bad value is a
    :class:`typer.BadParameter` naming the flag and what is allowed."""
    for flag, value in (("--x", x), ("--y", y), ("--sample-rate", sample_rate),
                        ("--calibration", calibration)):
        if value is not None and not math.isfinite(value):
            raise typer.BadParameter(f"{value} is not a finite number", param_hint=flag)
    for flag, value in (("--sample-rate", sample_rate), ("--calibration", calibration)):
        if value is not None and value <= 0:
            raise typer.BadParameter(f"{value:g} must be > 0", param_hint=flag)
    if units is not None and units not in ("N", "V"):
        raise typer.BadParameter(f"{units!r} is not N or V", param_hint="--units")
    if fmt is not None and fmt.lower() not in (*UPLOAD_FORMATS, "h5"):
        raise typer.BadParameter(f"{fmt!r} is not one of {', '.join(UPLOAD_FORMATS)}",
                                 param_hint="--format")
    fields = {"plate_id": plate_id, "position": position, "x_m": x, "y_m": y,
              "sphere_diameter": sphere_diameter, "calibration": calibration, "units": units,
              "sample_rate": sample_rate, "format": fmt, "channel": channel, "group": group,
              "plate_material": plate_material, "table": table, "setup": setup,
              "allow_duplicate": "true" if allow_duplicate else None}
    return cast(UploadForm, {k: v for k, v in fields.items() if v is not None})


def load_manifest(manifest: Path | None) -> list[Any]:
    """The manifest's rows (none without one); a bad manifest is a BadParameter."""
    if manifest is None:
        return []
    from solitonde.instrument.cli import manifest as campaign

    if not manifest.is_file():
        raise typer.BadParameter(f"no such file: {manifest}", param_hint="--manifest")
    try:
        return campaign.load(manifest)
    except campaign.ManifestError as exc:
        raise typer.BadParameter(str(exc).removeprefix("--manifest: "),
                                 param_hint="--manifest") from None


def post_one(client: Client, path: Path, given: UploadForm, rows: list[Any],
             base: Path | None, attempts: int = 3, pause_s: float = 1.0) -> Outcome:
    """Upload ``path`` with its fields, retrying a transient failure ``attempts`` times."""
    row = manifest_row_for(rows, base, path) if rows and base is not None else None
    try:
        fields = fields_for(given, row)
    except ValueError as exc:
        return Outcome(str(path), "refused", "", error=str(exc))
    outcome = client.upload(path, fields)
    for k in range(1, attempts):
        if not outcome.transient:
            break
        time.sleep(pause_s * 2 ** (k - 1))
        outcome = client.upload(path, fields)
    return outcome


def post(
    files: list[Path] = typer.Argument(None, help="Waveform files or folders (recursive); "
                                       "optional with --manifest.", show_default=False),
    server: str = SERVER,
    api_key_env: str = API_KEY_ENV,
    plate_id: str | None = PLATE_ID,
    position: str | None = POSITION,
    x: float | None = X,
    y: float | None = Y,
    sphere_diameter: float | None = SPHERE,
    calibration: float | None = CALIBRATION,
    units: str | None = UNITS,
    sample_rate: float | None = SAMPLE_RATE,
    fmt: str | None = FORMAT,
    channel: str | None = CHANNEL,
    group: str | None = GROUP,
    plate_material: str | None = MATERIAL,
    table: str | None = TABLE,
    allow_duplicate: bool = ALLOW_DUPLICATE,
    setup: str | None = SETUP,
    manifest: Path | None = MANIFEST,
    as_json: bool = AS_JSON,
) -> None:
    """Upload waveform files to the service; each is stored once (a repeat is a replay)."""
    from solitonde.instrument.inference.measured_shots import collect

    def usage(message: str) -> None:
        typer.echo(f"error: {message}", err=True)
        raise typer.Exit(code=2)

    try:
        given = given_fields(plate_id, position, x, y, sphere_diameter, calibration, units,
                             sample_rate, fmt, channel, group, plate_material, table,
                             allow_duplicate, setup)
        rows = load_manifest(manifest)
    except typer.BadParameter as exc:
        usage(f"{exc.param_hint}: {exc.message}")
        return
    files = list(files or [])
    if not files and manifest is None:
        usage("give waveform files or folders, or --manifest")
    if files:
        paths, missing = collect(files, fmt)
        if missing:
            usage("; ".join(m["error"] for m in missing))
    else:
        from solitonde.instrument.cli import manifest as campaign
        from solitonde.signal.io import EXTENSIONS

        try:
            paths = [p for p, _ in campaign.match(rows, manifest.parent,  # type: ignore[union-attr]
                                                  None if fmt else EXTENSIONS)]
        except campaign.ManifestError as exc:
            usage(str(exc))
            return
    base = manifest.parent if manifest is not None else None
    if rows:
        unmatched = [p for p in paths if manifest_row_for(rows, base, p) is None]  # type: ignore[arg-type]
        if unmatched:
            usage(f"--manifest: no row of {manifest.name} matches {unmatched[0]}"  # type: ignore[union-attr]
                  + (f" (and {len(unmatched) - 1} more)" if len(unmatched) > 1 else ""))
    failed = 0
    with Client(server, api_key_from(api_key_env)) as client:
        for path in paths:
            outcome = post_one(client, path, given, rows, base)
            failed += not outcome.ok
            if as_json:
                sys.stdout.write(json.dumps(outcome.to_dict(), default=str) + "\n")
            else:
                typer.echo(status_line(outcome), err=not outcome.ok)
    raise typer.Exit(code=1 if failed else 0)


def register(app: typer.Typer) -> None:
    """Add `post` to the CLI."""
    app.command("post")(post)
