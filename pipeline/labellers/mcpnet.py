"""MCPNet as the online labeller: every voxel a scan opens gets a class, a score and a unit embedding, from
its own features and 50 context points drawn from the voxel map (earlier scans included).

All new voxels of a scan go through the network in one batch (chunked only to bound memory). Without
colour in the log, the colour-free mode of the same weights is used (colour features zero, colour flag off).
The clustering stage links neighbouring voxels whose embeddings agree: cosine similarity above β.

    labeller = create(cfg)                    # the shipped weights, models/weights/mcpnet.pt
    labeller.label(vmap, new_rows, frame)     # writes class_ids, scores, embeddings of new_rows
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np
import torch

from aftershock.models.mcpnet import (
    context_draws,
    context_features,
    default_weights,
    floor_height,
    load_mcpnet,
    point_features,
    point_inputs_of_rows,
)
from aftershock.models.netconfig import NetConfig
from aftershock.pipeline.config import Config, Environment
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.structure.features import NOTHING_KNOWN, structure_features
from aftershock.pipeline.types import Frame, LabelledCloud
from aftershock.pipeline.voxel_map import VoxelMap

if TYPE_CHECKING:
    from aftershock.pipeline.structure.model import StructureModel

NAME: Final = "mcpnet"
NO_CONTEXT: Final = "mcpnet-nocontext"
NO_COLOR: Final = "mcpnet-nocolor"  # the colour-free network's weights: models/weights/mcpnet_nocolor.pt
CHUNK: Final = 4096  # voxels per forward pass; bounds memory at about 4096 x 50 x 200 floats
RELABEL_PER_NEW: Final = 4  # with relabelling on: at most this many older voxels re-classed per new voxel
EMBED_REACH_M: Final = 1.5  # embed_cloud: each point is seen from at most this far away, as in a scan
NOT_VOTED: Final = np.iinfo(np.uint16).max


def distinct_pairs(ctx_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(point index, neighbour row) of every distinct neighbour a point drew (draws are with replacement:
    about a third repeat on a VLP-16 mission), absent neighbours (-1) left out."""
    s = np.sort(ctx_rows, axis=1)
    keep = s >= 0
    keep[:, 1:] &= s[:, 1:] != s[:, :-1]
    owner, _ = np.nonzero(keep)
    return owner.astype(np.int64), s[keep].astype(np.int64)


def top_class(probs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Class ids (K,) uint16 and scores (K,) float32 (the probability of that class) of probabilities (K, C)."""
    return probs.argmax(axis=1).astype(np.uint16), probs.max(axis=1, initial=0.0)


class MCPNetLabeller:
    """The `Labeller` of `pipeline.label` backed by an MCPNet (or, with other weights, its no-context variant)."""

    name: str = NAME

    def __init__(
        self,
        cfg: Config,
        link_beta: float,
        weights: str | Path | None = None,
        kind: str = "mcpnet",
        weights_no_color: str | Path | None = None,
    ) -> None:
        self.name = kind
        path = Path(weights or default_weights(kind))
        self.model, self.net, self.figures = load_mcpnet(path, kind=kind)
        # Logs without colour get a network of their own (#12): trained on randomised buildings, colour dropped
        # per mission. A weights file named alone serves both.
        mono = weights_no_color or (default_weights(NO_COLOR) if kind == NAME and weights is None else None)
        self.mono_weights = Path(mono) if mono else path
        self.mono_model, self.mono_net = (self.model, self.net)
        if mono:
            self.mono_model, self.mono_net, _ = load_mcpnet(mono, kind=kind)
            if self.mono_net.embed_dim != self.net.embed_dim:
                raise InputError(
                    f"embeds in {self.mono_net.embed_dim} dimensions, {path.name} in {self.net.embed_dim}", mono
                )
        # Batches of a few dozen voxels: a second intra-op thread only waits (10-20x slower on a busy machine).
        torch.set_num_threads(1)
        self.weights = path
        self.embedding_dim = self.net.embed_dim
        self.cell_m = cfg.map.context_cell_m
        self.num = cfg.map.context_points
        self.beta = link_beta  # embeddings this similar link two voxels (the cluster section's β for the site)
        self.relabel = cfg.label.relabel_old_voxels
        self.vote = cfg.label.instance_vote
        self.raw_class = np.zeros(0, np.int64)  # the network's own class per map row, before instance votes
        self.raw_score = np.zeros(0, np.float32)
        # its class probabilities per map row (float16 keeps 28 bytes a voxel): a voxel whose class an instance
        # vote changed gets the probability the network gave that class as its confidence
        self.raw_prob = np.zeros((0, self.net.num_classes), np.float16)
        # the class the last instance vote wrote per map row (NOT_VOTED: none since the row's own prediction): a
        # vote rewrites only the rows whose voted class changed, and reports them (`label`'s return)
        self.voted = np.zeros(0, np.uint16)
        self.rng = np.random.default_rng(0)  # which older voxels are relabelled
        # The stream's structure model (`use_structure`), for weights that read its evidence: as it stood after
        # the previous scan (its stage runs after this one), as in training. None: nothing known of the building.
        self.structure: StructureModel | None = None

    @property
    def reads_structure(self) -> bool:
        """Whether either network reads the structure model's evidence (models.netconfig STRUCTURE_FEATURES)."""
        return self.net.structure or self.mono_net.structure

    def use_structure(self, model: StructureModel) -> None:
        """Read the structure model's evidence from `model` (the stream's, updated after each scan)."""
        self.structure = model

    def structure_evidence(self, positions: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """(K, 4) float32 structure features of map positions seen from `origin` ((3,) or (K, 3))."""
        if self.structure is None:
            return np.tile(np.asarray(NOTHING_KNOWN, np.float32), (len(positions), 1))
        return structure_features(self.structure, positions, float(np.median(origin[..., 2])))

    @property
    def config(self) -> NetConfig:
        return self.net

    def predict_probs(
        self,
        vmap: VoxelMap,
        rows: np.ndarray,
        origin: np.ndarray,
        floor_z: float,
        use_color: bool,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Softmax class probabilities (K, C) float32 and embeddings (K, E) float32 of map rows, seen from the
        robot at `origin` ((3,), or (K, 3) one per row); `top_class` gives their classes and scores."""
        model, net = (self.model, self.net) if use_color else (self.mono_model, self.mono_net)
        rows = np.asarray(rows, dtype=np.int64)
        k = len(rows)
        probs = np.zeros((k, net.num_classes), np.float32)
        emb = np.zeros((k, self.embedding_dim), np.float32)
        colors = vmap.colors if use_color else None
        use_ctx = net.kind == "mcpnet"
        for s in range(0, k, CHUNK):
            r = rows[s : s + CHUNK]
            o = origin[s : s + CHUNK] if origin.ndim == 2 else origin
            pf = point_features(vmap.positions[r], None if colors is None else colors[r], o, floor_z)
            evidence = self.structure_evidence(vmap.positions[r], o) if net.structure else None
            with torch.inference_mode():
                pooled = None
                if use_ctx:
                    draws = context_draws(vmap.keys[r], self.num)
                    ctx_rows = vmap.context_rows(vmap.positions[r], self.cell_m, self.num, uniform=draws)
                    wide_rows = self.wide_context_rows(vmap, r, net)
                    # the weights' layout says which features they read (position, colour, local shape)
                    pf = point_inputs_of_rows(net, pf, vmap.positions, r, ctx_rows, wide_rows, evidence)
                    owner, neighbour = distinct_pairs(ctx_rows)
                    c, _ = context_features(vmap.positions, colors, r[owner], neighbour[:, None])
                    pooled = model.pool_pairs(torch.from_numpy(c[:, 0]), torch.from_numpy(owner), len(r))
                    if wide_rows is not None:
                        owner, neighbour = distinct_pairs(wide_rows)
                        w = (vmap.positions[neighbour] - vmap.positions[r[owner]]).astype(np.float32)
                        wide = model.pool_pairs(torch.from_numpy(w), torch.from_numpy(owner), len(r), wide=True)
                        pooled = torch.cat([pooled, wide], dim=1)
                e, logits = model.head(torch.from_numpy(pf), pooled)
                probs[s : s + CHUNK] = torch.softmax(logits, dim=1).numpy()
            emb[s : s + CHUNK] = e.numpy()
        return probs, emb

    def wide_context_rows(self, vmap: VoxelMap, rows: np.ndarray, net: NetConfig) -> np.ndarray | None:
        """The wider context's rows (K, Mw) of map rows (K,), drawn as `net` was trained (None without)."""
        if not net.coarse_points:
            return None
        draws = context_draws(vmap.keys[rows], net.coarse_points)
        return vmap.context_rows(vmap.positions[rows], net.coarse_cell_m, net.coarse_points, uniform=draws)

    def label(self, vmap: VoxelMap, new_rows: np.ndarray, frame: Frame) -> np.ndarray:
        """Label the voxels this scan opened. Earlier voxels are updated as more of the scene arrives: with
        `label.instance_vote` the instances this scan saw again take the class their voxels vote for; with
        `label.relabel_old_voxels` older voxels seen again are re-predicted with the context they now have.
        Returns the rows whose class or score it rewrote besides the new ones."""
        origin = frame.pose[:3, 3] if frame.pose is not None else np.zeros(3)
        world = frame.world_points if frame.world_points is not None else np.zeros((0, 3))
        floor_z = floor_height(world)
        use_color = frame.scan.colors is not None
        rows = np.asarray(new_rows, dtype=np.int64)
        if self.relabel and frame.map_rows is not None and len(vmap):
            seen = np.unique(frame.map_rows.rows)
            old = seen[vmap.first_seq[seen] < frame.seq]
            budget = RELABEL_PER_NEW * len(rows)  # bounded: relabelling must not dominate the scan time
            rows_old = self.rng.choice(old, budget, replace=False) if len(old) > budget else old
        else:
            rows_old = np.zeros(0, np.int64)
        probs, emb = self.predict_probs(vmap, np.r_[rows, rows_old], origin, floor_z, use_color)
        classes, scores = top_class(probs)
        n = len(rows)
        self._grow(len(vmap))
        self.raw_class[rows], self.raw_score[rows], self.raw_prob[rows] = classes[:n], scores[:n], probs[:n]
        given = frame.map_rows.given if frame.map_rows is not None else rows[:0]
        given = given[vmap.class_ids[given] < self.net.num_classes] if len(given) else given
        if len(given):  # labelled by the structure model (its element's class and confidence): they vote as such
            self.raw_class[given], self.raw_score[given] = vmap.class_ids[given], vmap.scores[given]
            self.raw_prob[given] = 0.0
            self.raw_prob[given, self.raw_class[given]] = vmap.scores[given]
        self.voted[rows] = NOT_VOTED
        self.voted[given] = NOT_VOTED
        vmap.class_ids[rows] = classes[:n]
        vmap.scores[rows] = scores[:n]
        vmap.embeddings[rows] = emb[:n]
        if len(rows_old):
            # An older voxel takes the new class only when the network is now surer of it.
            better = scores[n:] > self.raw_score[rows_old]
            up = rows_old[better]
            self.raw_class[up], self.raw_score[up], self.raw_prob[up] = (
                classes[n:][better],
                scores[n:][better],
                probs[n:][better],
            )
            vmap.class_ids[up] = classes[n:][better]
            vmap.scores[up] = scores[n:][better]
            self.voted[up] = NOT_VOTED
        else:
            up = rows_old
        if self.vote and frame.map_rows is not None:
            return np.r_[up, self._vote(vmap, vmap.instance_ids[frame.map_rows.rows])]
        return up

    def vote_instances(self, vmap: VoxelMap, instances: np.ndarray) -> None:
        """Every voxel of these instances takes the class its instance's voxels vote for, each vote weighted
        by the network's confidence (the network's own per-voxel predictions are kept for later votes); its
        confidence becomes the probability the network gave it for that class."""
        self._vote(vmap, instances)

    def _grow(self, n: int) -> None:
        if n > len(self.raw_class):
            size = max(n, 2 * len(self.raw_class), 4096)
            self.raw_class = np.resize(self.raw_class, size)
            self.raw_score = np.resize(self.raw_score, size)
            prob = np.zeros((size, self.raw_prob.shape[1]), np.float16)
            prob[: len(self.raw_prob)] = self.raw_prob
            self.raw_prob = prob
            voted = np.full(size, NOT_VOTED, np.uint16)
            voted[: len(self.voted)] = self.voted
            self.voted = voted

    def _vote(self, vmap: VoxelMap, instances: np.ndarray) -> np.ndarray:
        """`vote_instances`; returns the rows it rewrote (those whose voted class changed since their last vote:
        the others hold it already, or what the structure model wrote over it)."""
        touched = np.unique(instances)
        touched = touched[touched > 0]
        if not len(touched):
            return np.zeros(0, np.int64)
        ids = vmap.instance_ids
        members = np.flatnonzero(np.isin(ids, touched))
        which = np.searchsorted(touched, ids[members])
        c = self.net.num_classes
        votes = np.bincount(
            which * c + self.raw_class[members], weights=self.raw_score[members], minlength=len(touched) * c
        )
        voted = votes.reshape(len(touched), c).argmax(axis=1)[which].astype(np.uint16)
        self._grow(len(vmap))
        change = self.voted[members] != voted
        members, voted = members[change], voted[change]
        vmap.class_ids[members] = voted
        vmap.scores[members] = self.raw_prob[members, voted]
        self.voted[members] = voted
        return members

    def affinity(self, vmap: VoxelMap, rows_a: np.ndarray, rows_b: np.ndarray) -> np.ndarray:
        """Link two voxels when their embeddings' cosine similarity exceeds β."""
        ea, eb = vmap.embeddings[rows_a], vmap.embeddings[rows_b]
        return np.einsum("ij,ij->i", ea, eb) > self.beta

    def embed_cloud(self, cloud: LabelledCloud) -> np.ndarray:
        """Unit embeddings (N, E) of every point of a static cloud, its context drawn from the cloud itself.

        The cloud goes into a voxel map of its own (a point takes the embedding of its voxel); each point is
        described as if the robot stood towards the cloud's centre, at most 1.5 m away as in a scan, on the
        cloud's floor (its lowest heights)."""
        pts = np.asarray(cloud.points, dtype=np.float64)
        if not len(pts):
            return np.zeros((0, self.embedding_dim), np.float32)
        vmap = VoxelMap(self.net.voxel_m)
        _, point_rows = vmap.insert(pts, cloud.colors)
        stored = vmap.positions[point_rows]
        offset = stored - np.r_[np.median(pts[:, :2], axis=0), 0.0]
        offset[:, 2] = 0.0
        dist = np.linalg.norm(offset, axis=1, keepdims=True)
        origin = stored - offset * np.minimum(1.0, EMBED_REACH_M / np.maximum(dist, 1e-9))
        _, emb = self.predict_probs(vmap, point_rows, origin, floor_height(pts), cloud.colors is not None)
        return emb


def create(cfg: Config, name: str = NAME, environment: Environment = Environment.INDOOR) -> MCPNetLabeller:
    """MCPNet, or the same network without context pooling for the name "mcpnet-nocontext"."""
    beta = cfg.cluster.link_beta(environment)
    if name == NO_CONTEXT:
        return MCPNetLabeller(cfg, beta, kind=NO_CONTEXT)
    return MCPNetLabeller(cfg, beta, weights=cfg.label.weights, weights_no_color=cfg.label.weights_no_color)
