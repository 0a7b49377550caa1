"""Console tables that fit the terminal without cutting a number short.

Rich shrinks a table that is too wide by cutting cells to ``…``: a TOF of ``1270.6`` printed as
``1270…`` is a wrong number, not a narrow one. :func:`fitted_table` instead leaves out the
columns the caller ranked least useful until the rest fits, never cuts a number, wraps text
columns (a file name, flags), and says which columns it left out and where to find them all.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from rich import box
from rich.console import Console
from rich.measure import Measurement
from rich.table import Table


@dataclass(frozen=True)
class Column:
    """A column: its header, whether it holds text (wrapped) or numbers (never cut), and its
    rank: the columns of the highest ``drop_order`` are left out first (0: always shown)."""

    header: str
    text: bool = False
    drop_order: int = 0


def fitted_table(console: Console, title: str, columns: Sequence[Column],
                 rows: Sequence[Sequence[str]], hint: str = "--json") -> tuple[Table, str | None]:
    """The table of ``rows`` with as many columns as fit ``console.width``, and a note naming the
    columns left out (None when all fit)."""
    keep = list(range(len(columns)))
    while True:
        table = _table(title, [columns[i] for i in keep], [[r[i] for i in keep] for r in rows])
        if _natural_width(console, table) <= console.width:
            break
        droppable = [i for i in keep if columns[i].drop_order > 0]
        if not droppable:
            break  # the essential columns alone are wider: the text columns wrap
        worst = max(droppable, key=lambda i: (columns[i].drop_order, i))
        keep.remove(worst)
    left_out = [c.header for i, c in enumerate(columns) if i not in keep]
    note = (f"{title}: {', '.join(left_out)} left out at this width ({console.width} columns; "
            f"{hint} has every value)") if left_out else None
    return table, note


def _natural_width(console: Console, table: Table) -> int:
    """The width the table takes with no cell wrapped or cut (rich's own measure stops at the
    console's width, which would hide the overflow)."""
    return Measurement.get(console, console.options.update_width(100_000), table).maximum


def _table(title: str, columns: Sequence[Column], rows: Sequence[Sequence[str]]) -> Table:
    table = Table(title=title, box=box.SIMPLE_HEAD, pad_edge=False)
    for col in columns:
        if col.text:
            table.add_column(col.header, overflow="fold")
        else:
            # never cut to "…": a number too wide for a column folds onto a second line
            table.add_column(col.header, no_wrap=True, overflow="fold", justify="right")
    for row in rows:
        table.add_row(*row)
    return table
