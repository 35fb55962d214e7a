"""Upper quantiles of the normal and χ² laws, for the tests' thresholds at a false-alarm rate.

The estimator sets its thresholds once from its declared false-alarm rate; these two laws are all it asks
of a statistics library, and importing scipy.stats for them costs a process about a second. The normal
quantile is the standard library's (Wichura's AS 241, accurate to ~1e-16 relative in the tail); χ² with a
few degrees of freedom has a closed-form survival function, inverted by bisection on its logarithm.
"""

from __future__ import annotations

import functools
import math
from statistics import NormalDist

_NORMAL = NormalDist()


def normal_isf(p: float) -> float:
    """The z with P(Z > z) = ``p`` for a standard normal Z (0 < p < 1)."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"a tail probability must be within (0, 1), got {p!r}")
    return -_NORMAL.inv_cdf(p)


def chi2_sf(x: float, k: int) -> float:
    """P(X > ``x``) for X χ² with ``k`` (a positive integer) degrees of freedom: the finite series of the
    incomplete gamma function at integer or half-integer order."""
    if k < 1 or int(k) != k:
        raise ValueError(f"degrees of freedom must be a positive integer, got {k!r}")
    if x <= 0.0:
        return 1.0
    half = 0.5 * x
    if k % 2 == 0:  # e^{-x/2} Σ_{i<k/2} (x/2)^i / i!
        term, total = 1.0, 1.0
        for i in range(1, k // 2):
            term *= half / i
            total += term
        return math.exp(-half) * total
    # erfc(√(x/2)) + e^{-x/2} Σ_{i=1}^{(k-1)/2} (x/2)^{i-1/2} / Γ(i + 1/2)
    total = math.erfc(math.sqrt(half))
    term = math.sqrt(half) * math.exp(-half) / math.gamma(1.5)
    for i in range(1, (k - 1) // 2 + 1):
        total += term
        term *= half / (i + 0.5)
    return total


@functools.lru_cache(maxsize=256)  # (the same few levels asked by every estimator made: a millisecond each start)
def chi2_isf(p: float, k: int) -> float:
    """The x with P(X > x) = ``p`` for X χ² with ``k`` degrees of freedom (0 < p < 1): bisection on the log of
    the survival function, which is monotone, to a relative 1e-12."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"a tail probability must be within (0, 1), got {p!r}")
    target = math.log(p)
    lo, hi = 0.0, max(2.0 * k, 1.0)
    while math.log(max(chi2_sf(hi, k), 1e-300)) > target:
        lo, hi = hi, 2.0 * hi
    while hi - lo > 1e-12 * hi:
        mid = 0.5 * (lo + hi)
        if math.log(max(chi2_sf(mid, k), 1e-300)) > target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
