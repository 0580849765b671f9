"""Numpy on the per-step hot path: the numbers of the public functions, without their dispatch.

A control step runs about a hundred numpy operations on arrays of 3 to 13 numbers (the expert, its
IK, the observations), where the Python-level wrappers of ``np.clip`` and ``np.linalg.norm`` cost
more than the arithmetic. These call what those wrappers end in, so every result is bit for bit
theirs and collected stores do not change:

- :data:`clip` ``(x, lo, hi[, out=])``: the ufunc that ``np.clip`` and ``ndarray.clip`` call
  (NaN passed through; between equal values it picks as ``np.clip`` does, which
  ``np.minimum(np.maximum(...))`` does not for signed zeros);
- :func:`norm`: ``np.linalg.norm`` of a vector.
"""

from __future__ import annotations

import math

import numpy as np

try:  # numpy >= 2
    from numpy._core.umath import clip
except ImportError:  # numpy 1.26
    from numpy.core.umath import clip  # type: ignore[no-redef]

__all__ = ["clip", "norm"]


def norm(v: np.ndarray) -> float:
    """``float(np.linalg.norm(v))`` of a float64 vector, computed as numpy computes it: ``sqrt(v . v)``
    over the flattened vector."""
    v = v.ravel(order="K")
    return math.sqrt(float(v.dot(v)))
