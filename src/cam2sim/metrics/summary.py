"""One metric over many frames: its mean, spread, 10th and 90th percentiles and count.

The one summary record of the image measures (``images.json``), the semantic IoU and the
splat's scores (``eval.json``): :func:`summarise` drops missing values (None, NaN) and leaves
every statistic None when nothing is left, never NaN.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pydantic

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__ = ["MetricSummary", "summarise"]


class MetricSummary(pydantic.BaseModel):
    """Mean, population standard deviation, 10th and 90th percentile and count of one metric.

    Every statistic is None when ``n`` is 0 (no frame had a value); never NaN. Summaries
    written before the records were one lack ``std`` or the percentiles: those read as None.
    """

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    mean: float | None = None
    std: float | None = None
    p10: float | None = None
    p90: float | None = None
    n: int = 0


def summarise(values: Iterable[float | None]) -> MetricSummary:
    """Summarise the values that are not None (nor NaN)."""
    kept = np.asarray([v for v in values if v is not None and not math.isnan(v)], dtype=np.float64)
    if kept.size == 0:
        return MetricSummary(n=0)
    return MetricSummary(
        mean=float(kept.mean()),
        std=float(kept.std()),
        p10=float(np.percentile(kept, 10)),
        p90=float(np.percentile(kept, 90)),
        n=int(kept.size),
    )
