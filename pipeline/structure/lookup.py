"""Set operations of the structure model over the map's rows and element ids, as lookup tables (the rows and ids
are small dense integers: a table indexed by them does what `np.isin` and `np.unique` do by sorting)."""

from __future__ import annotations

from collections.abc import Collection

import numpy as np


def member(elem: np.ndarray, ids: np.ndarray | Collection[int], size: int) -> np.ndarray:
    """Whether each element id of `elem` (-1: none) is one of `ids` (all in [0, `size`))."""
    table = np.zeros(size + 1, bool)  # its last entry stands for -1
    table[np.fromiter(ids, np.int64, len(ids)) if not isinstance(ids, np.ndarray) else ids] = True
    return table[elem]


def sorted_union(n: int, *parts: np.ndarray) -> np.ndarray:
    """The distinct rows of `parts` (all in [0, `n`)) in ascending order, as `np.unique(np.concatenate(parts))`:
    by sorting where they are few against the map's rows, else by a mask over the map's rows."""
    if sum(len(p) for p in parts) * 16 < n:  # a scan's new rows in a large map
        return np.unique(np.concatenate(parts))
    mask = np.zeros(n, bool)
    for part in parts:  # one iteration per part (a handful)
        mask[part] = True
    return np.flatnonzero(mask)
