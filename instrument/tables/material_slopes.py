"""How the table's features move with the plate's material, simulated far from the supports.

A table holds one plate material. The inversion widens its intervals by the material's spread
(instrument.inference.material_spread) through the features' slopes with respect to
``ln E'`` (E' = E / (1 - nu^2)) and ``ln rho``. Zener's single-sphere theory gives those slopes
as exchange rates (a material change acts as a thickness change through the inelasticity
lambda), but the chain's reflection also depends on the contact stiffness against the chain's
own (A_p / A_s), which lambda leaves out: far from the supports the exchange rates fall short
by up to 24 % in TOF and 15 % in ARR against an independent solve of the chain on steel at E =
200 and 210 GPa, 1.98-6.0 mm (tests/instrument/test_material_slopes.py).

So the slopes are simulated: per sphere size and thickness node, the chain on Zener's dashpot
(the plate far from every support, where the table itself uses it) at the family's material and
at E and rho each moved by :data:`~.table_build.SLOPE_STEP` (3 %) either way, the central
difference in the logarithm. That is 4 runs a node (about 0.01 s each), about a second per
sphere size, written into the table file as the group ``material_slopes`` (datasets ``tof_s``
and ``arr``, shape (D, t, 2): the slopes along ``ln E'`` and ``ln rho``). ``table build`` writes it
(:func:`~.table_build.simulate_slopes`, :func:`~.table_build.write_slopes`; the reader is
:func:`~.table.read_slopes`); :func:`add_to_table` (``table slopes FILE``) adds it to a table
built before (the features are not touched). Near a support the distance's share
(the guided waves' speed) still comes from the exchange rates, and so does all of it where
the table's reflection is a train at the detection floor (the inversion's floor nodes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from solitonde.instrument.tables.sweep import Sweep
from solitonde.instrument.tables.table import (
    ModelTable,
    TableError,
    add_to_file,
    read_slopes,
    require_complete,
)
from solitonde.instrument.tables.table_build import simulate_slopes, write_slopes
from solitonde.signal.features import EXTRACTOR_VERSION


def add_to_table(path: str | Path) -> dict[str, np.ndarray]:
    """Simulate the slopes of the table at ``path`` and write them into it: on a copy, renamed
    onto the file only once written, so an interrupted run leaves the table as it was."""
    require_complete(path)
    table = ModelTable.load(path)
    if table.reading_version != EXTRACTOR_VERSION:
        raise TableError("reading_version", f"the table's points were read with the extractor's "
                         f"reading {table.reading_version}, slopes now would be read with "
                         f"{EXTRACTOR_VERSION}: rebuild the table (`table build`, which simulates "
                         "its slopes)")
    slopes = simulate_slopes(Sweep.from_dict(table.sweep))
    add_to_file(path, ".slopes", lambda fh: write_slopes(fh, slopes),
                lambda fh: read_slopes(fh, table.shape))
    return slopes


__all__ = ["add_to_table"]
