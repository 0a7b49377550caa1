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
from typing import Any

import numpy as np
import typer

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


def make_samples(out_dir: Path, seed: int = 20240601) -> list[dict[str, Any]]:
    """Write every sample file into ``out_dir`` and return the truth rows (also in truth.tsv)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    truth_rows = []
    for spec in SPECS:
        waves = []
        for shot in range(spec.shots):
            height = 5e-3 * (1.0 + 0.01 * rng.uniform(-1.0, 1.0))
            scene = load_scene(None, [*spec.overrides, f"striker.drop_height={height!r}",
                                      "effects.plate_model=infinite", "output.duration=auto"])
            sim = simulate(scene)
            t = sim.truth
            truth = Truth.from_trace(sim.samples, sim.dt, sim.t0,
                                     (t["incident_time_s"], t["incident_peak_N"]),
                                     (t["reflected_time_s"], t["reflected_peak_N"]))
            reference = truth.incident_peak_N
            samples = degrade(sim.samples, spec.snr_db, rng, reference, drift=DRIFT, bits=BITS)
            meta = {"shot": shot,
                    "plate_id": f"synthetic-t{scene.plate.thickness * 1e3:.2f}mm",
                    "position": scene.plate.distance_to_support,
                    "sphere_diameter": scene.chain.diameter, "synthetic": True,
                    "snr_db": spec.snr_db, "drop_height_m": height}
            waves.append(Waveform(sim.t0, sim.dt, samples, "N", None, meta))
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
            n = min(w.n for w in waves)  # shots share one time axis: cut to the shortest
            waves = [Waveform(w.t0, w.dt, w.samples[:n], w.units, None, w.metadata) for w in waves]
        signal_io.write(path, waves)
    with (out_dir / TRUTH_FILE).open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(TRUTH_KEYS), delimiter="\t")
        writer.writeheader()
        for row in truth_rows:
            writer.writerow({k: (f"{v:.9g}" if isinstance(v, float) else v)
                             for k, v in row.items()})
    return truth_rows


def samples(
    out: Path = typer.Option(Path("data_samples/waveforms"), "--out", help="Folder to write into."),
    seed: int = typer.Option(20240601, "--seed", help="Noise seed (fixed: reproducible files)."),
) -> None:
    """Regenerate the synthetic sample waveforms and their truth table (data_samples/waveforms/)."""
    if out.exists() and not out.is_dir():
        typer.echo(f"error: --out: {str(out)!r} is a file; give a folder", err=True)
        raise typer.Exit(2)
    rows = make_samples(out, seed)
    typer.echo(f"wrote {len({r['file'] for r in rows})} files, {len(rows)} shots, truth.tsv "
               f"to {out}")


def register(app: typer.Typer) -> None:
    """Add `samples` to the CLI."""
    app.command("samples")(samples)
