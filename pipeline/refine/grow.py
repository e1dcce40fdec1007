"""Region growing driven by LRGNet: greedy, random restarts or beam search from each seed.

Each step pools a sample of the region (I inliers, J neighbours, with replacement when fewer) into the global
feature, then decides for *every* inlier and neighbour (in chunks) whether to remove or add it. A region stops
when nothing is added, no neighbours remain, it did not expand for two steps, or after `max_steps`.
Seeds are the unlabelled voxels of least curvature (reliable ones first, see `seed_order`). All randomness
comes from one seeded generator.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from enum import StrEnum
from typing import Final

import numpy as np
import torch

from aftershock.models.lrgnet import LRGNet
from aftershock.pipeline.config import LRGNetConfig
from aftershock.pipeline.refine.features import NORMAL, VoxelCloud, reads_plane, region_centre, step_features
from aftershock.pipeline.refine.merge import MAX_FLATNESS

CHUNK: Final = 8192  # candidates per head evaluation
NOT_EXPANDING_STOP: Final = 2
_EPS: Final = 1e-7
# The flat-region gate (`lrgnet.flat_gate_deg`) judges a region of at least this many voxels (fewer say little about
# its shape) by the crease split's test: smallest eigenvalue / sum under MAX_FLATNESS is a plane
FLAT_GATE_MIN_VOXELS: Final = 10


def seed_order(vc: VoxelCloud, min_neighbours: int) -> np.ndarray:
    """Voxels in the order they are tried as seeds: least curvature first, the voxels whose curvature is reliable
    (at least `min_neighbours` occupied neighbouring voxels) before the others (edges, slivers, strays)."""
    occupied = (vc.adjacency >= 0).sum(axis=1)
    return np.lexsort((vc.curvature, occupied < min_neighbours))


class Search(StrEnum):
    GREEDY = "greedy"
    RESTART = "restart"
    BEAM = "beam"


class Score(StrEnum):
    ML = "ml"  # summed log-likelihood of the decisions taken
    NP = "np"  # number of points in the final region


@dataclass(slots=True)
class Growth:
    """One region's growth: its final voxels, how it was scored and how many network steps it took."""

    region: np.ndarray
    loglik: float = 0.0
    steps: int = 0
    done: bool = False
    not_expanding: int = 0
    history: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class ModeSettings:
    """LRGNet's settings that depend on whether the cloud has colour (LRGNET_MODE_DEFAULTS), each resolved."""

    add_threshold: float
    merge_angle_deg: float
    merge_offset_m: float
    crease_angle_deg: float
    crease_min_voxels: int
    flat_gate_deg: float

    @classmethod
    def of(cls, cfg: LRGNetConfig, color: bool) -> ModeSettings:
        resolved = cfg.for_color(color)
        return cls(**{f.name: getattr(resolved, f.name) for f in fields(cls)})


@dataclass(slots=True)
class Segmentation:
    labels: np.ndarray  # (M,) int64 segment per voxel, 1.. in growth order
    steps_per_object: list[int]  # network steps spent on each grown region (all restarts/beams included)
    history: list[tuple[np.ndarray, np.ndarray]] | None  # voxel (inliers, neighbours) per step of one object


class Grower:
    """Grows regions over one voxelised cloud with one network."""

    def __init__(self, vc: VoxelCloud, net: LRGNet, cfg: LRGNetConfig) -> None:
        self.vc = vc
        self.net = net
        self.plane = reads_plane(net.in_features)  # weights of layout 3 read the per-step plane features too
        self.cfg = cfg.for_color(vc.color)
        self.mode = ModeSettings.of(cfg, vc.color)  # the add threshold and the gate depend on the cloud's colour
        self.rng = np.random.default_rng(cfg.seed)
        self.labelled = np.zeros(len(vc), bool)
        self._touched = np.zeros(len(vc), bool)
        self.network_steps = 0

    # --- one step -----------------------------------------------------------------------------------------
    def neighbours(self, region: np.ndarray) -> np.ndarray:
        """Unlabelled voxels touching the region and not in it."""
        nb = self.vc.adjacency[region].ravel()
        nb = nb[nb >= 0]
        self._touched[nb] = True  # a scratch mask instead of np.unique: no sort of |region| x 26 entries
        self._touched[region] = False
        out = np.flatnonzero(self._touched)
        self._touched[out] = False
        return out[~self.labelled[out]]

    def _sample(self, idx: np.ndarray, size: int) -> np.ndarray:
        # "With replacement when fewer" only repeats points, which cannot change a max-pool: pass them once.
        return idx if len(idx) <= size else self.rng.choice(idx, size, replace=False)

    @torch.no_grad()
    def probabilities(self, region: np.ndarray, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """P(remove) for every inlier and P(add) for every candidate."""
        self.network_steps += 1
        f = self.vc.features
        centre = region_centre(f, region)
        si = torch.from_numpy(step_features(f, self._sample(region, self.cfg.inliers), centre, self.plane))
        sn = torch.from_numpy(step_features(f, self._sample(candidates, self.cfg.neighbours), centre, self.plane))
        g = self.net.encode(si[None], sn[None])[0]
        return self._heads(g, region, centre, remove=True), self._heads(g, candidates, centre, remove=False)

    def _heads(self, g: torch.Tensor, idx: np.ndarray, centre: np.ndarray, remove: bool) -> np.ndarray:
        out = np.empty(len(idx), np.float32)
        fn = self.net.remove_logits if remove else self.net.add_logits
        for s in range(0, len(idx), CHUNK):
            x = torch.from_numpy(step_features(self.vc.features, idx[s : s + CHUNK], centre, self.plane))
            out[s : s + CHUNK] = torch.softmax(fn(g, x), dim=-1)[:, 1].numpy()
        return out

    def advance(self, state: Growth, sample: bool, record: bool) -> Growth:
        """One step of growth, decisions thresholded (greedy, 0.5 by default) or drawn from the probabilities."""
        region = state.region
        candidates = self.neighbours(region)
        if len(candidates) == 0:
            return Growth(region, state.loglik, state.steps, True, state.not_expanding, state.history)
        p_rm, p_add = self.probabilities(region, candidates)
        if sample:
            rm = self.rng.random(len(p_rm)) < p_rm
            add = self.rng.random(len(p_add)) < p_add
        else:
            rm, add = p_rm > self.cfg.remove_threshold, p_add > self.mode.add_threshold
        if self.mode.flat_gate_deg:
            add &= self.within_plane(region, candidates)
        loglik = state.loglik + float(
            np.log(np.where(rm, p_rm, 1 - p_rm) + _EPS).sum() + np.log(np.where(add, p_add, 1 - p_add) + _EPS).sum()
        )
        history = [*state.history, (region, candidates)] if record else state.history
        kept = region[~rm]
        if len(kept) == 0:  # the network removed everything: the seed alone stays
            kept = region[:1]
        new_region = np.concatenate([kept, candidates[add]])
        not_expanding = state.not_expanding + 1 if len(new_region) <= len(region) else 0
        done = not add.any() or not_expanding >= NOT_EXPANDING_STOP or state.steps + 1 >= self.cfg.max_steps
        return Growth(new_region, loglik, state.steps + 1, done, not_expanding, history)

    def within_plane(self, region: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        """Which candidates a region may take by the flat-region gate: while the region is a plane, only voxels
        whose normals lie within `flat_gate_deg` of its normal (a wall stops at the crease to the ceiling, where
        without colour the network alone does not); everything while it is small or not flat (a chair)."""
        ok = np.ones(len(candidates), bool)
        if len(region) < FLAT_GATE_MIN_VOXELS:
            return ok
        pts = self.vc.points[region]
        values, vectors = np.linalg.eigh(np.cov(pts - pts.mean(axis=0), rowvar=False))
        if values[0] >= MAX_FLATNESS * max(float(values.sum()), 1e-12):
            return ok
        cos = np.abs(self.vc.features[candidates, NORMAL] @ vectors[:, 0].astype(np.float32))
        return cos >= np.cos(np.radians(self.mode.flat_gate_deg))

    # --- one region -------------------------------------------------------------------------------------
    def score(self, g: Growth) -> float:
        return float(len(g.region)) if self.cfg.score == Score.NP else g.loglik

    def grow(self, seed: int, record: bool = False) -> Growth:
        start = Growth(np.array([seed], np.int64))
        search = Search(self.cfg.search)
        if search == Search.GREEDY:
            return self._run(start, sample=False, record=record)
        if search == Search.RESTART:
            runs = [self._run(start, sample=i > 0, record=record) for i in range(max(1, self.cfg.restarts))]
            return max(runs, key=self.score)
        return self._beam(start, record)

    def _run(self, state: Growth, sample: bool, record: bool) -> Growth:
        while not state.done:
            state = self.advance(state, sample, record)
        return state

    def _beam(self, start: Growth, record: bool) -> Growth:
        """Beam search: every open state expands greedily once and by sampling `beam_expansions - 1` times;
        the best `beam_width` states (finished or not) by score survive."""
        beam = [start]
        while not all(s.done for s in beam):
            children = [s for s in beam if s.done]
            for s in beam:
                if not s.done:
                    children += [self.advance(s, sample=e > 0, record=record) for e in range(self.cfg.beam_expansions)]
            beam = sorted(children, key=self.score, reverse=True)[: self.cfg.beam_width]
        return beam[0]

    # --- the whole cloud --------------------------------------------------------------------------------
    def segment(self, record_object: int | None = None) -> Segmentation:
        """Grow regions from seeds in increasing curvature (`seed_order`) until every voxel is labelled."""
        m = len(self.vc)
        labels = np.zeros(m, np.int64)
        order = seed_order(self.vc, self.cfg.seed_min_neighbours)
        steps_per_object: list[int] = []
        history = None
        pos = 0
        while pos < m:
            while pos < m and self.labelled[order[pos]]:
                pos += 1
            if pos >= m:
                break
            before = self.network_steps
            object_id = len(steps_per_object) + 1
            record = record_object == object_id
            g = self.grow(int(order[pos]), record=record)
            region = np.unique(g.region)
            region = region[~self.labelled[region]]
            labels[region] = object_id
            self.labelled[region] = True
            steps_per_object.append(self.network_steps - before)
            if record:
                history = g.history
        return Segmentation(labels, steps_per_object, history)
