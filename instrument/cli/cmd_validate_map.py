"""`solitonde validate-map`: simulated scans inverted jointly against position by position,
and the next position suggested against chosen at random (see
:mod:`solitonde.instrument.studies.map_study` for what is simulated and scored)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import typer

from solitonde.instrument.cli.common import table_path

if TYPE_CHECKING:
    from solitonde.instrument.studies.map_metrics import MapMetrics


def _fail(message: str, code: int = 1) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def validate_map_command(
    scans: int = typer.Option(30, "--scans", help="number of random scans (3-10 positions "
                              "each)"),
    seed: int = typer.Option(0, "--seed", help="random seed"),
    table: Path | None = typer.Option(None, "--table", help="model table"),
    diameter: float | None = typer.Option(None, "--diameter", help="the sphere size, m "
                                          "(default: the table's nearest to 9.53 mm)"),
    sequential: bool = typer.Option(True, "--sequential/--no-sequential", help="also the "
                                    "edge's error as positions are added, suggested or random "
                                    "(most of the study's time)"),
    measurements: Path | None = typer.Option(None, "--measurements", help="JSON file keeping "
                                             "the simulated positions; reused when present"),
    out: Path | None = typer.Option(None, "--out", help="also write every scan's rows as JSON"),
    as_json: bool = typer.Option(False, "--json", help="print the metrics as JSON"),
    shared_calibration: bool = typer.Option(False, "--shared-calibration", help="the joint "
                                            "maps draw the calibration's TOF offset error "
                                            "once per scan, not per position"),
    exact_positions: bool = typer.Option(False, "--exact-positions", help="simulate each "
                                         "position exactly at its recorded coordinates "
                                         "(default: the chain stands off them by the 1 mm the "
                                         "joint map states for them)"),
    truth_plate_theory: str = typer.Option("auto", "--truth-plate-theory", help="the "
                                           "simulated plates' sem.plate_theory: auto (the "
                                           "table's own tiers), 3d (the 3-D plate next to a "
                                           "support, where the table holds the 2-D plate, "
                                           "with the 2-D plate's in-plane elements), "
                                           "mindlin"),
    workers: int = typer.Option(1, "--workers", help="simulate the scans' positions this "
                                "many at a time"),
    width_split: bool = typer.Option(False, "--width-split", help="instead: what each "
                                     "near-edge position's thickness interval is made of "
                                     "(its distance, the material, the calibration, the "
                                     "table's error, the shots)"),
) -> None:
    """Simulate scans of random plates, invert them jointly and one by one, and score both."""
    from solitonde.instrument.studies import map_study
    from solitonde.instrument.studies.map_study import StudyInputError, run
    from solitonde.instrument.tables.table import ModelTable, TableError

    for flag, path in (("--out", out), ("--measurements", measurements)):
        if path is not None and (path.is_dir() or not path.parent.is_dir()):
            _fail(f"{flag}: {str(path)!r} is not a file in an existing folder")
    if width_split:
        try:
            split = map_study.width_split(ModelTable.load(table_path(table)), scans, seed,
                                          diameter_m=diameter, measurements=measurements)
        except StudyInputError as exc:
            _fail(f"--{exc.field.replace('_', '-')}: {str(exc).partition(': ')[2]}")
        except TableError as exc:
            _fail(f"--{'diameter' if exc.field == 'diameter_m' else 'table'}: {exc}")
        if as_json:
            typer.echo(json.dumps(split, indent=2))
            return
        typer.echo(f"near-edge thickness interval, {split['positions']} positions within 30 mm "
                   f"of the edge ({split['n_scans']} scans, seed {split['seed']}): median "
                   "width, of t, median ratio to alone")
        for step in map_study.SPLIT_STEPS:
            v = split[step]
            if v["median_width_m"] is None:
                continue
            typer.echo(f"  {step}: {v['median_width_m'] * 1e3:.2f} mm, "
                       f"{v['median_width_rel_t']:.3f} t, {v['median_ratio_to_alone']:.3f}")
        return
    try:
        model = ModelTable.load(table_path(table))
        result = run(model, scans, seed, diameter_m=diameter, measurements=measurements,
                     sequential=sequential, shared_calibration=shared_calibration,
                     exact_positions=exact_positions,
                     truth_plate_theory=truth_plate_theory, workers=workers,
                     progress=lambda what, k, n: print(f"{what} {k}/{n}", file=sys.stderr,
                                                       flush=True))
    except StudyInputError as exc:
        _fail(f"--{exc.field.replace('_', '-')}: {str(exc).partition(': ')[2]}")
    except TableError as exc:
        _fail(f"--{'diameter' if exc.field == 'diameter_m' else 'table'}: {exc}")
    m = result["metrics"]
    if out is not None:
        out.write_text(json.dumps(result, indent=1, default=str) + "\n")
    if as_json:
        typer.echo(json.dumps(m, indent=2, default=str))
        return
    for line in report_lines(m):
        typer.echo(line)


def report_lines(m: MapMetrics) -> list[str]:
    """The study's figures as the docs print them ("-" where a figure has no value)."""
    def num(v: float | None, fmt: str = ".3f", scale: float = 1.0) -> str:
        return "-" if v is None else format(v * scale, fmt)

    lines = [f"map study on {m['table']}: {m['n_scans']} scans, seed {m['seed']}, D "
             f"{m['diameter_m'] * 1e3:.2f} mm"
             + (", the calibration's TOF offset shared" if m.get("shared_calibration") else "")
             + (f", truths on sem.plate_theory {m['truth_plate_theory']}"
                if m.get("truth_plate_theory", "auto") != "auto" else "")
             + f", {m['simulated_positions']} positions simulated "
             f"({m['simulation_wall_s']:.0f} s), {m['wall_s']:.0f} s in all"]
    kinds = (("position by position", m["thickness_alone"], m["edge_alone"]),
             ("joint, thickness free", m["thickness_free"], m["edge_free"]),
             ("joint, common mean (5 %)", m["thickness_common"], m["edge_common"]))
    for name, t, e in kinds:
        lines.append(f"  {name}: thickness coverage {num(t['coverage_95'])} ({t['answers']} "
                     f"answers of {t['positions']}); within {30} mm of the edge median 95 % "
                     f"width {num(t['near_edge_width_median_m'], '.2f', 1e3)} mm "
                     f"({num(t['near_edge_width_median_rel'], '.3f')} of t, "
                     f"{t['near_edge_positions']} positions); edge offset coverage "
                     f"{num(e['coverage_95'])} ({e['located']} of {e['scans']} located; "
                     f"error over stated sd, rms {num(e['offset_z_rms'], '.2f')}), median "
                     f"error {num(e['error_median_m'], '.2f', 1e3)} mm, median 95 % "
                     f"width {num(e['ci95_width_median_m'], '.1f', 1e3)} mm")
        if "angle_coverage_95" in e:
            lines.append(f"    the edge as the scan sees it: angle coverage "
                         f"{num(e['angle_coverage_95'])} (rms z "
                         f"{num(e.get('angle_z_rms'), '.2f')}; median 95 % width "
                         f"{num(e.get('angle_ci95_width_median_deg'), '.2f')} deg); where it "
                         f"lies at the positions' centroid: coverage "
                         f"{num(e.get('at_scan_coverage_95'))} (rms z "
                         f"{num(e.get('at_scan_z_rms'), '.2f')}; median 95 % width "
                         f"{num(e.get('at_scan_ci95_width_median_m'), '.1f', 1e3)} mm; "
                         f"{num(e.get('at_scan_coverage_95_direction_fixed'))} over the "
                         f"{e.get('direction_fixed_scans')} scans whose direction is fixed); "
                         f"the frame's origin lies a median "
                         f"{num(e.get('lever_median_m'), '.0f', 1e3)} mm along the edge from "
                         "them")
    lines.append("  (rms z: each miss over the sd its 95 % interval states; 1 where the intervals "
                 "are as wide as the errors, below 1 where they are wider)")
    sequences = (("suggested", m.get("sequence_suggested")),
                 ("random_near_edge", m.get("sequence_random_near_edge")),
                 ("random_on_plate", m.get("sequence_random_on_plate")))
    for strategy, seq in sequences:
        if not seq:
            continue
        curve = ", ".join(f"{k}: {v * 1e3:.1f}" for k, v in
                          seq["edge_error_median_m_by_positions"].items())
        lines.append(f"  {strategy}: median edge error (mm) by positions {curve}; 5 mm reached "
                     f"in {seq['reached_target']} of {seq['scans']} scans, median positions "
                     f"{num(seq['positions_to_target_median'], '.1f')}")
    against = (("random_near_edge", m.get("suggested_fewer_than_random_near_edge"),
                m.get("suggested_more_than_random_near_edge")),
               ("random_on_plate", m.get("suggested_fewer_than_random_on_plate"),
                m.get("suggested_more_than_random_on_plate")))
    for other, fewer, more in against:
        if fewer is not None:
            lines.append(f"  suggested needed fewer positions than {other} in {fewer} scans, "
                         f"more in {more}")
    return lines


def register(app: typer.Typer) -> None:
    """Add `validate-map` to the CLI."""
    app.command("validate-map")(validate_map_command)
