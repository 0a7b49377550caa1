"""The plate map's title says the whole reason, wrapped to the figure, never cut."""

from __future__ import annotations

from matplotlib.backends.backend_agg import FigureCanvasAgg

from solitonde.instrument.plotting import map_figure

REASON = ("the positions are far from any support: fewer than two distance answers are "
          "constrained (the others only bound it); add positions nearer the edge")


def test_a_long_reason_is_wrapped_inside_the_figure_and_kept_whole():
    plate_map = {"plate_id": "P", "positions": [{"position": "A1", "x_m": 0.1, "y_m": 0.1,
                                                 "thickness_m": None, "distance_m": None}],
                 "support": None, "support_reason": REASON}
    for width in (1200, 700):
        fig = map_figure(plate_map, width_px=width)
        title = fig._suptitle
        assert " ".join(title.get_text().split()).endswith(REASON)
        box = title.get_window_extent(FigureCanvasAgg(fig).get_renderer())
        assert box.x0 >= 0 and box.x1 <= width, (width, box)
