"""How the table's features move with the plate's material, simulated far from the supports.

A table holds one plate material. The inversion widens its intervals by the material's spread
(instrument.inference.material_spread) through the features' slopes with respect to
``ln E'`` (E' = E / (1 - nu^2)) and ``ln rho``. Zener's single-sphere theory gives those slopes
as exchange rates (a material change acts as a thickness change through the inelasticity
lambda), but the chain's reflection also depends on the contact stiffness against the chain's
own (A_p / A_s), which lambda leaves out: on the bundled steel table the exchange rates fall
short of the slopes a table at E = 210 GPa, nu = 0.30 shows by 10-45 % in TOF and 4-18 % in
ARR far from the supports.

So the slopes are simulated: per sphere size and thickness node, the chain on Zener's dashpot
(the plate far from every support, where the table itself uses it) at the family's material and
at E and rho each moved by :data:`STEP` either way, the central difference in the logarithm.
That is 4 runs a node (about 0.01 s each), about a second per sphere size, written into the table
file as the group ``material_slopes`` (datasets ``tof_s`` and ``arr``, shape (D, t, 2): the
slopes along ``ln E'`` and ``ln rho``). ``table build`` writes it; ``table slopes FILE`` adds it
to a table built before (the features are not touched). Near a support the distance's share
(the guided waves' speed) still comes from the exchange rates, and so does all of it where
the table's reflection is a train at the detection floor (the inversion's floor nodes).
"""

from __future__ import annotations

import copy
import math
import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from solitonde.instrument.tables.table import AXES, FORMAT, TableError

STEP = 0.03
"""Relative change of E (at fixed nu) and of rho either way for the central difference: about a
grade's spread, so the slope is the secant over the range the inversion uses it for, and large
against the extractor's run-to-run rounding on weak reflections."""
GROUP = "material_slopes"
COMPONENTS = ("ln_e_prime", "ln_rho")


def _material(plate: Mapping[str, Any]) -> dict[str, Any]:
    """The plate material as a property mapping (a library name resolved)."""
    from solitonde.model.materials import material_of

    mat = plate["material"]
    if isinstance(mat, Mapping):
        return dict(mat)
    m = material_of(mat, "plate.material")
    return {"name": m.name, "youngs_modulus": m.youngs_modulus,
            "poisson_ratio": m.poisson_ratio, "density": m.density}


def simulate_slopes(sweep: Any) -> dict[str, np.ndarray]:
    """``{"tof_s": (D, t, 2), "arr": (D, t, 2)}`` for a table's sweep
    (:class:`~.table_build.Sweep`): the features' slopes along ``ln E'`` and ``ln rho`` at
    each sphere size and thickness, far from the supports; NaN where a run shows no
    reflection."""
    from solitonde.instrument.tables.table_build import simulate_point
    from solitonde.model.scene import scene_from_dict

    n_d, n_t = len(sweep.diameters_m), len(sweep.thicknesses_m)
    out = {name: np.full((n_d, n_t, 2), np.nan) for name in ("tof_s", "arr")}
    far = len(sweep.distances_m) - 1
    for i_d in range(n_d):
        for i_t in range(n_t):
            base = sweep.scene_at(i_d, i_t, far).model_dump(mode="json")
            base["effects"]["plate_model"] = "infinite"
            base["plate"]["material"] = _material(base["plate"])
            for k, key in enumerate(("youngs_modulus", "density")):
                ends = []
                for sign in (1.0, -1.0):
                    data = copy.deepcopy(base)
                    data["plate"]["material"][key] *= 1.0 + sign * STEP
                    data["plate"]["material"]["name"] = f"{key} {sign * STEP:+g}"
                    ends.append(simulate_point(scene_from_dict(data)))
                if all(e.get("tof_s") is not None and e.get("arr") is not None for e in ends):
                    span = math.log((1.0 + STEP) / (1.0 - STEP))
                    for name in out:
                        out[name][i_d, i_t, k] = (ends[0][name] - ends[1][name]) / span
    return out


def write_slopes(fh: h5py.File, slopes: Mapping[str, np.ndarray]) -> None:
    """Store ``slopes`` in an open table file (replacing any there)."""
    if GROUP in fh:
        del fh[GROUP]
    group = fh.create_group(GROUP)
    group.attrs["components"] = list(COMPONENTS)
    group.attrs["step"] = STEP
    group.attrs["plate_model"] = "infinite"
    for name, values in slopes.items():
        group.create_dataset(name, data=np.asarray(values, dtype=float))


def read_slopes(fh: h5py.File, shape: tuple[int, ...]) -> dict[str, np.ndarray] | None:
    """The stored slopes, or None for a table built before they were (the inversion then uses
    the exchange rates alone). Raises TableError for a group of the wrong shape."""
    if GROUP not in fh:
        return None
    want = (shape[0], shape[1], len(COMPONENTS))
    out = {}
    for name in ("tof_s", "arr"):
        values = np.asarray(fh[GROUP][name][...], dtype=float) if name in fh[GROUP] else None
        if values is None or values.shape != want:
            raise TableError(f"{GROUP}/{name}", f"expected shape {want}, got "
                             f"{None if values is None else values.shape}")
        out[name] = values
    return out


def add_to_table(path: str | Path) -> dict[str, np.ndarray]:
    """Simulate the slopes of the table at ``path`` and write them into it: on a copy, renamed
    onto the file only once written, so an interrupted run leaves the table as it was."""
    from solitonde.instrument.tables.table_build import Sweep

    path = Path(path)
    with h5py.File(path, "r") as fh:
        if fh.attrs.get("format") != FORMAT or not fh.attrs.get("complete", False):
            raise TableError("table", f"{str(path)!r} is not a complete solitonde model table")
        import json

        sweep = Sweep.from_dict(json.loads(fh.attrs["sweep"]))
        sizes = tuple(fh[f"axes/{a}"].size for a in AXES)
    slopes = simulate_slopes(sweep)
    part = path.with_name(path.name + ".slopes")
    shutil.copyfile(path, part)
    try:
        with h5py.File(part, "r+") as fh:
            write_slopes(fh, slopes)
        with h5py.File(part, "r") as fh:
            read_slopes(fh, sizes)
        os.replace(part, path)
    finally:
        part.unlink(missing_ok=True)
    return slopes


__all__ = ["COMPONENTS", "GROUP", "STEP", "add_to_table", "read_slopes", "simulate_slopes",
           "write_slopes"]
