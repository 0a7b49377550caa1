"""Pinned outputs of the model: a refactor of model/ must reproduce them to 1e-12.

Twelve small scenes cover every plate model (rigid, halfspace, infinite, sem, greens), gravity on
and off, Kuwabara-Kono dissipation on and off, both integrators (verlet everywhere, dopri5 on the
plate models that support it) and traces on and off. For each, the sensor samples, the energy
balance, the traces (when on), the truth dict and the key diagnostics are stored in
``tests/data/model_regression.npz``.

The pinned file was written by the code *before* a refactor; regenerate it only when the numbers
are meant to change (a change of physics or scheme), and say so in the commit:

    .venv/bin/python tests/test_model_regression.py --regenerate

Comparison: relative 1e-12 per element, with an absolute floor of 1e-12 times the array's largest
magnitude (so that exact zeros and values at round-off of zero compare sensibly); NaNs must stay
NaNs. Diagnostics that are timings (wall_s ...) are not pinned.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from solitonde.model.scene import scene_from_dict
from solitonde.model.simulate import simulate

PINNED = Path(__file__).parent / "data" / "model_regression.npz"
RTOL = 1e-12

#: A coarse mesh of the paper's plate (as in test_sem_coupled.py) and a short record: the
#: coupling's arithmetic is pinned, not the plate's accuracy.
COARSE_SEM = {"elements": [8, 8, 1], "order": [4, 4, 2], "contact_refinement": 0}
NEAR = {"distance_to_support": 0.05}
SHORT = {"n_particles": 8, "sensor_index": 4}
#: Traces on at a quarter of the default sample rate keep the pinned file small.
TRACES = {"traces": True, "sample_rate": 5e5}
DAMPED = {"dissipation": True, "damping": 2e-6}

SCENES: dict[str, dict[str, Any]] = {
    "rigid_gravity_traces": {
        "effects": {"plate_model": "rigid", "gravity": True}, "output": TRACES},
    "halfspace_nogravity": {"effects": {"plate_model": "halfspace", "gravity": False}},
    "infinite_gravity": {"effects": {"plate_model": "infinite", "gravity": True}},
    "infinite_damped_traces": {
        "effects": {"plate_model": "infinite", "gravity": True, **DAMPED},
        "output": TRACES},
    "rigid_damped_nogravity": {
        "effects": {"plate_model": "rigid", "gravity": False, **DAMPED}},
    "infinite_dopri5": {
        "effects": {"plate_model": "infinite", "gravity": True},
        "solver": {"integrator": "dopri5", "rtol": 1e-7}},
    "infinite_dopri5_damped": {
        "effects": {"plate_model": "infinite", "gravity": True, **DAMPED},
        "solver": {"integrator": "dopri5", "rtol": 1e-7}},
    "halfspace_dopri5_damped_traces": {
        "effects": {"plate_model": "halfspace", "gravity": True, **DAMPED},
        "solver": {"integrator": "dopri5", "rtol": 1e-7}, "output": TRACES},
    "rigid_dopri5_nogravity_traces": {
        "effects": {"plate_model": "rigid", "gravity": False},
        "solver": {"integrator": "dopri5"}, "output": TRACES},
    "sem_gravity_traces": {
        "effects": {"plate_model": "sem", "gravity": True}, "plate": NEAR, "sem": COARSE_SEM,
        "chain": SHORT, "output": {**TRACES, "duration": 3e-4}},
    "sem_damped_nogravity": {
        "effects": {"plate_model": "sem", "gravity": False, **DAMPED}, "plate": NEAR,
        "sem": COARSE_SEM, "chain": SHORT, "output": {"duration": 3e-4}},
    "greens_damped_gravity": {
        "effects": {"plate_model": "greens", "gravity": True, **DAMPED}, "plate": NEAR,
        "sem": COARSE_SEM, "chain": SHORT, "output": {"duration": 3e-4}},
}

#: Diagnostics that are numbers of the run (not timings, not descriptions).
DIAGNOSTICS = (
    "energy_drift", "energy_error_final", "energy_scale_J", "plate_work_J", "dissipated_J",
    "steps", "dt_s", "duration_s", "steps_accepted", "steps_rejected", "rhs_evaluations",
    "energy_deviation_step_ends_J", "plate_energy_J", "plate_steps", "chain_substeps",
)


def outputs(name: str) -> dict[str, np.ndarray]:
    """The pinned quantities of scene ``name``, as float arrays keyed ``name/field``."""
    r = simulate(scene_from_dict(SCENES[name]))
    out = {"samples": r.samples, "energy": r.energy}
    for key, value in (r.traces or {}).items():
        out[f"trace_{key}"] = value
    out["truth"] = np.array([r.truth[k] for k in sorted(r.truth)], dtype=float)
    out["truth_keys"] = np.array(sorted(r.truth))
    present = [k for k in DIAGNOSTICS if k in r.diagnostics]
    out["diagnostics"] = np.array([float(r.diagnostics[k]) for k in present])
    out["diagnostics_keys"] = np.array(present)
    return {f"{name}/{k}": np.asarray(v) for k, v in out.items()}


def regenerate() -> None:
    """Run every scene with the current code and write the pinned file."""
    pinned: dict[str, np.ndarray] = {}
    for name in SCENES:
        pinned.update(outputs(name))
    PINNED.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(PINNED, **pinned)
    print(f"wrote {len(pinned)} arrays of {len(SCENES)} scenes to {PINNED}")


def relative_difference(got: np.ndarray, want: np.ndarray) -> float:
    """Largest |got - want| / max(|want|, 1e-12 max|want|) over the finite elements."""
    finite = np.isfinite(want)
    if not finite.any():
        return 0.0
    scale = np.abs(want[finite]).max()
    floor = max(RTOL * scale, np.finfo(float).tiny)
    denom = np.maximum(np.abs(want[finite]), floor / RTOL)
    return float(np.max(np.abs(got[finite] - want[finite]) / denom))


@pytest.fixture(scope="module")
def pinned() -> dict[str, np.ndarray]:
    with np.load(PINNED) as data:
        return {k: data[k] for k in data.files}


@pytest.mark.parametrize("name", list(SCENES))
def test_outputs_match_pinned(name: str, pinned: dict[str, np.ndarray]) -> None:
    """Every pinned array of the scene within rtol 1e-12 (floor 1e-12 x the array's max)."""
    got = outputs(name)
    want_keys = {k for k in pinned if k.startswith(f"{name}/")}
    assert set(got) == want_keys
    for key in sorted(want_keys):
        want, have = pinned[key], got[key]
        if want.dtype.kind in "US":
            assert have.tolist() == want.tolist(), key
            continue
        assert have.shape == want.shape, key
        np.testing.assert_array_equal(np.isnan(have), np.isnan(want), err_msg=key)
        finite = np.isfinite(want)
        atol = RTOL * (np.abs(want[finite]).max() if finite.any() else 0.0)
        np.testing.assert_allclose(have, want, rtol=RTOL, atol=atol, err_msg=key)


if __name__ == "__main__":
    if sys.argv[1:] == ["--regenerate"]:
        regenerate()
    elif sys.argv[1:] == ["--diff"]:
        with np.load(PINNED) as data:
            worst = 0.0
            for scene in SCENES:
                for key, have in outputs(scene).items():
                    if have.dtype.kind not in "US":
                        d = relative_difference(have, data[key])
                        worst = max(worst, d)
                        same = np.array_equal(have, data[key], equal_nan=True)
                        print(f"{key}: {d:.3e}{'  (bit-identical)' if same else ''}")
            print(f"largest relative difference: {worst:.3e}")
    else:
        sys.exit("usage: python tests/test_model_regression.py --regenerate | --diff")
