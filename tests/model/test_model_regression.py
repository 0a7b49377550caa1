"""Pinned outputs of the model: physical observables on any machine, every bit on the pinning one.

Twelve small scenes cover every plate model (rigid, halfspace, infinite, sem, greens), gravity on
and off, Kuwabara-Kono dissipation on and off, both integrators (verlet everywhere, dopri5 on the
plate models that support it) and traces on and off. For each, the sensor samples, the energy
balance, the traces (when on), the truth dict and the key diagnostics are stored in
``tests/data/model_regression.npz``; ``tests/data/model_regression_machine.json`` names the
machine code they hold on to 1e-12 (numba's target triple, CPU name and features, the numba and
llvmlite versions; written by ``--regenerate``).

Two comparisons:

* **On any machine** (``test_observables_match_pinned``): the physical observables, to the
  tolerance the method promises. The kernels are compiled with fastmath (reassociated sums,
  fused multiply-adds), so their rounding follows the CPU's vector width and instruction set, and
  an adaptive run can even take other steps. The tolerance ``tol`` of a scene:

  - dopri5: ``2 n rtol``, ``n`` the accepted steps: each step's local error is held under
    ``rtol`` of the component's scale, the local errors of ``n`` steps add up at most linearly,
    and two runs (pinned and now) each carry that much;
  - a fixed step (velocity Verlet, the spectral-element plate): ``2 n ROUNDING``, ``n`` the
    steps: nothing but rounding differs, at most :data:`ROUNDING` per step (a reassociated or
    fused sum of up to 256 terms), added up linearly.

  Compared with it: the sensor trace and each recorded trace (|difference| <= tol x the trace's
  largest magnitude); the peak forces (tol x the largest of them); the peak times (tol x the
  simulated duration, twice that for the TOF, a difference of two times); the ARR (the relative
  errors of its two peaks added); the energy balance and the energies (5/2 tol x the energy
  scale: the Hertz energy goes as the overlap to the power 5/2). Step counts, rejected steps and
  the integration error measures are properties of the arithmetic, not of the plate: not
  compared across machines.
* **On the pinning machine** (``test_outputs_match_pinned``): every pinned array to 1e-12 (an
  absolute floor of 1e-12 times the array's largest magnitude, NaNs stay NaNs), the guard of a
  refactor that must not change a bit. Skipped, naming both, on another machine or numba.

Regenerate the pinned file only when the numbers are meant to change (a change of physics or
scheme), and say so in the commit; it rewrites the machine file too:

    .venv/bin/python tests/model/test_model_regression.py --regenerate

``--diff`` prints each array's largest relative difference against the pinned one. The pins under
the generic CPU (no vector extensions, no FMA): ``NUMBA_CPU_NAME=generic .venv/bin/python -m
pytest tests/model/test_model_regression.py``, which the slow-marked
``test_observables_hold_under_the_generic_cpu`` runs in a subprocess.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from solitonde.model.scene import SolverSpec, scene_from_dict
from solitonde.model.simulate import simulate

PINNED = Path(__file__).resolve().parents[1] / "data" / "model_regression.npz"
MACHINE = Path(__file__).resolve().parents[1] / "data" / "model_regression_machine.json"
RTOL = 1e-12
ROUNDING = 256 * np.finfo(float).eps
"""Rounding one step can change on another CPU: a fused or reassociated sum of up to 256 terms."""
HERTZ_ENERGY_POWER = 2.5
"""The Hertz energy goes as the overlap to the power 5/2: a relative error e in the overlaps is
at most 5/2 e in the energy."""

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


def machine() -> dict[str, Any]:
    """The machine code numba compiles for here: target triple, CPU name and features (what
    ``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES`` set), numba's and llvmlite's versions."""
    import llvmlite
    import numba
    from numba.core.registry import cpu_target

    triple, cpu, features = cpu_target.target_context.codegen().magic_tuple()
    return {"triple": triple, "cpu": cpu, "features": features, "numba": numba.__version__,
            "llvmlite": llvmlite.__version__}


def regenerate() -> None:
    """Run every scene with the current code and write the pinned file and the machine file."""
    pinned: dict[str, np.ndarray] = {}
    for name in SCENES:
        pinned.update(outputs(name))
    PINNED.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(PINNED, **pinned)
    MACHINE.write_text(json.dumps(machine(), indent=1) + "\n")
    print(f"wrote {len(pinned)} arrays of {len(SCENES)} scenes to {PINNED}, and {MACHINE.name}")


def tolerance(name: str, diagnostics: dict[str, float]) -> float:
    """The relative agreement the method promises for scene ``name`` between two machines (see
    the module docstring), from the pinned step count."""
    solver = SCENES[name].get("solver", {})
    if solver.get("integrator") == "dopri5":
        rtol = float(solver.get("rtol", SolverSpec().rtol))
        return 2.0 * diagnostics["steps_accepted"] * rtol
    return 2.0 * diagnostics["steps"] * ROUNDING


def observable_violations(name: str, got: dict[str, np.ndarray],
                          want: dict[str, np.ndarray]) -> list[str]:
    """Every physical observable of scene ``name`` outside its tolerance, as readable lines."""
    key = f"{name}/"
    diag = dict(zip(want[key + "diagnostics_keys"].tolist(),
                    want[key + "diagnostics"].tolist(), strict=True))
    have_diag = dict(zip(got[key + "diagnostics_keys"].tolist(),
                         got[key + "diagnostics"].tolist(), strict=True))
    tol = tolerance(name, diag)
    e_tol = HERTZ_ENERGY_POWER * tol * diag["energy_scale_J"]
    bad: list[str] = []

    def check(what: str, have: Any, ref: Any, atol: float) -> None:
        have, ref = np.asarray(have, dtype=float), np.asarray(ref, dtype=float)
        if have.shape != ref.shape:
            bad.append(f"{what}: shape {have.shape}, pinned {ref.shape}")
            return
        if not np.array_equal(np.isnan(have), np.isnan(ref)):
            bad.append(f"{what}: NaNs moved")
            return
        finite = np.isfinite(ref)
        worst = float(np.max(np.abs(have[finite] - ref[finite]), initial=0.0))
        if worst > atol:
            bad.append(f"{what}: |difference| {worst:.3e} > {atol:.3e} (tol {tol:.2e})")

    for field in sorted(k[len(key):] for k in want if k.startswith(key)):
        if field == "samples" or field.startswith("trace_"):
            ref = want[key + field]
            scale = float(np.nanmax(np.abs(ref))) if np.isfinite(ref).any() else 0.0
            check(field, got[key + field], ref, tol * scale)
        elif field == "energy":
            check(field, got[key + field], want[key + field], e_tol)
    truth = dict(zip(want[key + "truth_keys"].tolist(), want[key + "truth"].tolist(), strict=True))
    now = dict(zip(got[key + "truth_keys"].tolist(), got[key + "truth"].tolist(), strict=True))
    if set(now) != set(truth):
        bad.append(f"truth keys {sorted(now)}, pinned {sorted(truth)}")
        return bad
    forces = [abs(v) for k, v in truth.items() if k.endswith("_N")]
    f_max = max(forces, default=0.0)
    duration = diag["duration_s"]
    for k, ref in truth.items():
        if k.endswith("_N"):
            atol = tol * f_max
        elif k == "tof_s":
            atol = 2.0 * tol * duration
        elif k.endswith("_s"):
            atol = tol * duration
        elif k == "arr":  # reflected / incident: their relative errors add
            atol = abs(ref) * tol * f_max * (1.0 / abs(truth["reflected_peak_N"])
                                             + 1.0 / abs(truth["incident_peak_N"]))
        else:
            raise AssertionError(f"no tolerance rule for truth[{k!r}]")
        check(f"truth[{k}]", now[k], ref, atol)
    for k in ("energy_scale_J", "plate_work_J", "dissipated_J", "plate_energy_J"):
        if k in diag:
            check(f"diagnostics[{k}]", have_diag.get(k, np.nan), diag[k], e_tol)
    check("diagnostics[duration_s]", have_diag["duration_s"], duration, tol * duration)
    return bad


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


@pytest.fixture(scope="module")
def computed() -> dict[str, dict[str, np.ndarray]]:
    """Each scene's outputs, computed once for both comparisons."""
    return {}


def _outputs(name: str, computed: dict[str, dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    if name not in computed:
        computed[name] = outputs(name)
    return computed[name]


@pytest.mark.parametrize("name", list(SCENES))
def test_observables_match_pinned(name: str, pinned: dict[str, np.ndarray],
                                  computed: dict[str, dict[str, np.ndarray]]) -> None:
    """Peak forces, peak times, TOF, ARR, traces and energies within the scheme's tolerance."""
    bad = observable_violations(name, _outputs(name, computed), pinned)
    assert not bad, f"{name} on {machine()['cpu']}:\n" + "\n".join(bad)


def _pinning_machine() -> dict[str, Any]:
    return json.loads(MACHINE.read_text())


@pytest.mark.parametrize("name", list(SCENES))
def test_outputs_match_pinned(name: str, pinned: dict[str, np.ndarray],
                              computed: dict[str, dict[str, np.ndarray]]) -> None:
    """Every pinned array of the scene within rtol 1e-12 (floor 1e-12 x the array's max), on
    the machine code that wrote them."""
    here, there = machine(), _pinning_machine()
    if here != there:
        differ = {k: (here.get(k), there.get(k)) for k in set(here) | set(there)
                  if here.get(k) != there.get(k)}
        shown = {k: (v if k != "features" else "(differ)") for k, v in differ.items()}
        pytest.skip(f"bits pinned on other machine code: {shown} (here, pinned)")
    got = _outputs(name, computed)
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


@pytest.mark.slow
def test_observables_hold_under_the_generic_cpu() -> None:
    """The observables hold when numba compiles for the generic x86-64 CPU (no AVX, no FMA): the
    way to see on one machine what another CPU does to the bits."""
    env = {**os.environ, "NUMBA_CPU_NAME": "generic"}
    env.pop("NUMBA_CPU_FEATURES", None)
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          str(Path(__file__)), "-k", "observables and not generic"],
                         env=env, capture_output=True, text=True, timeout=3000)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
    assert f"{len(SCENES)} passed" in out.stdout


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
        sys.exit("usage: python tests/model/test_model_regression.py --regenerate | --diff")
