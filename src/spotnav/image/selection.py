"""Compiled selection for the edge reader's kernels: the median and the k-th smallest of a few values in place,
without sorting or allocating, and every n-th of the rays marked.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _median(values: np.ndarray, scratch: np.ndarray) -> float:
    """The median of ``values`` (N >= 1, no NaN), as ``np.median``, selected in ``scratch`` (N or longer; may be
    ``values`` itself) without sorting or allocating."""
    n = len(values)
    for i in range(n):
        scratch[i] = values[i]
    upper = _select(scratch, n, n // 2)
    if n % 2:
        return upper
    lower: float = scratch[0]
    for i in range(1, n // 2):
        lower = max(lower, scratch[i])
    return 0.5 * (lower + upper)


# Up to this many values a selection partitions without branches on the values (Lomuto's scheme, each value moved
# by a conditional move): on a frame's medians of 38 and 64 values (the edge reader's, varied rays) 0.13 -> 0.07 ms,
# where Hoare's scheme mispredicts about one comparison in two. Past it, many equal values (steps between clipped
# samples, all zero) would make that scheme's passes quadratic.
_BRANCHLESS_SELECT_MAX = 64


@njit(cache=True)
def _select(values: np.ndarray, n: int, k: int) -> float:
    """The ``k``-th smallest of ``values[:n]``, in place: then ``values[:k]`` are no larger (Lomuto's selection
    without branches up to ``_BRANCHLESS_SELECT_MAX`` values, else Hoare's)."""
    low, high = 0, n - 1
    if n <= _BRANCHLESS_SELECT_MAX:
        while low < high:
            middle = (low + high) // 2
            pivot: float = values[middle]
            values[middle], values[high] = values[high], pivot
            store = low
            for i in range(low, high):
                value, stored = values[i], values[store]
                smaller = value < pivot
                values[store] = value if smaller else stored
                values[i] = stored if smaller else value
                store += smaller
            values[high], values[store] = values[store], pivot
            if k == store:
                return pivot
            if k < store:
                high = store - 1
            else:
                low = store + 1
        kth: float = values[k]
        return kth
    while low < high:
        pivot = values[(low + high) // 2]
        i, j = low, high
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            high = j
        elif k >= i:
            low = i
        else:
            break
    kth = values[k]
    return kth


@njit(cache=True)
def _every_nth(selected: np.ndarray, n: int) -> np.ndarray:
    """Indices of every ``n``-th entry of ``selected`` (R,) that is True."""
    chosen = np.empty(len(selected), dtype=np.int64)
    count = 0
    for r in range(0, len(selected), n):
        if selected[r]:
            chosen[count] = r
            count += 1
    return chosen[:count]
