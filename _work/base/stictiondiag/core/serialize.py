"""JSON-able copies of results: the one converter every result's ``to_dict`` uses."""

from __future__ import annotations

import math
from enum import Enum
from typing import Any

import numpy as np


def to_plain(v: Any) -> Any:
    """JSON-able copy: numpy scalars -> float/int, NaN/inf -> None, arrays -> lists.

    Dicts keep their order with string keys; tuples become lists; an enum member
    becomes its value.  Anything else is returned as it is.
    """
    if isinstance(v, Enum):
        return to_plain(v.value)
    if isinstance(v, dict):
        return {str(k): to_plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [to_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return [to_plain(x) for x in v.tolist()]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        f = float(v)
        return f if math.isfinite(f) else None
    return v


def plain_float(v: Any) -> float | None:
    """One number as a JSON-able float: None and NaN/inf -> None, anything else
    ``float(v)`` (so an integer comes out as a float, as results print it)."""
    if v is None:
        return None
    f = float(v)
    return f if math.isfinite(f) else None
