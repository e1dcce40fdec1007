"""Truth in place of one part of a labeller's output (`eval --oracle`), to tell apart what limits a score.

`eval --poses truth` takes registration out of the picture; this takes out the class head ("classes": every
voxel the log has a true class for gets it) or the embedding ("objects": every voxel gets a fixed random unit
vector of its true object, so the clustering sees embeddings that tell objects apart perfectly). What is left
is the rest of the labeller and the clustering with its settings (which reads embeddings, and classes only
to know walls and floors). On validation missions this showed that the colour-free MCPNet's objects are
limited by its embeddings, not its classes or the clustering
(docs/benchmarks/objects.md#what-limits-objects-eval---oracle). Only logs with ground truth; the wrapped
labeller's own outputs are computed as usual (and cost as usual), then overwritten.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Final, Literal, get_args

import numpy as np

from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.label import Labeller, hand_structure
from aftershock.pipeline.types import Frame
from aftershock.pipeline.voxel_map import VoxelMap

if TYPE_CHECKING:
    from aftershock.pipeline.structure.model import StructureModel

Oracle = Literal["none", "classes", "objects"]
ORACLES: Final[tuple[str, ...]] = get_args(Oracle)
_SEED: Final = 0


class TruthStandIn:
    """A `Labeller` that runs `inner`, then puts the truth in place of its classes or embeddings."""

    def __init__(self, inner: Labeller, what: Oracle) -> None:
        if what not in ("classes", "objects"):
            raise ValueError(f"unknown oracle {what!r}")
        if what == "objects" and not inner.embedding_dim:
            raise ValueError(f"labeller {inner.name!r} has no embeddings to replace")
        self.inner = inner
        self.what = what
        self.name = f"{inner.name}+true-{what}"
        self.embedding_dim = inner.embedding_dim
        self._vectors = np.zeros((0, max(inner.embedding_dim, 1)), np.float32)

    def label(self, vmap: VoxelMap, new_rows: np.ndarray, frame: Frame) -> np.ndarray | None:
        rewritten = self.inner.label(vmap, new_rows, frame)
        given = frame.map_rows.given if frame.map_rows is not None else new_rows[:0]
        self._overwrite(vmap, np.r_[new_rows, given])  # the rows the structure model labelled too
        return None if self.what == "classes" else rewritten  # the true classes go over every voxel

    def vote_instances(self, vmap: VoxelMap, instances: np.ndarray) -> None:
        """The inner labeller's vote (the end of a run), and the truth put back over it."""
        self.inner.vote_instances(vmap, instances)
        self._overwrite(vmap, np.flatnonzero(np.isin(vmap.instance_ids, instances)))

    def affinity(self, vmap: VoxelMap, rows_a: np.ndarray, rows_b: np.ndarray) -> np.ndarray:
        return self.inner.affinity(vmap, rows_a, rows_b)

    def use_structure(self, model: StructureModel) -> None:
        """The inner labeller reads the structure model where its network does (pipeline.label.hand_structure)."""
        hand_structure(self.inner, model)

    def _overwrite(self, vmap: VoxelMap, rows: np.ndarray) -> None:
        if self.what == "classes":
            # the wrapped labeller may have re-voted older voxels too (instance votes): all of them get the truth
            truth = vmap.true_class_ids
            known = truth != UNLABELLED
            vmap.class_ids[known] = truth[known]
            return
        objects = vmap.true_instance_ids[rows].astype(np.int64)
        vmap.embeddings[rows] = self._vector(objects)

    def _vector(self, objects: np.ndarray) -> np.ndarray:
        """A fixed random unit vector per true object id (the same id, the same vector, whatever the order: a
        larger table drawn from the same seed begins with the same rows)."""
        need = int(objects.max(initial=-1)) + 1
        if need > len(self._vectors):
            size = max(need, 2 * len(self._vectors), 1024)
            v = np.random.default_rng(_SEED).normal(size=(size, self.embedding_dim)).astype(np.float32)
            self._vectors = v / np.linalg.norm(v, axis=1, keepdims=True)
        return self._vectors[objects]
