"""The pair table of the clustering: every pair of touching instances, with how many neighbouring voxel pairs
join them (contacts) and how many of those the labeller linked (links).

A pair is one int64 key, the smaller id in the high 32 bits; keys are kept sorted and unique, so a merge
(ids renamed through a look-up table) folds the pairs of the merged instances together.
"""

from __future__ import annotations

from typing import Final

import numpy as np

PAIR_SHIFT: Final = np.int64(32)


def pack_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """One key per unordered pair (lo << 32 | hi)."""
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    return (lo << PAIR_SHIFT) | hi


def pack_ordered(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """One key per ordered pair (a << 32 | b): sorts by a, then b."""
    return (np.asarray(a, np.int64) << PAIR_SHIFT) | np.asarray(b, np.int64)


def unpack_pairs(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return keys >> PAIR_SHIFT, keys & ((np.int64(1) << PAIR_SHIFT) - 1)


class PairTable:
    """Touching instance pairs, sorted by key, with their contact and link counts."""

    def __init__(self) -> None:
        self.keys = np.zeros(0, np.int64)  # touching instance pairs (lo << 32 | hi), sorted
        self.contacts = np.zeros(0, np.int64)  # neighbouring voxel pairs between them
        self.links = np.zeros(0, np.int64)  # ... of which the labeller linked

    def __len__(self) -> int:
        return len(self.keys)

    def pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) instance ids of every pair, in key order."""
        return unpack_pairs(self.keys)

    def add(self, ia: np.ndarray, ib: np.ndarray, linked: np.ndarray) -> None:
        """Count one contact per voxel pair between instances ia and ib (ids > 0, different), and its link."""
        keys = pack_pairs(ia, ib)
        self._store(
            np.r_[self.keys, keys],
            np.r_[self.contacts, np.ones(len(keys), np.int64)],
            np.r_[self.links, linked.astype(np.int64)],
        )

    def rename(self, lut: np.ndarray) -> None:
        """Ids renamed through `lut` (old id -> new id): pairs that now coincide add up, pairs within one go."""
        if not len(self.keys):
            return
        lo, hi = unpack_pairs(self.keys)
        self._store(pack_pairs(lut[lo], lut[hi]), self.contacts, self.links)

    def _store(self, keys: np.ndarray, contacts: np.ndarray, links: np.ndarray) -> None:
        lo, hi = unpack_pairs(keys)
        keep = lo != hi
        uniq, inv = np.unique(keys[keep], return_inverse=True)
        self.keys = uniq
        self.contacts = np.bincount(inv.ravel(), weights=contacts[keep], minlength=len(uniq)).astype(np.int64)
        self.links = np.bincount(inv.ravel(), weights=links[keep], minlength=len(uniq)).astype(np.int64)
