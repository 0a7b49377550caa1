"""`solitonde table build` and `solitonde table info`: make and inspect model tables.

Axes are given as comma lists (``4.76e-3,9.53e-3``) or as ``geom:START:STOP:N`` /
``lin:START:STOP:N``; without them the default table's grid is used (the paper's three spheres,
t = 1.5..6 mm, L = 0..457 mm dense within 200 mm). With ``--scene`` (or ``--set
chain.diameter=...``) and no ``--diameters`` the table is built for the scene's sphere size only.

Before the sweep starts, ``build`` prints its plan: the points, the sphere sizes, thicknesses
and distances, how many points need a meshed plate, and a time estimate from a pilot (the
thinnest, a middle and the thickest plate of each kind run first and kept; the dissipation
layers' chains too); then a progress bar whose ETA tqdm refines as plates return.
"""

from __future__ import annotations

import json
import re
import shlex
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import typer

from solitonde.instrument.cli.main import HELP_MARKUP
from solitonde.instrument.service.settings import DEFAULT_TABLE
from solitonde.instrument.tables.sweep import (
    PAPER_DIAMETERS_M,
    Sweep,
    default_distances_m,
    default_thicknesses_m,
)
from solitonde.instrument.tables.table import ModelTable, TableError, TableSummary
from solitonde.instrument.tables.table_build import BuildPlan, build_table, partial_path
from solitonde.model.errors import SceneError
from solitonde.model.scene import SceneDict, apply_overrides, load_scene_file, scene_from_dict
from solitonde.signal.features import EXTRACTOR_VERSION

if TYPE_CHECKING:  # the inference's modules load scipy.interpolate: only `table info` needs them
    from solitonde.instrument.inference.tier_match import TierMatchRow

DEFAULT_TABLE_PATH = DEFAULT_TABLE


def parse_axis(text: str | None, name: str, default: list[float]) -> list[float]:
    """An axis from ``a,b,c``, ``lin:a:b:n`` or ``geom:a:b:n``; ``default`` when not given."""
    if text is None:
        return list(default)
    try:
        if text.startswith(("lin:", "geom:")):
            kind, a, b, n = text.split(":")
            fn = np.linspace if kind == "lin" else np.geomspace
            return [float(round(x, 9)) for x in fn(float(a), float(b), int(n))]
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise typer.BadParameter(f"{text!r}: expected a comma list of numbers in m, or "
                                 "lin:START:STOP:N / geom:START:STOP:N", param_hint=name) from None


def _interrupted(exc: BaseException) -> bool:
    """Ctrl-C, also when it arrived inside compiled code (numba re-raises it as a SystemError
    caused by the KeyboardInterrupt)."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, KeyboardInterrupt):
            return True
        seen = seen.__cause__ or seen.__context__
    return False


def duration(seconds: float) -> str:
    """``42 s``, ``3.5 min``, ``1.2 h``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def _mm(values: list[float]) -> str:
    return ", ".join(f"{v * 1e3:.4g}" for v in values)


def plan_text(plan: BuildPlan, before_s: float = 0.0) -> str:
    """The plan as the command prints it before the sweep; ``before_s``, the seconds the
    command ran before the build began (its start and imports), counts in the total."""
    sw = plan.sweep
    n_d, n_t, n_l = sw.shape
    done = n_d * n_t * n_l - plan.points_todo
    lines = [f"plan: {n_d * n_t * n_l} points = {n_d} sphere size{'s' * (n_d != 1)} x "
             f"{n_t} thicknesses x {n_l} distances"
             + (f" ({done} done before, {plan.points_todo} to go)" if done else ""),
             f"  sphere diameters, mm: {_mm(sw.diameters_m)}",
             f"  thicknesses, mm:      {_mm(sw.thicknesses_m)}",
             f"  distances, mm:        {_mm(sw.distances_m)}"]
    kinds = {"meshed": "near a support (meshed plate)", "dashpot": "far (Zener's dashpot)"}
    for kind, n in plan.points_by_kind.items():
        pilots = ", ".join(f"{c[1]:.2f} s a point at {c[0] * 1e3:.3g} mm"
                           for c in sorted(plan.costs[kind]))
        lines.append(f"  {n} points {kinds[kind]}: pilot {pilots}")
    if plan.compile_s > 10:
        lines.append(f"  (the pilot first compiled the model's kernels: {duration(plan.compile_s)}"
                     ", once per installation)")
    if plan.layers:
        lines.append(f"  {plan.layers} dissipation layer{'s' * (plan.layers != 1)}: the plates' "
                     f"responses read from the store, only the chains run (damped: "
                     f"{plan.damped_factor:.2g}x the elastic chain's time): "
                     f"{duration(plan.layers_eta_s)}" + (" here" if plan.layers_here else ""))
    if plan.slopes_eta_s >= 0.5:
        lines.append(f"  material slopes: {duration(plan.slopes_eta_s)}")
    started = f" and the workers' {duration(plan.start_s)} start" if plan.start_s else ""
    if abs(plan.slowdown - 1.0) >= 0.1:
        lines.append(f"  (a plate takes {plan.slowdown:.2g}x the pilot's time with every worker "
                     "busy: counted)")
    where = ("here, a plate at a time (less than the workers' start would take)" if plan.here
             else f"on {plan.workers} worker{'s' * (plan.workers != 1)}")
    lines.append(f"  estimated time: {duration(plan.remaining_s)} {where} after a "
                 f"{duration(plan.pilot_wall_s)} pilot"
                 f"{started} ({duration(before_s + plan.elapsed_s + plan.remaining_s)} in all)")
    return "\n".join(lines)


def _process_seconds() -> float:
    """Seconds since this process started (its interpreter's start and imports: about a
    second, which a user's clock counts and the build's own does not)."""
    import psutil

    return max(0.0, time.time() - psutil.Process().create_time())


def _fail(message: str) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def build_command(
    out: Path = typer.Option(DEFAULT_TABLE_PATH, "--out", "-o", help="table file to write"),
    diameters: str | None = typer.Option(None, help="sphere diameters D, m (default: the "
                                         "scene's with --scene, else the paper's "
                                         "4.76e-3,9.53e-3,19.05e-3)"),
    thicknesses: str | None = typer.Option(None, help="plate thicknesses t, m "
                                           "(default: geom:1.5e-3:6e-3:16)"),
    distances: str | None = typer.Option(None, help="distances to the support L, m "
                                         "(default: 0..0.457, dense within 0.2)"),
    scene: Path | None = typer.Option(None, help="base scene file (YAML/JSON)"),
    set_: list[str] = typer.Option([], "--set", help="scene override key=value (repeatable)"),
    traces: bool = typer.Option(False, "--traces", help="also store every sensor trace"),
    workers: int | None = typer.Option(None, help="local worker processes (default: one per "
                                       "core); 1 runs serially without Dask"),
    scheduler: str | None = typer.Option(None, help="address of an existing Dask scheduler"),
    responses: Path | None = typer.Option(
        None, "--responses", help="folder of the plate-response store (default: each machine's "
        "own, `solitonde cache info` names it); on a cluster, a folder every worker reads and "
        "writes"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="progress bar"),
    as_json: bool = typer.Option(False, "--json", help="print the build report as JSON"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing table file "
                                   "(without --out: the bundled table)"),
    table_id: str | None = typer.Option(None, "--id", help="the table's id, which measurements "
                                        "and the service name it by (default: the file's stem)"),
    dissipation_layer: list[float] = typer.Option(
        [], "--dissipation-layer", metavar="TAU",
        help="also simulate the sweep with Kuwabara-Kono contact damping TAU s (repeatable; the "
             "bundled tables: 7e-8, 1.2e-7 and 2e-7) and store it in the table, so that a "
             "calibration can fit the chain's damping"),
) -> None:
    """Simulate the sweep (resuming an interrupted build) and write the table atomically."""
    if table_id is not None and not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}", table_id):
        _fail(f"--id: {table_id!r} is not an id (allowed: 1-64 letters, digits, '.', '_', '-', "
              "starting with a letter or digit)")
    if out.is_file() and not partial_path(out).exists() and not overwrite:
        which = " (the bundled table: --out was not given)" if out == DEFAULT_TABLE_PATH else ""
        _fail(f"--out: {str(out)!r} exists{which}; give another --out, or --overwrite to "
              "replace it")
    try:
        base: SceneDict = load_scene_file(scene) if scene is not None else {}
        base = apply_overrides(base, set_)
        own_sphere = scene is not None or any(s.split("=")[0].strip() == "chain.diameter"
                                              for s in set_)
        sizes = ([scene_from_dict(base).chain.diameter] if own_sphere
                 else list(PAPER_DIAMETERS_M))
        sweep = Sweep(
            parse_axis(diameters, "--diameters", sizes),
            parse_axis(thicknesses, "--thicknesses", default_thicknesses_m()),
            parse_axis(distances, "--distances", default_distances_m()),
            scene=base, traces=traces,
        )
        for tau in dissipation_layer:
            _check_damping(tau, "--dissipation-layer")
        command = "solitonde " + " ".join(shlex.quote(a) for a in sys.argv[1:])
        # A fresh install: the extractor compiles in the background while the pilot compiles
        # the model's kernels; the pilot's first shot waits for it (build_table's points are
        # read by the compiled extractor only).
        from solitonde.signal import kernel_choice

        kernel_choice.start()
        store = True if responses is None else responses
        before = _process_seconds()
        plans: list[BuildPlan] = []

        def show(plan: BuildPlan) -> None:
            plans.append(plan)
            typer.echo(plan_text(plan, before), err=as_json)

        report = build_table(sweep, out, workers=workers, scheduler=scheduler, progress=progress,
                             command=command, table_id=table_id, plan=show,
                             responses=store, layers=len(dissipation_layer))
        if report.complete and dissipation_layer:
            here = bool(plans) and plans[0].layers_here  # too few plates for workers
            _add_layer(out, dissipation_layer, [], 1 if here else workers, progress, as_json,
                       scheduler, store)
    except (TableError, SceneError) as exc:
        _fail(str(exc))
        return
    except (KeyboardInterrupt, SystemError) as exc:
        if not _interrupted(exc):
            raise
        part = partial_path(out)
        kept = (f"the points done so far are kept in {str(part)!r}; run the same command again "
                "to resume" if part.exists() else "nothing was written")
        typer.echo(f"interrupted: {kept}", err=True)
        raise typer.Exit(130) from None
    data = {"path": str(report.path), "complete": report.complete,
            "points_written": report.points_written, "plates_written": report.plates_written,
            "wall_s": report.wall_s, "scenes_per_s": report.scenes_per_s, "runner": report.runner}
    if as_json:
        typer.echo(json.dumps(data, indent=2))
    else:
        typer.echo(f"wrote {report.path}: {report.points_written} scenes on "
                   f"{report.plates_written} plates in {report.wall_s:.1f} s "
                   f"({report.scenes_per_s:.2f} scenes/s, {report.runner})")


SPREAD_SOURCES = {
    "library": "its grade's (the library's)",
    "stated": "stated with the plate's properties",
    "default": "the default for a material given by its properties alone: state "
               "youngs_modulus_rel_sd, poisson_ratio_sd, density_rel_sd with them to replace it",
    "none": "none (the table records no plate material)"}


class TableInfo(TableSummary):
    """``table info --json``: the table's summary and its plate material spread (with where
    the spread comes from)."""

    material_spread: dict[str, float | str]
    tier_match: list[TierMatchRow]


def info_command(
    file: Path = typer.Argument(DEFAULT_TABLE_PATH, help="table file"),
    as_json: bool = typer.Option(False, "--json", help="print JSON"),
) -> None:
    """Axes, point status and provenance of a table."""
    try:
        table = ModelTable.load(file)
    except TableError as exc:
        _fail(str(exc))
        return
    from solitonde.instrument.inference.material_spread import (
        describe_spread,
        spread_of,
        spread_source,
    )
    from solitonde.instrument.inference.tier_match import summary as tier_summary

    spread, source = spread_of(table), spread_source(table)
    data: TableInfo = {**table.summary(), "material_spread": {**spread, "source": source},
                       "tier_match": tier_summary(table)}
    if as_json:
        typer.echo(json.dumps(data, indent=2))
        return
    typer.echo(f"{file}: {'complete' if data['complete'] else 'INCOMPLETE'}, "
               f"shape {data['shape']} ({data['n_points']} points)")
    for name, axis in data["axes"].items():
        vals = ", ".join(f"{v * 1e3:.4g}" for v in axis["values"])
        typer.echo(f"  {name}: {axis['n']} values, mm: {vals}")
    typer.echo(f"  status: {data['status_counts']}")
    typer.echo(f"  plate models: {data['plate_models']}")
    for row in data["tier_match"]:
        typer.echo(f"  tier levels, D {row['diameter_m'] * 1e3:.4g} mm: " + (
            f"{row['rows_matched']} of {row['rows']} rows' meshed nodes read at the dashpot's "
            f"level where the two meet (TOF x{row['tof_factor'][0]:.4f}-"
            f"{row['tof_factor'][1]:.4f}, ARR x{row['arr_factor'][0]:.4f}-"
            f"{row['arr_factor'][1]:.4f})" if row["tof_factor"] and row["arr_factor"] else
            "no row matched (as simulated)"))
    layer = data["dissipation_layer"]
    typer.echo("  dissipation layer: " + ("none (`solitonde table dissipation` adds one)"
                                          if layer is None else
                                          "Kuwabara-Kono tau = " + ", ".join(
                                              f"{t:g}" for t in layer["damping_s"]) + " s"))
    typer.echo(f"  plate material spread: {describe_spread(spread)}, "
               + SPREAD_SOURCES[source])
    reading = data["reading_version"]
    typer.echo(f"  reading: {reading}" + ("" if reading == EXTRACTOR_VERSION else
                                           f" (shots are read with {EXTRACTOR_VERSION}: rebuild "
                                           "the table before inverting with it)"))
    prov = data["provenance"]
    if prov:
        typer.echo(f"  built {prov.get('built_at')} in {prov.get('build_wall_s', 0):.0f} s "
                   f"({prov.get('runner')}) on {prov.get('machine', {}).get('node')}, "
                   f"solitonde {prov.get('solitonde_version')} git {prov.get('git_revision')}")


def slopes_command(
    file: Path = typer.Argument(DEFAULT_TABLE_PATH, help="table file"),
) -> None:
    """Simulate how the table's features move with the plate material (E, rho) far from the
    supports and write it into the table (table build does; for a table built before)."""
    import time

    from solitonde.instrument.tables.material_slopes import add_to_table

    started = time.perf_counter()
    try:
        slopes = add_to_table(file)
    except TableError as exc:
        _fail(str(exc))
        return
    n_d, n_t, _ = slopes["arr"].shape
    typer.echo(f"wrote material_slopes into {file}: {n_d} sphere size(s) x {n_t} thicknesses "
               f"in {time.perf_counter() - started:.1f} s")


def _check_damping(value: float, flag: str) -> None:
    if not (value > 0 and value <= 1e-3):
        _fail(f"{flag}: {value!r} s is not a Kuwabara-Kono time constant (allowed: "
              "0 < TAU <= 1e-3 s; the synthetic chain's is 1e-7)")


def _add_layer(file: Path, dampings: list[float], sources: list[Path], workers: int | None,
               progress: bool, quiet: bool, scheduler: str | None = None,
               responses: Path | bool = True) -> None:
    """Simulate slices at ``dampings`` (or take them from ``sources``) and add them to the
    dissipation layer of ``file``. The slices share one local cluster (started once, not once a
    slice) unless a scheduler is given or the build is serial."""
    import contextlib
    import time

    from solitonde.instrument.parallel import default_workers, local_cluster
    from solitonde.instrument.tables.dissipation import (
        add_to_table,
        layer_from_table,
        simulate_layer,
    )

    started = time.perf_counter()
    table = ModelTable.load(file)
    built: list[Path] = []
    layer = None
    for source in sources:
        one = layer_from_table(table, ModelTable.load(source))
        layer = one if layer is None else layer.merged(one)
    lanes = default_workers() if workers is None else workers
    with contextlib.ExitStack() as stack:
        if dampings and scheduler is None and lanes > 1:
            cluster = stack.enter_context(local_cluster(lanes))
            scheduler = cluster.scheduler_address
        for tau in dampings:
            one, path = simulate_layer(table, tau, file.parent, workers=workers,
                                       progress=progress, scheduler=scheduler,
                                       responses=responses)
            built.append(path)
            layer = one if layer is None else layer.merged(one)
    assert layer is not None
    full = add_to_table(file, layer)
    for path in built:
        path.unlink(missing_ok=True)  # its features are in the table now
    taus = ", ".join(f"{t:g}" for t in full.damping_s)
    typer.echo(f"wrote the dissipation layer (Kuwabara-Kono tau = {taus} s) into {file} in "
               f"{time.perf_counter() - started:.1f} s", err=quiet)


def dissipation_command(
    file: Path = typer.Argument(DEFAULT_TABLE_PATH, help="table file"),
    damping: list[float] = typer.Option([], "--damping", metavar="TAU",
                                        help="simulate a slice at this Kuwabara-Kono time "
                                             "constant, s (repeatable; default 7e-8, 1.2e-7 "
                                             "and 2e-7 without --from)"),
    source: list[Path] = typer.Option([], "--from", help="take a slice from this table: the "
                                      "same sweep built with --set effects.dissipation=true "
                                      "--set effects.damping=TAU (repeatable)"),
    workers: int | None = typer.Option(None, help="local worker processes (default: one per "
                                       "core)"),
    scheduler: str | None = typer.Option(None, help="address of an existing Dask scheduler"),
    responses: Path | None = typer.Option(
        None, "--responses", help="folder of the plate-response store the table was built with "
        "(default: each machine's own)"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="progress bar"),
) -> None:
    """Add slices to a table's dissipation layer (table build --dissipation-layer does): the
    sweep with contact damping, which a calibration reads the chain's damping from."""
    from solitonde.instrument.tables.dissipation import DEFAULT_DAMPINGS_S

    for tau in damping:
        _check_damping(tau, "--damping")
    if not damping and not source:
        damping = list(DEFAULT_DAMPINGS_S)
    try:
        _add_layer(file, damping, source, workers, progress, False, scheduler,
                   True if responses is None else responses)
    except (TableError, SceneError) as exc:
        _fail(str(exc))


def register(app: typer.Typer) -> None:
    """Add the `table` command group to the CLI."""
    group = typer.Typer(help="Build and inspect model tables.", no_args_is_help=True,
                        rich_markup_mode=HELP_MARKUP)
    group.command("build")(build_command)
    group.command("info")(info_command)
    group.command("slopes")(slopes_command)
    group.command("dissipation")(dissipation_command)
    app.add_typer(group, name="table")
