"""Values made ready for JSON: one rule for the service, the command line and the files.

JSON has no NaN or infinity and knows neither numpy types nor paths, so every writer of JSON in
the service and the command line passes its data through :func:`json_ready`. (Metadata written
into waveform files keeps its own rule, ``waveform._jsonable``: NaN survives a file round trip.)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import PurePath
from typing import Any

import numpy as np


def json_ready(value: Any) -> Any:
    """Mappings (keys as text), lists, tuples and arrays to plain containers, numpy scalars to
    Python numbers, paths to text; NaN and infinities to None (null), recursively."""
    if isinstance(value, Mapping):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_ready(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, PurePath):
        return str(value)
    return value
