"""What the inversion reads of one sphere size's shots (:class:`FeatureSummary`), the per-shot
scatter it assumes where none is stated, and the error it raises for input it cannot use."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypedDict

from solitonde.instrument.errors import InstrumentError
from solitonde.instrument.inference.sizes import SPHERE_DIAMETER_MAX, size_problem

DEFAULT_TOF_REL_STD = 0.01
"""Per-shot TOF scatter assumed when none is given: 1 % of the TOF."""
DEFAULT_ARR_STD = 0.03
"""Per-shot ARR scatter assumed when none is given (absolute)."""
MIN_TOF_STD_S = 0.2e-6
"""Floor of the per-shot TOF scatter (a tenth of a 2 MHz sample): a scatter of 0 from few
identical shots must not make the likelihood infinitely sharp."""
MIN_ARR_STD = 0.003
"""Floor of the per-shot ARR scatter."""


class InversionError(InstrumentError, ValueError):
    """Bad inversion input; ``field`` names it."""


class FeatureSummaryDict(TypedDict):
    """A :class:`FeatureSummary` as JSON, its fields in order."""

    diameter_m: float
    tof_s: float | None
    arr: float | None
    tof_std_s: float | None
    arr_std: float | None
    n_shots: int
    arr_upper_bound: float | None
    tof_window_s: float | None


@dataclass(frozen=True)
class FeatureSummary:
    """The shots of one sphere size: mean TOF and ARR, their scatter and the shot count.

    A size whose shots show no reflection gives no TOF and no ARR but ``arr_upper_bound``, the
    largest ARR that could have hidden under the noise: it still bounds the plate (a reflection
    that small means a thin plate), and enters the likelihood as such.
    """

    diameter_m: float
    tof_s: float | None
    arr: float | None
    tof_std_s: float | None = None
    arr_std: float | None = None
    n_shots: int = 1
    arr_upper_bound: float | None = None
    tof_window_s: float | None = None
    """A hidden size's: the longest TOF its records would have shown whole (the bound says
    nothing of a reflection arriving later); None: no limit known."""

    def __post_init__(self) -> None:
        def check(name: str, value: Any, ok: bool, allowed: str) -> None:
            if not ok:
                raise InversionError(name, f"got {value!r} (allowed: {allowed})")

        def number(v: Any) -> bool:
            return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)

        hidden = self.tof_s is None and self.arr is None
        names = ("diameter_m", "arr_upper_bound") if hidden else ("diameter_m", "tof_s", "arr")
        for name in names:
            v = getattr(self, name)
            check(name, v, number(v), "a finite number" + (
                " (a size without TOF and ARR needs the bound of its hidden reflection)"
                if name == "arr_upper_bound" else ""))
        check("diameter_m", self.diameter_m, size_problem(self.diameter_m) is None,
              f"0 < D <= {SPHERE_DIAMETER_MAX:g} m; " + (size_problem(self.diameter_m) or ""))
        if hidden:
            bound = self.arr_upper_bound
            check("arr_upper_bound", bound, bound is not None and 0 < bound <= 1.5,
                  "0 < bound <= 1.5")
        else:
            check("tof_s", self.tof_s, self.tof_s is not None and self.tof_s > 0, "> 0 s")
            check("arr", self.arr, self.arr is not None and self.arr >= 0, ">= 0")
            check("arr_upper_bound", self.arr_upper_bound, self.arr_upper_bound is None,
                  "null when TOF and ARR are given")
        for name in ("tof_std_s", "arr_std"):
            v = getattr(self, name)
            check(name, v, v is None or (isinstance(v, int | float) and math.isfinite(v)
                                         and v >= 0), ">= 0, or null for the default")
        check("n_shots", self.n_shots, isinstance(self.n_shots, int) and self.n_shots >= 1,
              "an integer >= 1")
        check("tof_window_s", self.tof_window_s, self.tof_window_s is None or (
            hidden and number(self.tof_window_s)), "a finite number of seconds, for a size "
              "without TOF and ARR only, or null")

    @property
    def hidden(self) -> bool:
        """Whether this size shows no reflection (only its ARR bound)."""
        return self.tof_s is None

    @classmethod
    def from_any(cls, item: FeatureSummary | Mapping[str, Any]) -> FeatureSummary:
        if isinstance(item, FeatureSummary):
            return item
        if not isinstance(item, Mapping):
            raise InversionError("inputs", f"expected a mapping, got {type(item).__name__}")
        known = {"diameter_m", "tof_s", "arr", "tof_std_s", "arr_std", "n_shots",
                 "arr_upper_bound", "tof_window_s"}
        extra = set(item) - known
        if extra:
            raise InversionError(sorted(extra)[0], f"unknown key (allowed: {sorted(known)})")
        hidden = (item.get("tof_s") is None and item.get("arr") is None
                  and item.get("arr_upper_bound") is not None)
        for key in ("diameter_m",) if hidden else ("diameter_m", "tof_s", "arr"):
            if item.get(key) is None:
                raise InversionError(key, "missing")
        n = item.get("n_shots", 1)
        if isinstance(n, float) and n.is_integer():
            n = int(n)

        def opt(key: str) -> float | None:
            return None if item.get(key) is None else float(item[key])

        return cls(float(item["diameter_m"]), opt("tof_s"), opt("arr"), opt("tof_std_s"),
                   opt("arr_std"), 1 if n is None else n, opt("arr_upper_bound"),
                   opt("tof_window_s"))

    def to_dict(self) -> FeatureSummaryDict:
        return {"diameter_m": self.diameter_m, "tof_s": self.tof_s, "arr": self.arr,
                "tof_std_s": self.tof_std_s, "arr_std": self.arr_std, "n_shots": self.n_shots,
                "arr_upper_bound": self.arr_upper_bound, "tof_window_s": self.tof_window_s}

    def sigmas(self) -> tuple[float, float]:
        """Standard errors of the mean TOF (s) and mean ARR, before the model error."""
        if self.hidden:
            raise InversionError("tof_s", "a size without a reflection has no TOF")
        assert self.tof_s is not None  # not hidden
        s_tof = self.tof_std_s if self.tof_std_s is not None else DEFAULT_TOF_REL_STD * self.tof_s
        s_arr = self.arr_std if self.arr_std is not None else DEFAULT_ARR_STD
        root = math.sqrt(self.n_shots)
        return max(s_tof, MIN_TOF_STD_S) / root, max(s_arr, MIN_ARR_STD) / root

    def bound_sigma(self) -> float:
        """Standard error of a hidden reflection's ARR against its bound: the per-shot default
        ARR scatter over the shots."""
        return max(DEFAULT_ARR_STD, MIN_ARR_STD) / math.sqrt(self.n_shots)
