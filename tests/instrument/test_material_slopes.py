"""The table's simulated material slopes, against an independent solve and Zener's exchange rates.

The inversion widens its intervals by the plate material's spread through how the features move
with ``ln E'`` (E' = E / (1 - nu^2)) and ``ln rho``. The bundled tables carry those slopes as
simulated far from the supports (instrument/tables/material_slopes.py). Here they are checked
against scipy's DOP853 solve of the chain on Zener's dashpot (tests/support/independent_chain.py,
no model code) at two Young's moduli, and the inversion's material term is checked to use them.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from independent_chain import features_of

from solitonde.instrument.inference.fine_grid import fine_grid
from solitonde.instrument.inference.material_spread import sensitivity
from solitonde.instrument.tables.material_slopes import add_to_table
from solitonde.instrument.tables.table import MATERIAL_SLOPES, ModelTable, TableError

ROOT = Path(__file__).resolve().parents[2]
STEEL_TABLE = ROOT / "data_samples" / "steel_table.h5"
A36 = {"youngs_modulus": 200e9, "poisson_ratio": 0.26, "density": 7850.0}
E_STEP = 1.05
"""The independent solve's second modulus: 5 %, about the grade's range (190-210 GPa)."""


@pytest.fixture(scope="module")
def steel() -> ModelTable:
    return ModelTable.load(STEEL_TABLE)


def test_the_bundled_tables_carry_their_slopes(steel: ModelTable) -> None:
    default = ModelTable.load(ROOT / "data_samples" / "default_table.h5")
    for table in (steel, default):
        assert table.material_slopes is not None
        n_d, n_t = table.shape[:2]
        assert table.material_slopes["arr"].shape == (n_d, n_t, 2)


def test_the_slopes_match_an_independent_solve_at_two_moduli(steel: ModelTable) -> None:
    """At the 4.15 mm node, far from the supports: TOF and ARR of the independent solve at
    E = 200 and 210 GPa (nu, rho the same) against the table's slopes times d ln E'. The
    exchange rates alone fall short by 18 % in ARR here; the simulated slopes agree within 5 %
    (the secant over +-3 % against one over 5 %, and the extractor's rounding)."""
    i_t = 11
    t_node = float(steel.axes["thickness_m"][i_t])
    assert abs(t_node - 4.146e-3) < 1e-5
    tof0, arr0 = features_of(A36, t_node)
    tof1, arr1 = features_of({**A36, "youngs_modulus": A36["youngs_modulus"] * E_STEP}, t_node)
    step = math.log(E_STEP)
    slope_tof, slope_arr = (steel.material_slopes[k][0, i_t, 0] for k in ("tof_s", "arr"))
    assert slope_arr * step == pytest.approx(arr1 - arr0, rel=0.05)
    assert slope_tof * step == pytest.approx(tof1 - tof0, rel=0.05)
    # the inversion's material term at that node, far from the supports, is the simulated slope
    grid = fine_grid(steel, 0)
    u_tof, u_arr = sensitivity(steel, grid, {"youngs_modulus_rel_sd": 1.0,
                                             "poisson_ratio_sd": 0.0, "density_rel_sd": 0.0})
    i = int(np.argmin(abs(grid.thickness_m - t_node)))
    assert u_arr[0, i, -1] == pytest.approx(slope_arr, rel=0.01)
    assert u_tof[0, i, -1] == pytest.approx(slope_tof, rel=0.01)
    # and Zener's exchange rates alone are further off: a table without the slopes uses them
    steel_rates = ModelTable.load(STEEL_TABLE)
    steel_rates.material_slopes = None
    _, rates_arr = sensitivity(steel_rates, fine_grid(steel_rates, 0), {
        "youngs_modulus_rel_sd": 1.0, "poisson_ratio_sd": 0.0, "density_rel_sd": 0.0})
    assert abs(rates_arr[0, i, -1] * step / (arr1 - arr0) - 1.0) > 0.10


def test_slopes_are_added_to_an_older_table_in_place(tmp_path: Path) -> None:
    """``table slopes`` (add_to_table) on a table built before the slopes: the group is written,
    the features are untouched, and a table without it still loads (the exchange rates)."""
    old = tmp_path / "old.h5"
    shutil.copyfile(STEEL_TABLE, old)
    with h5py.File(old, "r+") as fh:
        del fh[MATERIAL_SLOPES]
    before = ModelTable.load(old)
    assert before.material_slopes is None
    add_to_table(old)
    after = ModelTable.load(old)
    assert after.material_slopes is not None
    assert np.array_equal(after.features["arr"], before.features["arr"], equal_nan=True)
    assert np.allclose(after.material_slopes["arr"],
                       ModelTable.load(STEEL_TABLE).material_slopes["arr"], equal_nan=True)
    # a table read another way than shots are now gets no slopes read this way
    with h5py.File(old, "r+") as fh:
        del fh[MATERIAL_SLOPES]
        fh.attrs["reading_version"] = after.reading_version - 1
    with pytest.raises(TableError, match="rebuild the table") as err:
        add_to_table(old)
    assert err.value.field == "reading_version"
