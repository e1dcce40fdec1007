"""`aftershock train mcpnet`: MCPNet and its baselines from simulated missions, seeded, on a CPU.

Missions are staged the way inference sees them: each scan is placed in the world (with the simulator's true
pose: registration noise is left out of training), cut to the labelling range, inserted in a voxel map, and
every voxel it opens becomes a training point whose context (and wider context) is drawn from the map built so
far. MCPNet learns from randomised missions of the training generators (#12); the network without context and
the PointNet baseline (single scans, the scans of the last 0.1 s, the scans within 0.5 m) from plain missions of
both families, as before #12. Held-out seeds and the held-out generator are never trained on.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import torch
from torch import nn

from aftershock.models import transfer_split as split
from aftershock.models.mcpnet import (
    MCPNet,
    context_draws,
    floor_height,
    num_parameters,
    point_features,
    point_inputs,
    row_offsets,
    save_weights,
)
from aftershock.models.netconfig import (
    CONTEXT_DIM,
    POINT_DIM,
    STRUCTURE_TRANSFER_FEATURES,
    TRANSFER_FEATURES,
    NetConfig,
)
from aftershock.models.optimise import descend
from aftershock.models.pointnet import PointNet
from aftershock.models.weights_file import WEIGHTS_DIR
from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.config import Environment, StructureConfig
from aftershock.pipeline.errors import OutputError
from aftershock.pipeline.structure.features import FEATURES as STRUCTURE_FEATURES
from aftershock.pipeline.structure.features import structure_features
from aftershock.pipeline.structure.model import StructureModel
from aftershock.pipeline.voxel_map import VoxelMap
from aftershock.sources.simulator import Mission as SimMission
from aftershock.sources.simulator import build_scene, get_profile

FAMILIES: Final[tuple[str, ...]] = ("office", "disaster")
SENSOR: Final = "vlp16"
# The split, defined once: training seeds and held-out evaluation seeds never overlap.
TRAIN_SEEDS: Final[tuple[int, ...]] = tuple(range(100, 110))
HELDOUT_SEEDS: Final[tuple[int, ...]] = (900, 901)
TRAIN_SCANS: Final = 150  # scans per training mission
HELDOUT_SCANS: Final = 150

EPOCHS: Final = 3  # the no-context MCPNet (MCPNet: MCPNET_EPOCHS): an epoch shows every training point once
POINTNET_EPOCHS: Final = 14  # PointNet: an epoch shows a quarter of the training scans
BATCH_INSTANCES: Final = 16
POINTS_PER_INSTANCE: Final = 16
MARGIN: Final = 1.0
UNIFORM_POINTS: Final = 128  # per batch, drawn over all points for the class loss only
LEARNING_RATE: Final = 1e-3
# The families' MCPNet (logs with colour): share of crop batches and affinity weight, as TRANSFER_* below, and
# its epochs (the no-context baseline keeps EPOCHS). Chosen on the 54 validation missions with colour; at 3 epochs
# mean IoU fell (docs/decisions.md#the-colour-mcpnet-with-crops-and-the-affinity-loss).
CROP_BATCHES: Final = 0.5
AFFINITY_WEIGHT: Final = 1.0
MCPNET_EPOCHS: Final = 6
COLOR_DROP: Final = 0.3  # the baselines: share of training points (PointNet: clouds) shown without colour
# MCPNet since #12: trained to transfer. Randomised missions of the training generators (palettes, robots,
# mounts, sensors, conditions), from scratch, colour dropped for half of the missions (a robot without a camera
# has no colour for a whole log), so that the colour-free mode is learnt as much as the colour one. The
# held-out generator is never staged.
TRANSFER_SCANS: Final = 100
TRANSFER_COLOR_DROP: Final = 0.5
# 6, not 3: after 3 epochs the training accuracy was still rising (0.54 / 0.63 / 0.67); the LR decays on one
# cosine over the whole run (1e-3 to 5e-5, as every MCPNet here), so a longer run also stays longer at a high LR.
TRANSFER_EPOCHS: Final = 6
CLASS_WEIGHT_POWER: Final = 0.0
# Share of the colour-free network's triplet batches drawn as neighbouring instances of one mission
# (`Pool.local_instance_batch`) rather than over all missions; shipped for a while at 0.5, replaced by the
# crop batches below (docs/decisions.md#neighbour-batches-for-the-colour-free-mcpnet).
TRANSFER_LOCAL_BATCHES: Final = 0.0
# Share of batches drawn as a spatial crop (`Pool.crop_batch`), and the weight of the affinity loss on the crop's
# neighbouring points (`affinity_loss`); 0 = neither. Chosen on 54 validation missions: crops and the affinity loss
# beat the neighbour batches, then more crops and a heavier loss won round D
# (docs/decisions.md#round-d-more-crops-and-a-heavier-affinity-loss).
TRANSFER_CROP_BATCHES: Final = 0.75
TRANSFER_AFFINITY_WEIGHT: Final = 3.0
# Weight of a crop batch's own 256 points in its class loss beside its uniformly drawn ones (1: alike, as shipped;
# 0: the uniform points only). A crop is mostly the floor and walls around one object, so it skews the classes.
TRANSFER_CROP_CLASS_WEIGHT: Final = 1.0
CROP_POINTS: Final = 256  # a crop: this many training points of one mission nearest a point of a random instance
# The affinity loss acts where the clusterer decides: pairs of points in neighbouring 0.1 m voxels (the 26 around
# one lie within sqrt(3) x 0.1 m). One instance's neighbours are pulled above LINK_POSITIVE cosine similarity (the
# clusterer links voxels at 0.9), two instances' neighbours pushed below LINK_NEGATIVE (instances merge at 0.85
# mean similarity, fragments are absorbed at 0.7).
AFFINITY_RADIUS_M: Final = 0.18
LINK_POSITIVE: Final = 0.95
LINK_NEGATIVE: Final = 0.65
_MISSION_SPACING_M: Final = 1e5  # missions set apart this far in the crop index, so a crop never spans two
COARSE_POINTS: Final = 32  # draws of the wider context (3 x 3 x 3 cells of 0.5 m)
TRANSFER_SENSORS: Final[tuple[str, ...]] = ("vlp16", "vlp16", "vlp32c", "os1-32")
TRANSFER_ROBOTS: Final[tuple[str, ...]] = ("legged", "wheeled", "tracked")
POINTNET_MAX_POINTS: Final = 1024
POINTNET_CLOUDS_PER_STEP: Final = 8
POINTNET_SCAN_SHARE: Final = 0.25  # scans (clouds) drawn per PointNet epoch, as a share of all training scans
TEMPORAL_WINDOW_S: Final = 0.1
SPATIAL_WINDOW_M: Final = 0.5


@dataclass(slots=True)
class Mission:
    """One staged mission: the map's stored points with their truth, and the points to predict."""

    positions: np.ndarray  # (R, 3) float64
    colors: np.ndarray  # (R, 3) uint8
    classes: np.ndarray  # (R,) int64 true class (UNLABELLED where unknown)
    instances: np.ndarray  # (R,) int64 true instance (0 = none)
    rows: np.ndarray  # (S,) int64 map row of every training point (a new voxel)
    context: np.ndarray  # (S, M) int64 context rows, -1 where none
    wide: np.ndarray  # (S, Mw) int64 rows of the wider context, -1 where none (Mw = 0 without one)
    sample_scan: np.ndarray  # (S,) int64 scan index of every training point
    origins: np.ndarray  # (T, 3) sensor position per scan
    floors: np.ndarray  # (T,) floor height per scan
    stamps: np.ndarray  # (T,) scan time, seconds
    scan_rows: list[np.ndarray]  # rows hit by each scan (inside the range)
    new_rows: list[np.ndarray]  # rows each scan opened
    structure: np.ndarray  # (S, 4) float32 the structure model's evidence of every training point when it opened


def stage_mission(mission: SimMission, cfg: NetConfig, structure: bool | None = None) -> Mission:
    """Replay a simulated mission with its true motion through a voxel map; see the module docstring.

    Every point is placed with the true pose at its own firing time (an exact deskew), where inference
    has KISS-ICP's estimate instead. With `structure` (default: where `cfg` reads them) a structure model grows
    beside the map, as the stream's `structure` stage does, and every training point gets its features from the
    model as it stood when the point's voxel opened: as of the previous scan, which is what the labeller sees
    (the structure stage runs after it)."""
    vmap = VoxelMap(cfg.voxel_m)
    use = cfg.structure if structure is None else structure
    model = StructureModel(StructureConfig(), Environment.INDOOR, cfg.voxel_m) if use else None
    rows, contexts, wides, sample_scan, origins, floors, stamps, scan_rows, new_rows = ([] for _ in range(9))
    evidence: list[np.ndarray] = []
    for t, scan in enumerate(mission):
        assert scan.class_ids is not None and scan.instance_ids is not None and scan.times is not None
        poses = mission.trajectory.poses(mission.sweep_start_s(t) + scan.times)  # (N, 4, 4)
        world = np.einsum("nij,nj->ni", poses[:, :3, :3], scan.points) + poses[:, :3, 3]
        end = mission.trajectory.poses(np.array([mission.sweep_start_s(t) + mission.profile.sweep_s]))[0]
        keep = np.hypot(scan.points[:, 0], scan.points[:, 1]) <= cfg.range_m  # as pipeline.label does
        colors = None if scan.colors is None else scan.colors[keep]
        new, point_rows = vmap.insert(world[keep], colors, t, scan.class_ids[keep], scan.instance_ids[keep])
        draws = context_draws(vmap.keys[new], cfg.context_points)
        ctx = vmap.context_rows(vmap.positions[new], cfg.context_cell_m, cfg.context_points, uniform=draws)
        wide = np.zeros((len(new), 0), np.int64)
        if cfg.coarse_points:  # drawn as the labeller draws it (MCPNetLabeller.wide_context_rows)
            draws = context_draws(vmap.keys[new], cfg.coarse_points)
            wide = vmap.context_rows(vmap.positions[new], cfg.coarse_cell_m, cfg.coarse_points, uniform=draws)
        if model is not None:  # the model as of the previous scan, then this scan's voxels into it
            evidence.append(structure_features(model, vmap.positions[new], float(end[2, 3])))
            model.update(vmap, float(end[2, 3]))
        rows.append(new.astype(np.int64))
        contexts.append(ctx.astype(np.int64))
        wides.append(wide.astype(np.int64))
        sample_scan.append(np.full(len(new), t, np.int64))
        origins.append(end[:3, 3].copy())
        floors.append(floor_height(world))
        stamps.append(scan.stamp_s)
        scan_rows.append(np.unique(point_rows).astype(np.int64))
        new_rows.append(new.astype(np.int64))
    m = cfg.context_points
    return Mission(
        positions=vmap.positions.copy(),
        colors=vmap.colors.copy(),
        classes=vmap.true_class_ids.astype(np.int64),
        instances=vmap.true_instance_ids.astype(np.int64),
        rows=np.concatenate(rows) if rows else np.zeros(0, np.int64),
        context=np.concatenate(contexts) if contexts else np.zeros((0, m), np.int64),
        wide=np.concatenate(wides) if wides else np.zeros((0, cfg.coarse_points), np.int64),
        sample_scan=np.concatenate(sample_scan) if sample_scan else np.zeros(0, np.int64),
        origins=np.array(origins).reshape(-1, 3),
        floors=np.array(floors),
        stamps=np.array(stamps),
        scan_rows=scan_rows,
        new_rows=new_rows,
        structure=np.concatenate(evidence) if evidence else np.zeros((0, len(STRUCTURE_FEATURES)), np.float32),
    )


def transfer_uris(seeds: Iterable[int], scans: int, generators: tuple[str, ...] = split.TRAIN_GENERATORS) -> list[str]:
    """The randomised training missions: every training generator and seed, a sensor and a robot drawn per
    mission, the robot's mount, motion, the palette and the sensor's conditions drawn by the simulator."""
    out = []
    for s in seeds:
        for g in generators:
            rng = np.random.default_rng([s, sum(map(ord, g)), 12])
            sensor = TRANSFER_SENSORS[int(rng.integers(len(TRANSFER_SENSORS)))]
            robot = TRANSFER_ROBOTS[int(rng.integers(len(TRANSFER_ROBOTS)))]
            out.append(f"sim://{g}?seed={s}&sensor={sensor}&scans={scans}&robot={robot}&randomize=1")
    return out


def open_uri(uri: str) -> SimMission:
    from aftershock.sources.simulated import make_mission, parse_sim_uri

    return make_mission(parse_sim_uri(uri))


def open_mission(family: str, seed: int, scans: int) -> SimMission:
    """The simulated mission `sim://FAMILY?seed=N&sensor=vlp16&scans=N` describes."""
    return SimMission(build_scene(family, seed=seed), get_profile(SENSOR), seed=seed, scans=scans)


class Pool:
    """Several staged missions joined into one table: rows offset per mission, instances made unique."""

    def __init__(self, missions: list[Mission]) -> None:
        offsets = np.cumsum([0] + [len(m.positions) for m in missions])
        self.positions = np.concatenate([m.positions for m in missions])
        self.colors = np.concatenate([m.colors for m in missions]).astype(np.float32) / 255.0
        self.classes = np.concatenate([m.classes for m in missions])
        inst = [np.where(m.instances > 0, m.instances + (i << 32), 0) for i, m in enumerate(missions)]
        self.instances = np.concatenate(inst)
        self.rows = np.concatenate([m.rows + o for m, o in zip(missions, offsets, strict=False)])
        self.context = np.concatenate(
            [np.where(m.context >= 0, m.context + o, -1) for m, o in zip(missions, offsets, strict=False)]
        )
        self.wide = np.concatenate(
            [np.where(m.wide >= 0, m.wide + o, -1) for m, o in zip(missions, offsets, strict=False)]
        )
        self.origin = np.concatenate([m.origins[m.sample_scan] for m in missions])
        self.floor = np.concatenate([m.floors[m.sample_scan] for m in missions])
        self.mission = np.concatenate([np.full(len(m.rows), i, np.int64) for i, m in enumerate(missions)])
        self.num_missions = len(missions)
        # staged without a structure model: none of its evidence (a network that reads it cannot train here)
        have = all(len(m.structure) == len(m.rows) for m in missions)
        self.structure = (
            np.concatenate([m.structure for m in missions]).astype(np.float32)
            if have
            else np.zeros((len(self.rows), 0), np.float32)
        )
        known = self.classes[self.rows] != UNLABELLED
        for name in ("rows", "context", "wide", "origin", "floor", "mission", "structure"):
            setattr(self, name, getattr(self, name)[known])
        self.sample_class = self.classes[self.rows]
        self.sample_instance = self.instances[self.rows]
        # Instances with at least two training points, and where their points sit in the sample arrays.
        order = np.argsort(self.sample_instance, kind="stable")
        ids, start, count = np.unique(self.sample_instance[order], return_index=True, return_counts=True)
        good = (ids > 0) & (count >= 2)
        self.inst_order, self.inst_start, self.inst_count = order, start[good], count[good]
        # Where each of those instances lies (centroid of its training points) and whose mission it is, for
        # batches of neighbouring instances (`local_instance_batch`).
        inst_of_sample = np.repeat(np.arange(len(ids)), count)[np.argsort(order, kind="stable")]
        sums = np.zeros((len(ids), 3))
        np.add.at(sums, inst_of_sample, self.positions[self.rows])
        self.inst_centre = (sums / count[:, None])[good]
        self.inst_mission = (ids[good] >> 32).astype(np.int64)
        self._crop_tree: Any = None  # a scipy cKDTree (untyped), built on the first `crop_batch`

    def __len__(self) -> int:
        return len(self.rows)

    def features(
        self,
        idx: np.ndarray,
        rng: np.random.Generator,
        augment: bool,
        cfg: NetConfig,
        color_drop: float = COLOR_DROP,
        per_mission: bool = False,
    ) -> tuple[np.ndarray, ...]:
        """Point features (B, len(cfg.features)), context (B, M, 6), mask (B, M), wider context (B, Mw, 3) and
        its mask (B, Mw) of samples `idx`. With `augment`: a random turn about z per sample, and colour dropped
        for a share `color_drop` of the samples, or of the missions with `per_mission` (a robot without a camera
        has no colour for a whole log)."""
        rows = self.rows[idx]
        pos = self.positions[rows]
        base = np.zeros((len(idx), POINT_DIM), np.float32)
        base[:, 0:2] = pos[:, 0:2] - self.origin[idx, 0:2]
        base[:, 2] = pos[:, 2] - self.floor[idx]
        base[:, 3:6] = self.colors[rows] - 0.5
        base[:, 6] = 1.0
        ctx_rows = self.context[idx]
        mask = ctx_rows >= 0
        safe = np.where(mask, ctx_rows, rows[:, None])
        ctx = np.zeros((*ctx_rows.shape, CONTEXT_DIM), np.float32)
        ctx[..., 0:3] = self.positions[safe] - pos[:, None, :]
        ctx[..., 3:6] = self.colors[safe] - self.colors[rows][:, None, :]
        wide, wide_mask = row_offsets(self.positions, rows, self.wide[idx])
        if augment:
            angle = rng.uniform(0, 2 * np.pi, len(idx)).astype(np.float32)
            c, s = np.cos(angle), np.sin(angle)
            for arr, cc, ss in ((base, c, s), (ctx, c[:, None], s[:, None]), (wide, c[:, None], s[:, None])):
                x, y = arr[..., 0].copy(), arr[..., 1].copy()
                arr[..., 0], arr[..., 1] = cc * x - ss * y, ss * x + cc * y
            if per_mission:
                drop = (rng.random(self.num_missions) < color_drop)[self.mission[idx]]
            else:
                drop = rng.random(len(idx)) < color_drop
            base[drop, 3:7] = 0.0
            ctx[drop, :, 3:6] = 0.0
        structure = self.structure[idx] if cfg.structure else None  # the same from any direction: not turned
        pf = point_inputs(cfg, base, ctx, mask, wide, wide_mask, structure)  # the shape features turn with the offsets
        return pf, ctx, mask, wide, wide_mask

    def instance_batch(self, rng: np.random.Generator) -> np.ndarray:
        """16 instances x 16 points (with replacement where an instance has fewer), as sample indices."""
        pick = rng.choice(len(self.inst_start), size=min(BATCH_INSTANCES, len(self.inst_start)), replace=False)
        return self._instance_points(pick, rng)

    def local_instance_batch(self, rng: np.random.Generator) -> np.ndarray:
        """Like `instance_batch`, but one random instance and the 15 of its mission whose centroids lie nearest:
        the negatives the clusterer must tell apart (two walls at a corner, chairs side by side), which 16
        instances drawn over all missions almost never hold."""
        anchor = int(rng.integers(len(self.inst_start)))
        same = np.flatnonzero(self.inst_mission == self.inst_mission[anchor])
        dist = np.linalg.norm(self.inst_centre[same] - self.inst_centre[anchor], axis=1)
        pick = same[np.argsort(dist, kind="stable")[:BATCH_INSTANCES]]  # the anchor itself first
        return self._instance_points(pick, rng)

    def crop_batch(self, rng: np.random.Generator) -> np.ndarray:
        """The CROP_POINTS training points of one mission nearest a random point of a random instance: a piece of
        the map about a metre across with the boundaries the clusterer has to draw (an object and the floor
        under it, two walls at a corner), at the density the map has."""
        if self._crop_tree is None:
            from scipy.spatial import cKDTree

            where = self.positions[self.rows].copy()
            where[:, 0] += self.mission * _MISSION_SPACING_M
            self._crop_tree = cKDTree(where)
        anchor = self._instance_points(np.array([int(rng.integers(len(self.inst_start)))]), rng)[0]
        _, near = self._crop_tree.query(self._crop_tree.data[anchor], k=min(CROP_POINTS, len(self)))
        return np.sort(np.asarray(near, np.int64))

    def _instance_points(self, pick: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        offs = (rng.random((len(pick), POINTS_PER_INSTANCE)) * self.inst_count[pick, None]).astype(np.int64)
        return self.inst_order[self.inst_start[pick, None] + offs].ravel()


def distinct_draws(ctx_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(point index, draw index) of the first draw of every distinct neighbour in context rows (K, M), -1 left
    out: pooling these gives what pooling all draws gives, at the cost of the distinct ones."""
    order = np.argsort(ctx_rows, axis=1, kind="stable")
    s = np.take_along_axis(ctx_rows, order, axis=1)
    keep = s >= 0
    keep[:, 1:] &= s[:, 1:] != s[:, :-1]
    owner, j = np.nonzero(keep)
    return owner, order[owner, j]


def semihard_triplet_loss(emb: torch.Tensor, labels: torch.Tensor, margin: float = MARGIN) -> torch.Tensor:
    """Semi-hard triplet loss on squared distances of unit embeddings, over every anchor-positive pair:
    the negative is the closest one farther than the positive, else the farthest negative.
    Each anchor's negative distances are sorted once and searched, O(B^2 log B) rather than O(B^3)."""
    n = len(labels)
    d = (2.0 - 2.0 * emb @ emb.T).clamp_min(0.0)
    same = labels[:, None] == labels[None, :]
    pos = same & ~torch.eye(n, dtype=torch.bool)
    neg = ~same
    if not pos.any() or not neg.any():
        return emb.sum() * 0.0
    big = torch.full_like(d, 1e9)
    sorted_neg, _ = torch.where(neg, d, big).sort(dim=1)  # non-negatives sort to the end
    first_beyond = torch.searchsorted(sorted_neg.detach(), d.detach().contiguous(), right=True)
    has = first_beyond < neg.sum(dim=1, keepdim=True)
    closest = sorted_neg.gather(1, first_beyond.clamp(max=n - 1))
    farthest = torch.where(neg, d, torch.zeros_like(d)).amax(dim=1, keepdim=True).expand_as(d)
    d_an = torch.where(has, closest, farthest)
    loss = (margin + d - d_an).clamp_min(0.0)
    return loss[pos].mean()


def affinity_loss(emb: torch.Tensor, labels: torch.Tensor, positions: np.ndarray) -> torch.Tensor:
    """Double-margin loss on the cosine similarity of unit embeddings of points within AFFINITY_RADIUS_M of each
    other: one instance's pairs below LINK_POSITIVE and two instances' pairs above LINK_NEGATIVE cost the square of
    the shortfall; the two kinds are averaged apart (different-instance neighbours are the rarer, and the ones that
    merge objects). Points of no instance (label 0) take no part."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(positions).query_pairs(AFFINITY_RADIUS_M, output_type="ndarray")
    if len(pairs) == 0:
        return emb.sum() * 0.0
    i, j = torch.from_numpy(pairs[:, 0]), torch.from_numpy(pairs[:, 1])
    keep = (labels[i] > 0) & (labels[j] > 0)
    i, j = i[keep], j[keep]
    cos = (emb[i] * emb[j]).sum(dim=1)
    same = labels[i] == labels[j]
    loss = emb.sum() * 0.0
    if same.any():
        loss = loss + (LINK_POSITIVE - cos[same]).clamp_min(0.0).square().mean()
    if (~same).any():
        loss = loss + (cos[~same] - LINK_NEGATIVE).clamp_min(0.0).square().mean()
    return loss


def weighted_class_loss(
    ce: nn.CrossEntropyLoss, logits: torch.Tensor, labels: torch.Tensor, head: int, head_weight: float
) -> torch.Tensor:
    """`ce`'s weighted mean with the first `head` points counting `head_weight` each (the others 1): with 0 it is
    `ce` over the rest alone."""
    per_point = nn.functional.cross_entropy(logits, labels, weight=ce.weight, reduction="none")
    share = torch.ones(len(labels))
    share[:head] = head_weight
    class_weight = ce.weight[labels] if ce.weight is not None else 1.0
    return (per_point * share).sum() / (class_weight * share).sum()


def train_mcpnet(
    pool: Pool,
    cfg: NetConfig,
    epochs: int,
    seed: int,
    log: bool = True,
    color_drop: float = COLOR_DROP,
    checkpoint: Callable[[MCPNet, dict], None] | None = None,
    learning_rate: float = LEARNING_RATE,
    per_mission: bool = False,
    class_weight_power: float = 0.0,
    local_batches: float = 0.0,
    crop_batches: float = 0.0,
    affinity_weight: float = 0.0,
    crop_class_weight: float = 1.0,
) -> tuple[MCPNet, dict]:
    """Adam on triplet + cross-entropy; an epoch is as many batches as it takes to see every point once.
    `class_weight_power` p weights each class's loss by (its share of the points)^-p: 0 sees the classes as the
    stream does, 0.5 lifts the rare ones (mean IoU counts every class alike). `local_batches`: the share of
    batches whose instances are neighbours in one mission (`Pool.local_instance_batch`); 0 draws no extra random
    numbers, so recipes without it train as before. `crop_batches`: the share of batches that are a spatial crop
    (`Pool.crop_batch`; drawn before the local ones), where `affinity_weight` weighs `affinity_loss` beside the
    triplet loss (over the crop's points of an instance); `crop_class_weight` weighs a crop batch's own points in
    its class loss against its uniformly drawn ones (0: the uniform points only; a crop is mostly the floor and
    walls around one object)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = MCPNet(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=learning_rate)
    batch = BATCH_INSTANCES * POINTS_PER_INSTANCE
    steps = max(1, len(pool) // batch)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs * steps, eta_min=learning_rate / 20)
    share = np.bincount(pool.sample_class, minlength=cfg.num_classes) / len(pool)
    weight = np.where(share > 0, np.maximum(share, 1e-4) ** -class_weight_power, 0.0)
    weight = weight / (weight * share).sum()  # the mean weight over the points stays 1
    ce = nn.CrossEntropyLoss(weight=torch.from_numpy(weight.astype(np.float32)))
    use_ctx = cfg.kind == "mcpnet"
    history = []
    start = time.perf_counter()
    for epoch in range(epochs):
        tot_t = tot_c = acc = 0.0
        for _ in range(steps):
            crop = crop_batches > 0 and rng.random() < crop_batches
            local = not crop and local_batches > 0 and rng.random() < local_batches
            if crop:
                inst_idx = pool.crop_batch(rng)
            else:
                inst_idx = pool.local_instance_batch(rng) if local else pool.instance_batch(rng)
            uni_idx = rng.integers(0, len(pool), UNIFORM_POINTS)  # class frequencies as the stream sees them
            idx = np.concatenate([inst_idx, uni_idx])
            pf, ctx, _, wide, _ = pool.features(idx, rng, True, cfg, color_drop, per_mission)
            pooled = None
            if use_ctx:  # each distinct neighbour once, as the labeller pools (a third of the draws repeat)
                owner, at = distinct_draws(pool.context[idx])
                pooled = model.pool_pairs(torch.from_numpy(ctx[owner, at]), torch.from_numpy(owner), len(idx))
            if model.use_wide:
                owner, at = distinct_draws(pool.wide[idx])
                wide_pooled = model.pool_pairs(
                    torch.from_numpy(wide[owner, at]), torch.from_numpy(owner), len(idx), True
                )
                assert pooled is not None, "the wide context comes with the context"
                pooled = torch.cat([pooled, wide_pooled], dim=1)
            emb, logits = model.head(torch.from_numpy(pf), pooled)
            labels = torch.from_numpy(pool.sample_class[idx])
            inst = torch.from_numpy(pool.sample_instance[inst_idx])
            if crop:
                of_object = inst > 0
                lt = semihard_triplet_loss(emb[: len(inst_idx)][of_object], inst[of_object])
                if affinity_weight > 0:
                    where = pool.positions[pool.rows[inst_idx]]
                    lt = lt + affinity_weight * affinity_loss(emb[: len(inst_idx)], inst, where)
            else:
                lt = semihard_triplet_loss(emb[: len(inst_idx)], inst)
            # at weight 1 the plain mean: the same value, and the shipped recipes rebuild bit for bit
            if crop and crop_class_weight != 1.0:
                lc = weighted_class_loss(ce, logits, labels, len(inst_idx), crop_class_weight)
            else:
                lc = ce(logits, labels)
            descend(opt, lt + lc, sched)
            tot_t += float(lt.detach())
            tot_c += float(lc.detach())
            acc += float((logits.argmax(1) == labels).float().mean())
        history.append({"epoch": epoch + 1, "triplet": tot_t / steps, "ce": tot_c / steps, "acc": acc / steps})
        if log:
            _log_epoch(cfg.kind, epochs, history[-1], start)
        if checkpoint is not None and epoch + 1 < epochs:  # a long run on a busy machine keeps what it has
            checkpoint(model, {"epoch": epoch + 1, "history": list(history)})
    model.eval()
    return model, {"steps_per_epoch": steps, "history": history, "seconds": round(time.perf_counter() - start, 1)}


def _log_epoch(kind: str, epochs: int, h: dict[str, float], start: float) -> None:
    """One progress line per training epoch, on stderr."""
    print(
        f"[{kind}] epoch {h['epoch']}/{epochs}: triplet {h['triplet']:.3f} ce {h['ce']:.3f} "
        f"acc {h['acc']:.3f} ({time.perf_counter() - start:.0f} s)",
        file=sys.stderr,
        flush=True,
    )


# ----------------------------------------------------------------------------------------------- PointNet


def expansion_rows(mission: Mission, t: int, mode: str) -> np.ndarray:
    """Map rows PointNet sees at scan t: the scan alone, with the scans of the last 0.1 s, or within 0.5 m."""
    if mode == "single":
        return mission.scan_rows[t]
    if mode == "temporal":
        near = np.flatnonzero(mission.stamps[: t + 1] >= mission.stamps[t] - TEMPORAL_WINDOW_S - 1e-6)
    else:
        d = np.linalg.norm(mission.origins[: t + 1, :2] - mission.origins[t, :2], axis=1)
        near = np.flatnonzero(d <= SPATIAL_WINDOW_M)
    return np.unique(np.concatenate([mission.scan_rows[i] for i in near]))


def train_pointnet(
    missions: list[Mission], cfg: NetConfig, epochs: int, seed: int, log: bool = True
) -> tuple[PointNet, dict]:
    """One PointNet for all three online baselines: each training cloud is a scan expanded one of three ways."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = PointNet(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=LEARNING_RATE)
    ce = nn.CrossEntropyLoss(ignore_index=-1)
    scans = [(i, t) for i, m in enumerate(missions) for t in range(len(m.scan_rows)) if len(m.new_rows[t])]
    per_epoch = max(POINTNET_CLOUDS_PER_STEP, int(len(scans) * POINTNET_SCAN_SHARE))
    steps = max(1, per_epoch // POINTNET_CLOUDS_PER_STEP)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs * steps, eta_min=LEARNING_RATE / 20)
    history = []
    start = time.perf_counter()
    for epoch in range(epochs):
        order = rng.permutation(len(scans))
        tot_t = tot_c = acc = 0.0
        for s in range(steps):
            pick = order[s * POINTNET_CLOUDS_PER_STEP : (s + 1) * POINTNET_CLOUDS_PER_STEP]
            feats, labels, insts, masks = [], [], [], []
            for k in pick:
                i, t = scans[k]
                m = missions[i]
                rows = expansion_rows(m, t, ("single", "temporal", "spatial")[rng.integers(3)])
                if len(rows) > POINTNET_MAX_POINTS:
                    rows = rng.choice(rows, POINTNET_MAX_POINTS, replace=False)
                f = point_features(m.positions[rows], m.colors[rows], m.origins[t], m.floors[t])
                angle = rng.uniform(0, 2 * np.pi)
                c, sn = np.cos(angle), np.sin(angle)
                f[:, 0], f[:, 1] = c * f[:, 0] - sn * f[:, 1], sn * f[:, 0] + c * f[:, 1]
                if rng.random() < COLOR_DROP:
                    f[:, 3:7] = 0.0
                pad = POINTNET_MAX_POINTS - len(rows)
                cls = np.where(m.classes[rows] == UNLABELLED, -1, m.classes[rows])
                feats.append(np.pad(f, ((0, pad), (0, 0))))
                labels.append(np.pad(cls, (0, pad), constant_values=-1))
                insts.append(np.pad(m.instances[rows], (0, pad)))
                masks.append(np.arange(POINTNET_MAX_POINTS) < len(rows))
            emb, logits = model(torch.from_numpy(np.stack(feats)), torch.from_numpy(np.stack(masks)))
            lab = torch.from_numpy(np.stack(labels))
            lc = ce(logits.reshape(-1, cfg.num_classes), lab.reshape(-1))
            lt = torch.zeros(())
            for b in range(len(pick)):
                sel = _instance_subset(insts[b], masks[b], rng)
                if len(sel):
                    lt = lt + semihard_triplet_loss(emb[b, sel], torch.from_numpy(insts[b][sel])) / len(pick)
            descend(opt, lt + lc, sched)
            tot_t += float(lt.detach())
            tot_c += float(lc.detach())
            valid = lab >= 0
            acc += float((logits.argmax(-1)[valid] == lab[valid]).float().mean())
        history.append({"epoch": epoch + 1, "triplet": tot_t / steps, "ce": tot_c / steps, "acc": acc / steps})
        if log:
            _log_epoch("pointnet", epochs, history[-1], start)
    model.eval()
    return model, {"steps_per_epoch": steps, "history": history, "seconds": round(time.perf_counter() - start, 1)}


def _instance_subset(insts: np.ndarray, mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Up to 16 points of each of up to 16 instances of one cloud, for the triplet loss."""
    valid = np.flatnonzero(mask & (insts > 0))
    if not len(valid):
        return valid
    ids = np.unique(insts[valid])
    ids = rng.choice(ids, min(BATCH_INSTANCES, len(ids)), replace=False)
    out = []
    for i in ids:  # at most 16 instances per cloud
        members = valid[insts[valid] == i]
        out.append(rng.choice(members, min(POINTS_PER_INSTANCE, len(members)), replace=False))
    return np.concatenate(out)


# ----------------------------------------------------------------------------------------------- entry point


def stage_all(seeds: Iterable[int], scans: int, cfg: NetConfig, log: bool = True) -> list[Mission]:
    """Missions of both families for each seed."""
    missions = []
    for s in seeds:
        for family in FAMILIES:
            t0 = time.perf_counter()
            missions.append(stage_mission(open_mission(family, s, scans), cfg))
            if log:
                m = missions[-1]
                print(
                    f"staged {family} seed {s}: {len(m.rows)} points, {len(m.positions)} voxels "
                    f"({time.perf_counter() - t0:.1f} s)",
                    file=sys.stderr,
                    flush=True,
                )
    return missions


def stage_uris(uris: Iterable[str], cfg: NetConfig, log: bool = True, structure: bool | None = None) -> list[Mission]:
    """Staged missions of simulator URIs (`structure`: as `stage_mission`)."""
    missions = []
    for uri in uris:
        t0 = time.perf_counter()
        missions.append(stage_mission(open_uri(uri), cfg, structure))
        if log:
            m = missions[-1]
            print(
                f"staged {uri}: {len(m.rows)} points, {len(m.positions)} voxels ({time.perf_counter() - t0:.1f} s)",
                file=sys.stderr,
                flush=True,
            )
    return missions


KINDS: Final[tuple[str, ...]] = ("mcpnet", "mcpnet-nocolor", "mcpnet-nocontext", "pointnet")
# The colour-free network reads the structure model's evidence (#28): see docs/decisions.md for the round that
# decided it.
TRANSFER_STRUCTURE: Final = False


def train_transfer(
    pool: Pool,
    cfg: NetConfig,
    epochs: int,
    seed: int,
    checkpoint: Callable[[MCPNet, dict], None] | None = None,
    log: bool = True,
) -> tuple[MCPNet, dict]:
    """The colour-free network's recipe (TRANSFER_*) on a staged pool."""
    return train_mcpnet(
        pool,
        cfg,
        epochs,
        seed,
        log=log,
        color_drop=TRANSFER_COLOR_DROP,
        per_mission=True,
        class_weight_power=CLASS_WEIGHT_POWER,
        local_batches=TRANSFER_LOCAL_BATCHES,
        crop_batches=TRANSFER_CROP_BATCHES,
        affinity_weight=TRANSFER_AFFINITY_WEIGHT,
        crop_class_weight=TRANSFER_CROP_CLASS_WEIGHT,
        checkpoint=checkpoint,
    )


def mcpnet_config(structure: bool = False) -> NetConfig:
    """MCPNet for logs without colour (#12): height, colour (for training with and without it) and the local
    shape at two scales, a wider context branch; x, y relative to the robot left out. With `structure` (#28) also
    the structure model's evidence (STRUCTURE_FEATURES)."""
    features = STRUCTURE_TRANSFER_FEATURES if structure else TRANSFER_FEATURES
    return NetConfig(kind="mcpnet", point_dim=len(features), features=features, coarse_points=COARSE_POINTS)


def train(
    out: Path | None = None,
    seed: int = 0,
    epochs: int | None = None,
    force: bool = False,
    kinds: tuple[str, ...] = KINDS,
    generators: tuple[str, ...] = split.TRAIN_GENERATORS,
    structure: bool | None = None,
) -> dict[str, Any]:
    """Stage the training missions, train the networks, write their weights.

    MCPNet for logs with colour, MCPNet without context and PointNet: plain VLP-16 missions of both families,
    colour dropped per point. MCPNet for logs without colour (#12): randomised missions of the training
    generators (`transfer_uris`), see TRANSFER_*. `out` is the MCPNet weights file (default
    models/weights/mcpnet.pt); the others go beside it. `kinds` limits which networks are trained; `epochs`
    overrides every network's epochs; `generators` the scene generators of the colour-free network's missions;
    `structure` whether it reads the structure model's evidence (default TRANSFER_STRUCTURE).
    """
    torch.set_num_threads(1)  # on a shared 2-core machine a second intra-op thread mostly waits
    out = Path(out) if out is not None else WEIGHTS_DIR / "mcpnet.pt"
    paths = {
        "mcpnet": out,
        "mcpnet-nocolor": out.with_name(out.stem + "_nocolor.pt"),
        "mcpnet-nocontext": out.with_name(out.stem + "_nocontext.pt"),
        "pointnet": out.with_name("pointnet.pt") if out.stem == "mcpnet" else out.with_name(out.stem + "_pointnet.pt"),
    }
    paths = {k: p for k, p in paths.items() if k in kinds}
    for p in paths.values():
        if p.exists() and not force:
            raise OutputError("weights file exists; pass --force to overwrite", p)
    start = time.perf_counter()
    figures: dict[str, Any] = {"seed": seed}

    def keep(kind: str, model: nn.Module, cfg: NetConfig, recipe: dict[str, Any], fig: dict[str, Any]) -> None:
        fig["parameters"] = num_parameters(model)
        save_weights(paths[kind], model, cfg, {**recipe, **fig})
        figures[kind] = {k: v for k, v in fig.items() if k != "history"} | {"final": fig["history"][-1]}

    if {"mcpnet", "mcpnet-nocontext", "pointnet"} & set(kinds):
        base = NetConfig()
        missions = stage_all(TRAIN_SEEDS, TRAIN_SCANS, base)
        pool = Pool(missions)
        recipe = {
            "train_seeds": list(TRAIN_SEEDS),
            "families": list(FAMILIES),
            "sensor": SENSOR,
            "scans_per_mission": TRAIN_SCANS,
            "training_points": len(pool),
            "range_m": base.range_m,
            "seed": seed,
            "staging_seconds": round(time.perf_counter() - start, 1),
        }
        for kind in ("mcpnet", "mcpnet-nocontext"):
            if kind in kinds:
                cfg = NetConfig(kind=kind)
                # MCPNet's own recipe; the no-context network stays the baseline it was
                own, crop_batches, affinity_weight = (
                    (MCPNET_EPOCHS, CROP_BATCHES, AFFINITY_WEIGHT) if kind == "mcpnet" else (EPOCHS, 0.0, 0.0)
                )
                model, fig = train_mcpnet(
                    pool,
                    cfg,
                    own if epochs is None else epochs,
                    seed,
                    crop_batches=crop_batches,
                    affinity_weight=affinity_weight,
                )
                crops = {"crop_batches": CROP_BATCHES, "affinity_weight": AFFINITY_WEIGHT} if kind == "mcpnet" else {}
                keep(kind, model, cfg, recipe | crops, fig)
        if "pointnet" in kinds:
            cfg = NetConfig(kind="pointnet")
            pointnet, fig = train_pointnet(missions, cfg, POINTNET_EPOCHS if epochs is None else epochs, seed)
            keep("pointnet", pointnet, cfg, recipe, fig)
        del missions, pool
    if "mcpnet-nocolor" in kinds:
        t0 = time.perf_counter()
        cfg = mcpnet_config(TRANSFER_STRUCTURE if structure is None else structure)
        uris = transfer_uris(TRAIN_SEEDS, TRANSFER_SCANS, generators)
        pool = Pool(stage_uris(uris, cfg))
        transfer_epochs = TRANSFER_EPOCHS if epochs is None else epochs
        recipe = {
            "structure_features": cfg.structure,
            "train_seeds": list(TRAIN_SEEDS),
            "generators": list(generators),
            "held_out_generator": split.HELDOUT_GENERATOR,
            "missions": uris,
            "scans_per_mission": TRANSFER_SCANS,
            "color_drop_per_mission": TRANSFER_COLOR_DROP,
            "class_weight_power": CLASS_WEIGHT_POWER,
            "local_batches": TRANSFER_LOCAL_BATCHES,
            "crop_batches": TRANSFER_CROP_BATCHES,
            "affinity_weight": TRANSFER_AFFINITY_WEIGHT,
            "crop_class_weight": TRANSFER_CROP_CLASS_WEIGHT,
            "training_points": len(pool),
            "epochs": transfer_epochs,
            "range_m": cfg.range_m,
            "seed": seed,
            "staging_seconds": round(time.perf_counter() - t0, 1),
        }
        partial = paths["mcpnet-nocolor"].with_suffix(".partial.pt")
        model, fig = train_transfer(
            pool, cfg, transfer_epochs, seed, lambda m, f: save_weights(partial, m, cfg, {**recipe, **f})
        )
        keep("mcpnet-nocolor", model, cfg, recipe, fig)
        partial.unlink(missing_ok=True)
    figures["weights"] = {k: str(p) for k, p in paths.items()}
    figures["sizes_bytes"] = {k: p.stat().st_size for k, p in paths.items()}
    figures["total_seconds"] = round(time.perf_counter() - start, 1)
    return figures
