"""Binomial rates as the study and the datasets report them: a 95 % Wilson interval and a 'k/n (rate)' cell."""
from __future__ import annotations

import math

WILSON_Z_95 = 1.959963984540054


def wilson_interval(successes: int, n: int, z: float = WILSON_Z_95) -> tuple[float, float] | None:
    """95 % Wilson score interval of a binomial rate; None when there are no trials."""
    if n == 0:
        return None
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    # The bounds are exactly 0 and 1 at the extremes; rounding would leave 0.9999999999999999.
    low = 0.0 if successes == 0 else centre - half
    high = 1.0 if successes == n else centre + half
    return (low, high)


def count_and_rate(k: int, n: int) -> str:
    """'3/4 (75.0 %)', or '-' where there is nothing to count."""
    return f"{k}/{n} ({100 * k / n:.1f} %)" if n else "-"
