"""`solitonde samples`: regenerate the synthetic waveform files in data_samples/waveforms/.

Each file holds shots simulated by the project's own chain model (model.simulate) for one scene,
with acquisition defects added (white noise at a stated SNR, baseline drift, 12-bit quantisation;
see solitonde.signal.synth.degrade). Shots differ by their noise and by a drop height varied
+-1 % (the paper's striker spread), so every shot has its own truth. The model's own peaks
(integration-step resolution, amplitudes above the static sensor reading) go to truth.tsv
(tab-separated, so that `solitonde analyze data_samples/waveforms` skips it). Amplitudes are
taken above the
level the noise-free trace holds before each pulse's foot (signal.accuracy.Truth.from_trace, the
extractor's own baseline definition): after the incident the chain decompresses and the sensor
sits below its static reading, and a reflection is measured from where it starts.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict

import numpy as np
import typer

from solitonde.instrument.tables.measured import as_measured
from solitonde.model.scene import load_scene
from solitonde.model.simulate import simulate
from solitonde.signal import io as signal_io
from solitonde.signal.accuracy import Truth
from solitonde.signal.synth import degrade
from solitonde.signal.waveform import Waveform

TRUTH_KEYS = ("file", "shot", "tof_s", "arr", "incident_time_s", "reflected_time_s",
              "incident_peak_N", "reflected_peak_N", "snr_db", "drop_height_m",
              "sphere_diameter_m", "plate_thickness_m", "sample_rate_hz")


@dataclass(frozen=True)
class SampleSpec:
    """One sample file: the scene overrides, the SNR and how many shots."""

    name: str
    overrides: tuple[str, ...]
    snr_db: float
    shots: int
    options: tuple[tuple[str, Any], ...] = ()


SPECS = (
    SampleSpec("synthetic_D9.53_t4.83_snr40.csv",
               ("chain.diameter=9.53e-3", "plate.thickness=4.83e-3"), 40.0, 2),
    SampleSpec("synthetic_D9.53_t3.18_snr30.h5",
               ("chain.diameter=9.53e-3", "plate.thickness=3.18e-3"), 30.0, 3),
    SampleSpec("synthetic_D9.53_t2.29_snr40.npy",
               ("chain.diameter=9.53e-3", "plate.thickness=2.29e-3"), 40.0, 2),
    SampleSpec("synthetic_D19.05_t4.83_snr30.tdms",
               ("chain.diameter=19.05e-3", "plate.thickness=4.83e-3"), 30.0, 2),
)
DRIFT = 0.01
TRUTH_FILE = "truth.tsv"
BITS = 12


def _common_axis(waves: list[Waveform]) -> list[Waveform]:
    """The shots cut to the time span they all cover, for formats with one time axis per file
    (their pre-triggers and records differ by a few samples with the drop height)."""
    start = max(w.t0 for w in waves)
    cuts = [round((start - w.t0) / w.dt) for w in waves]
    n = min(w.n - cut for w, cut in zip(waves, cuts, strict=True))
    return [Waveform(start, w.dt, w.samples[cut:cut + n], w.units, None, w.metadata)
            for w, cut in zip(waves, cuts, strict=True)]


class TruthRow(TypedDict):
    """A sample shot's truth (a row of truth.tsv, :data:`TRUTH_KEYS`)."""

    file: str
    shot: int
    tof_s: float | None
    arr: float | None
    incident_time_s: float | None
    reflected_time_s: float | None
    incident_peak_N: float
    reflected_peak_N: float | None
    snr_db: float
    drop_height_m: float
    sphere_diameter_m: float
    plate_thickness_m: float
    sample_rate_hz: float


class ScanTruth(TypedDict):
    """A scan position's truth (a row of the scan's truth.tsv)."""

    position: str
    x_m: float
    y_m: float
    distance_m: float
    thickness_m: float
    plate_model: str
    tof_s: float | None
    arr: float | None


class _ManifestRow(TypedDict):
    file: str
    plate_id: str
    position: str
    x_m: float
    y_m: float
    sphere_diameter_m: float


def make_samples(out_dir: Path, seed: int = 20240601) -> list[TruthRow]:
    """Write every sample file into ``out_dir`` and return the truth rows (also in truth.tsv)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    truth_rows: list[TruthRow] = []
    for spec in SPECS:
        waves = []
        for shot in range(spec.shots):
            height = 5e-3 * (1.0 + 0.01 * rng.uniform(-1.0, 1.0))
            scene = load_scene(None, [*spec.overrides, f"striker.drop_height={height!r}",
                                      "effects.plate_model=infinite", "output.duration=auto"])
            sim = simulate(scene)
            t = sim.truth
            truth = Truth.from_peaks(sim.samples, sim.dt, sim.t0, t)
            reference = truth.incident_peak_N
            meta = {"shot": shot,
                    "plate_id": f"synthetic-t{scene.plate.thickness * 1e3:.2f}mm",
                    "position": scene.plate.distance_to_support,
                    "sphere_diameter": scene.chain.diameter, "synthetic": True,
                    "snr_db": spec.snr_db, "drop_height_m": height}
            recorded = as_measured(sim, meta)
            samples = degrade(recorded.samples, spec.snr_db, rng, reference, drift=DRIFT,
                              bits=BITS)
            waves.append(recorded.with_samples(samples))
            truth_rows.append({
                "file": spec.name, "shot": shot, "tof_s": truth.tof_s, "arr": truth.arr,
                "incident_time_s": t["incident_time_s"], "reflected_time_s": t["reflected_time_s"],
                "incident_peak_N": reference, "reflected_peak_N": truth.reflected_peak_N,
                "snr_db": spec.snr_db, "drop_height_m": height,
                "sphere_diameter_m": scene.chain.diameter,
                "plate_thickness_m": scene.plate.thickness, "sample_rate_hz": 1.0 / sim.dt,
            })
        path = out_dir / spec.name
        if path.suffix in (".npy", ".csv"):
            waves = _common_axis(waves)
        signal_io.write(path, waves)
    with (out_dir / TRUTH_FILE).open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(TRUTH_KEYS), delimiter="\t")
        writer.writeheader()
        for row in truth_rows:
            writer.writerow({k: (f"{v:.9g}" if isinstance(v, float) else v)
                             for k, v in row.items()})
    return truth_rows


SCAN_PLATE = "SCAN-A"
SCAN_THICKNESS = 3.0e-3
SCAN_DIAMETER = 9.53e-3
SCAN_POSITIONS = (("P01", 0.004, 0.120), ("P02", 0.008, 0.780), ("P03", 0.012, 0.300),
                  ("P04", 0.016, 0.620), ("P05", 0.020, 0.450), ("P06", 0.025, 0.200),
                  ("P07", 0.060, 0.700), ("P08", 0.200, 0.400))
"""(name, x, y) in metres on the paper's plate; its clamped edge is x = 0, so x is the truth.
Six positions lie within the ~30 mm where the edge changes the reflection (the critical
distance, k = 0.2), spread along the edge so that its direction is told; two lie beyond."""
SCAN_SHOTS = 3
SCAN_SNR_DB = 40.0


def make_scan(out_dir: Path, seed: int = 20261125) -> list[ScanTruth]:
    """A simulated scan of positions near the clamped edge x = 0 of the paper's plate, as a lab
    brings it: plain files that name nothing (``scan_<position>_shot<k>.csv``, force in N),
    a campaign manifest (``campaign.csv``) that says which file is where, and ``truth.tsv``.

    Each position is one simulation with the chain at distance x from the edge, on the auto
    tier: today the Mindlin plate's Green's functions near the edge; the bundled files were
    written when auto chose the 3-D plate's, on its default 16 x 16 elements (``truth.tsv``'s
    ``plate_model`` says which). Its shots differ by their noise (40 dB, 1 % drift, 12 bits).
    The model's chain stands on the plate's centre line, so y only places the position on the
    map; the free edges at y = 0 and y = 0.914 m are far from every y used.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    truth: list[ScanTruth] = []
    manifest: list[_ManifestRow] = []
    for name, x, y in SCAN_POSITIONS:
        scene = load_scene(None, [f"chain.diameter={SCAN_DIAMETER!r}",
                                  f"plate.thickness={SCAN_THICKNESS!r}",
                                  f"plate.distance_to_support={x!r}", "output.duration=auto"])
        sim = simulate(scene)
        reference = sim.truth["incident_peak_N"]
        recorded = as_measured(sim)
        for k in range(SCAN_SHOTS):
            noisy = degrade(recorded.samples, SCAN_SNR_DB, rng, reference, drift=DRIFT, bits=BITS)
            signal_io.write(out_dir / f"scan_{name}_shot{k}.csv",
                            Waveform(recorded.t0, recorded.dt, noisy, "N", None, {}))
        manifest.append({"file": f"scan_{name}_shot*.csv", "plate_id": SCAN_PLATE,
                         "position": name, "x_m": x, "y_m": y,
                         "sphere_diameter_m": SCAN_DIAMETER})
        truth.append({"position": name, "x_m": x, "y_m": y, "distance_m": x,
                      "thickness_m": SCAN_THICKNESS, "plate_model": sim.plate_model,
                      "tof_s": sim.truth["tof_s"], "arr": sim.truth["arr"]})
    for name, rows in (("campaign.csv", manifest), ("truth.tsv", truth)):
        with (out_dir / name).open("w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]),
                                    delimiter="\t" if name.endswith(".tsv") else ",")
            writer.writeheader()
            writer.writerows({k: (f"{v:.9g}" if isinstance(v, float) else v)
                              for k, v in row.items()} for row in rows)
    return truth


def samples(
    out: Path = typer.Option(None, "--out", help="Folder to write into (default: "
                             "data_samples/waveforms, or data_samples/scan with --scan)."),
    seed: int = typer.Option(None, "--seed", help="Noise seed (fixed by default: reproducible "
                             "files)."),
    scan: bool = typer.Option(False, "--scan", help="Write the simulated scan near a clamped "
                              "edge instead: plain files, campaign.csv, truth.tsv (about a "
                              "minute)."),
) -> None:
    """Regenerate the synthetic sample waveforms and their truth table (data_samples/waveforms/),
    or with --scan the simulated scan of a plate near its clamped edge (data_samples/scan/)."""
    out = out or Path("data_samples/scan" if scan else "data_samples/waveforms")
    if out.exists() and not out.is_dir():
        typer.echo(f"error: --out: {str(out)!r} is a file; give a folder", err=True)
        raise typer.Exit(2)
    if scan:
        positions = make_scan(out, 20261125 if seed is None else seed)
        typer.echo(f"wrote {len(positions)} positions x {SCAN_SHOTS} shots, campaign.csv, "
                   f"truth.tsv to {out}")
        return
    rows = make_samples(out, 20240601 if seed is None else seed)
    typer.echo(f"wrote {len({r['file'] for r in rows})} files, {len(rows)} shots, truth.tsv "
               f"to {out}")


def register(app: typer.Typer) -> None:
    """Add `samples` to the CLI."""
    app.command("samples")(samples)
