"""Plain JSON values from what the analysis produces (numpy scalars and arrays, NaN)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def json_safe(o: Any) -> Any:
    """Numpy scalars and arrays as numbers and lists, tuples as lists, NaN and inf as null."""
    if isinstance(o, dict):
        return {str(k): json_safe(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [json_safe(v) for v in o]
    if isinstance(o, np.ndarray):
        return json_safe(o.tolist())
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o
