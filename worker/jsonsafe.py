"""JSON text from what a training reports (kept import-light: the training child loads it)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any


def to_json(obj: Any) -> str:
    """JSON text for a progress dict or summary: numpy scalars become numbers, NaN/inf become null."""

    def clean(v: Any) -> Any:
        if isinstance(v, bool) or v is None or isinstance(v, (int, str)):
            return v
        if isinstance(v, float):
            return v if math.isfinite(v) else None
        if isinstance(v, Mapping):
            return {str(k): clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if hasattr(v, "tolist"):  # numpy / torch scalars and arrays
            return clean(v.tolist())
        if hasattr(v, "__float__"):
            return clean(float(v))
        return str(v)

    return json.dumps(clean(obj), separators=(",", ":"), allow_nan=False)
