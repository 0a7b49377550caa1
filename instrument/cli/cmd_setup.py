"""`solitonde setup`: the instrument set-ups a service keeps (create, show, list, calibrate).

A set-up is what a lab configures once: the chain's sphere sizes, the table its plates are read
against, labels, and a chain calibration. The service keeps every revision; ``post --setup``,
``watch --setup`` and the page measure with one. ``setup show ID --out FILE`` saves the newest
revision as a file, which ``analyze --setup FILE`` reads offline.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, TypedDict, cast
from urllib.parse import quote

import typer

from solitonde.instrument.cli.cmd_post import API_KEY_ENV, SERVER
from solitonde.instrument.cli.common import sphere_sizes

if TYPE_CHECKING:
    from solitonde.instrument.inference.setups import SetupDict

setup_app = typer.Typer(help="Instrument set-ups kept by a service: create, show, list, "
                        "calibrate.", no_args_is_help=True)


class SetupBody(TypedDict, total=False):
    """What ``setup create`` states of a set-up (the service's ``SetupIn``)."""

    id: str
    sphere_diameters_m: list[float]
    table: str
    plate_material: Any
    chain: Any
    striker: Any
    labels: dict[str, str]


def _fail(message: str, code: int = 2) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def _request(server: str, api_key_env: str, method: str, path: str,
             body: Any = None) -> Any:
    """One JSON request and the server's JSON answer ({} for none); the server's problem
    detail (exit 1) or an unreachable server (exit 1) is said in one line."""
    from solitonde.instrument.cli.uploader import ServerError, call

    try:
        r = call(server, api_key_env, method, path, body)
    except ServerError as exc:
        _fail(exc.message, 1)
    return r.json() if r.content else {}


def _path(setup_id: str, *rest: str) -> str:
    return "/v1/setups/" + "/".join([quote(setup_id, safe=""), *rest])


def _line(s: SetupDict) -> str:
    cal = s.get("chain_calibration")
    sizes = ", ".join(f"{d * 1e3:.4g}" for d in s["sphere_diameters_m"])
    how = "not calibrated"
    if cal:
        entries = cal.get("per_diameter") or []
        how = "calibrated: " + "; ".join(
            f"D {e['diameter_m'] * 1e3:.4g} mm tof_offset {e['tof_offset_s'] * 1e6:.2f} us, "
            f"arr_factor {e['arr_factor']:.3f}"
            + (f", damping {e['damping_s']:.3g} s" if "damping_s" in e else "")
            + (f", by distance at {len(e['by_distance'])} references"
               if e.get("by_distance") else "")
            for e in entries)
    return (f"{s['id']}  revision {s['revision']}  D {sizes} mm  table {s['table']}  {how}")


@setup_app.command("create")
def create(
    setup_id: str = typer.Argument(..., metavar="ID", help="the set-up's id"),
    sphere_diameter: list[float] = typer.Option([], "--sphere-diameter", callback=sphere_sizes,
                                                help="m, a sphere size the chain mounts (repeat "
                                                "for several; needed to create)"),
    table: str | None = typer.Option(None, "--table", help="the server's table id (GET "
                                     "/v1/tables; needed to create)"),
    plate_material: str | None = typer.Option(None, "--plate-material", help="the plate "
                                              "family's material: a library name or its "
                                              "properties as JSON"),
    label: list[str] = typer.Option([], "--label", help="KEY=VALUE (operator, instrument ...; "
                                    "repeat)"),
    revise: bool = typer.Option(False, "--revise", help="make a new revision of an existing "
                                "set-up: what is given replaces the newest revision's, labels "
                                "are merged, the rest and the chain calibration carry over"),
    server: str = SERVER,
    api_key_env: str = API_KEY_ENV,
    as_json: bool = typer.Option(False, "--json", help="print the stored set-up as JSON"),
) -> None:
    """Create a set-up on the server (revision 1), or with --revise a new revision."""
    from solitonde.instrument.cli.common import parse_material

    labels: dict[str, str] = {}
    for item in label:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            _fail(f"--label: {item!r} is not KEY=VALUE")
        labels[key.strip()] = value.strip()
    body: SetupBody = {"id": setup_id}
    if revise:  # the newest revision, what this call states replacing it
        from solitonde.instrument.inference.setups import INPUT_FIELDS

        current = _request(server, api_key_env, "GET", _path(setup_id))
        body = cast(SetupBody, {k: current[k] for k in INPUT_FIELDS
                                if current.get(k) is not None})
        labels = {**(current.get("labels") or {}), **labels}
    elif not sphere_diameter or table is None:
        _fail("--sphere-diameter and --table are needed to create a set-up (--revise takes "
              "them from its newest revision)")
    if sphere_diameter:
        body["sphere_diameters_m"] = sphere_diameter
    if table is not None:
        body["table"] = table
    if plate_material is not None:
        try:
            body["plate_material"] = parse_material(plate_material)
        except ValueError as exc:
            _fail(f"--plate-material: {exc}")
    if labels:
        body["labels"] = labels
    out = (_request(server, api_key_env, "PUT", _path(setup_id), body) if revise
           else _request(server, api_key_env, "POST", "/v1/setups", body))
    typer.echo(json.dumps(out, indent=2) if as_json else _line(out))


@setup_app.command("show")
def show(
    setup_id: str = typer.Argument(..., metavar="ID", help="the set-up's id"),
    server: str = SERVER,
    api_key_env: str = API_KEY_ENV,
    out: Path | None = typer.Option(None, "--out", help="save it as a file (for analyze "
                                    "--setup)"),
) -> None:
    """Print a set-up's newest revision (JSON) and its revisions; --out saves it."""
    found = _request(server, api_key_env, "GET", _path(setup_id))
    text = json.dumps(found, indent=2) + "\n"
    if out is not None:
        from solitonde.signal.atomic import write_text

        write_text(out, text)
        typer.echo(f"wrote {out} (set-up {setup_id!r}, revision {found['revision']})")
    else:
        typer.echo(text, nl=False)


@setup_app.command("list")
def list_setups(
    server: str = SERVER,
    api_key_env: str = API_KEY_ENV,
    as_json: bool = typer.Option(False, "--json", help="print them as JSON"),
) -> None:
    """Every set-up's newest revision, one line each."""
    items = _request(server, api_key_env, "GET", "/v1/setups")["items"]
    if as_json:
        typer.echo(json.dumps(items, indent=2))
        return
    for s in items:
        typer.echo(_line(s))
    if not items:
        typer.echo("no set-ups yet (solitonde setup create ...)")


@setup_app.command("calibrate")
def calibrate(
    setup_id: str = typer.Argument(..., metavar="ID", help="the set-up's id"),
    reference: list[str] = typer.Option([], "--reference", help="THICKNESS_M,DISTANCE_M,ID[;ID"
                                        "...]: stored measurements on a reference plate "
                                        "(repeat for several plates or distances)"),
    file: Path | None = typer.Option(None, "--file", help="a calibration written by "
                                     "`solitonde calibrate`, taken as it is"),
    wait: bool = typer.Option(True, "--wait/--no-wait", help="wait until the set-up's "
                              "measurements are re-estimated"),
    server: str = SERVER,
    api_key_env: str = API_KEY_ENV,
    as_json: bool = typer.Option(False, "--json", help="print the answer as JSON"),
) -> None:
    """Calibrate a set-up's chain on the server: fitted on stored reference measurements, or
    from a file; its measurements are then re-estimated (a job)."""
    import time

    if (file is None) == (not reference):
        _fail("give --reference (one or more) or --file")
    if file is not None:
        try:
            body = json.loads(file.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            _fail(f"--file: cannot read {str(file)!r} as JSON ({exc})")
        answer = _request(server, api_key_env, "PUT", _path(setup_id, "calibration"), body)
    else:
        refs = []
        for item in reference:
            parts = item.split(",")
            try:
                thickness, distance = float(parts[0]), float(parts[1])
                ids = [int(x) for x in parts[2].replace(";", " ").split()]
            except (IndexError, ValueError):
                _fail(f"--reference: {item!r} is not THICKNESS_M,DISTANCE_M,ID[;ID...]")
            refs.append({"thickness_m": thickness, "distance_m": distance,
                         "measurement_ids": ids})
        answer = _request(server, api_key_env, "POST", _path(setup_id, "calibration"),
                          {"references": refs})
    job = answer["job"]
    while wait and job["state"] in ("queued", "running"):
        time.sleep(0.5)
        job = _request(server, api_key_env, "GET", job["links"]["self"])
    answer["job"] = job
    if as_json:
        typer.echo(json.dumps(answer, indent=2))
        return
    typer.echo(_line(answer["setup"]))
    typer.echo(f"job {job['id']}: {job['state']}, {job['done']} of {job['total']} measurements "
               f"re-estimated" + (f", {len(job['failed'])} failed" if job.get("failed") else ""))


def register(app: typer.Typer) -> None:
    """Add `setup` to the CLI."""
    app.add_typer(setup_app, name="setup")
