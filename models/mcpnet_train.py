"""`aftershock train mcpnet`: MCPNet and its baselines from simulated missions, seeded, on a CPU.

Missions of both scene families are staged the way inference sees them: each scan is placed in the world
(with the simulator's true pose: registration noise is left out of training), cut to the labelling range,
inserted in a voxel map, and every voxel it opens becomes a training point whose context is drawn from the
map built so far. The same staged missions train the network without context and the PointNet baseline
(single scans, the scans of the last 0.1 s, the scans within 0.5 m). Held-out seeds are never trained on.
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
    num_parameters,
    point_features,
    save_weights,
    with_geometry,
)
from aftershock.models.netconfig import CONTEXT_DIM, GEOMETRY_FEATURES, POINT_DIM, POINT_FEATURES, NetConfig
from aftershock.models.pointnet import PointNet
from aftershock.models.weights_file import WEIGHTS_DIR
from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.errors import OutputError
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

EPOCHS: Final = 3  # MCPNet and its no-context variant: an epoch shows every training point once
POINTNET_EPOCHS: Final = 14  # PointNet: an epoch shows a quarter of the training scans
BATCH_INSTANCES: Final = 16
POINTS_PER_INSTANCE: Final = 16
MARGIN: Final = 1.0
UNIFORM_POINTS: Final = 128  # per batch, drawn over all points for the class loss only
LEARNING_RATE: Final = 1e-3
COLOR_DROP: Final = 0.3  # share of training points shown without colour (the colour-free mode)
# MCPNet since #12: trained to transfer. Randomised missions of the training generators (palettes, robots,
# mounts, sensors, conditions), geometry features, and colour dropped for half the points, so that the
# colour-free mode is learnt as much as the colour one. The held-out generator is never staged.
TRANSFER_SEEDS: Final[tuple[int, ...]] = split.TRAIN_SEEDS[:4]
TRANSFER_SCANS: Final = 100
TRANSFER_COLOR_DROP: Final = 0.5
TRANSFER_EPOCHS: Final = 1  # fine-tuning the families' MCPNet (see `widen`)
TRANSFER_LEARNING_RATE: Final = LEARNING_RATE / 3
TRANSFER_SENSORS: Final[tuple[str, ...]] = ("vlp16", "vlp16", "vlp32c", "os1-32")
TRANSFER_ROBOTS: Final[tuple[str, ...]] = ("legged", "wheeled", "tracked")
POINTNET_MAX_POINTS: Final = 1024
POINTNET_CLOUDS_PER_STEP: Final = 8
POINTNET_SCAN_SHARE: Final = 0.25  # scans (clouds) drawn per PointNet epoch, as a share of all training scans
TEMPORAL_WINDOW_S: Final = 0.1
SPATIAL_WINDOW_M: Final = 0.5


def floor_height(world_points: np.ndarray) -> float:
    """The scan's floor: a low percentile of the whole scan's heights (robust to a few stray returns)."""
    if not len(world_points):
        return 0.0
    return float(np.percentile(world_points[:, 2], 1.0))


@dataclass(slots=True)
class Mission:
    """One staged mission: the map's stored points with their truth, and the points to predict."""

    positions: np.ndarray  # (R, 3) float64
    colors: np.ndarray  # (R, 3) uint8
    classes: np.ndarray  # (R,) int64 true class (UNLABELLED where unknown)
    instances: np.ndarray  # (R,) int64 true instance (0 = none)
    rows: np.ndarray  # (S,) int64 map row of every training point (a new voxel)
    context: np.ndarray  # (S, M) int64 context rows, -1 where none
    sample_scan: np.ndarray  # (S,) int64 scan index of every training point
    origins: np.ndarray  # (T, 3) sensor position per scan
    floors: np.ndarray  # (T,) floor height per scan
    stamps: np.ndarray  # (T,) scan time, seconds
    scan_rows: list[np.ndarray]  # rows hit by each scan (inside the range)
    new_rows: list[np.ndarray]  # rows each scan opened


def stage_mission(mission: SimMission, cfg: NetConfig) -> Mission:
    """Replay a simulated mission with its true motion through a voxel map; see the module docstring.

    Every point is placed with the true pose at its own firing time (an exact deskew), where inference
    has KISS-ICP's estimate instead."""
    vmap = VoxelMap(cfg.voxel_m)
    rows, contexts, sample_scan, origins, floors, stamps, scan_rows, new_rows = [], [], [], [], [], [], [], []
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
        rows.append(new.astype(np.int64))
        contexts.append(ctx.astype(np.int64))
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
        sample_scan=np.concatenate(sample_scan) if sample_scan else np.zeros(0, np.int64),
        origins=np.array(origins).reshape(-1, 3),
        floors=np.array(floors),
        stamps=np.array(stamps),
        scan_rows=scan_rows,
        new_rows=new_rows,
    )


def transfer_uris(seeds: Iterable[int], scans: int) -> list[str]:
    """The randomised training missions: every training generator and seed, a sensor and a robot drawn per
    mission, the robot's mount, motion, the palette and the sensor's conditions drawn by the simulator."""
    out = []
    for s in seeds:
        for g in split.TRAIN_GENERATORS:
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
        self.origin = np.concatenate([m.origins[m.sample_scan] for m in missions])
        self.floor = np.concatenate([m.floors[m.sample_scan] for m in missions])
        known = self.classes[self.rows] != UNLABELLED
        for name in ("rows", "context", "origin", "floor"):
            setattr(self, name, getattr(self, name)[known])
        self.sample_class = self.classes[self.rows]
        self.sample_instance = self.instances[self.rows]
        # Instances with at least two training points, and where their points sit in the sample arrays.
        order = np.argsort(self.sample_instance, kind="stable")
        ids, start, count = np.unique(self.sample_instance[order], return_index=True, return_counts=True)
        good = (ids > 0) & (count >= 2)
        self.inst_order, self.inst_start, self.inst_count = order, start[good], count[good]

    def __len__(self) -> int:
        return len(self.rows)

    def features(
        self,
        idx: np.ndarray,
        rng: np.random.Generator,
        augment: bool,
        geometry: bool = False,
        color_drop: float = COLOR_DROP,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Point features (B, 7, or 12 with `geometry`), context (B, M, 6) and mask (B, M) of samples `idx`."""
        rows = self.rows[idx]
        pos = self.positions[rows]
        pf = np.zeros((len(idx), POINT_DIM), np.float32)
        pf[:, 0:2] = pos[:, 0:2] - self.origin[idx, 0:2]
        pf[:, 2] = pos[:, 2] - self.floor[idx]
        pf[:, 3:6] = self.colors[rows] - 0.5
        pf[:, 6] = 1.0
        ctx_rows = self.context[idx]
        mask = ctx_rows >= 0
        safe = np.where(mask, ctx_rows, rows[:, None])
        ctx = np.zeros((*ctx_rows.shape, CONTEXT_DIM), np.float32)
        ctx[..., 0:3] = self.positions[safe] - pos[:, None, :]
        ctx[..., 3:6] = self.colors[safe] - self.colors[rows][:, None, :]
        if geometry:  # local shape, from the same context (turning about z changes none of it)
            pf = with_geometry(pf, ctx, mask)
        if augment:
            angle = rng.uniform(0, 2 * np.pi, len(idx)).astype(np.float32)
            c, s = np.cos(angle), np.sin(angle)
            x, y = pf[:, 0].copy(), pf[:, 1].copy()
            pf[:, 0], pf[:, 1] = c * x - s * y, s * x + c * y
            x, y = ctx[..., 0].copy(), ctx[..., 1].copy()
            ctx[..., 0], ctx[..., 1] = c[:, None] * x - s[:, None] * y, s[:, None] * x + c[:, None] * y
            drop = rng.random(len(idx)) < color_drop
            pf[drop, 3:7] = 0.0
            ctx[drop, :, 3:6] = 0.0
        return pf, ctx, mask

    def instance_batch(self, rng: np.random.Generator) -> np.ndarray:
        """16 instances x 16 points (with replacement where an instance has fewer), as sample indices."""
        pick = rng.choice(len(self.inst_start), size=min(BATCH_INSTANCES, len(self.inst_start)), replace=False)
        offs = (rng.random((len(pick), POINTS_PER_INSTANCE)) * self.inst_count[pick, None]).astype(np.int64)
        return self.inst_order[self.inst_start[pick, None] + offs].ravel()


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


def train_mcpnet(
    pool: Pool,
    cfg: NetConfig,
    epochs: int,
    seed: int,
    log: bool = True,
    color_drop: float = COLOR_DROP,
    checkpoint: Callable[[MCPNet, dict], None] | None = None,
    init: MCPNet | None = None,
    learning_rate: float = LEARNING_RATE,
) -> tuple[MCPNet, dict]:
    """Adam on triplet + cross-entropy; an epoch is as many batches as it takes to see every point once.
    `init` starts from a trained network (see `widen`) instead of from random weights."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = MCPNet(cfg)
    if init is not None:
        model.load_state_dict(widen(init, cfg).state_dict())
    opt = torch.optim.Adam(model.parameters(), lr=learning_rate)
    batch = BATCH_INSTANCES * POINTS_PER_INSTANCE
    steps = max(1, len(pool) // batch)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs * steps, eta_min=learning_rate / 20)
    ce = nn.CrossEntropyLoss()
    use_ctx = cfg.kind == "mcpnet"
    history = []
    start = time.perf_counter()
    for epoch in range(epochs):
        tot_t = tot_c = acc = 0.0
        for _ in range(steps):
            inst_idx = pool.instance_batch(rng)
            uni_idx = rng.integers(0, len(pool), UNIFORM_POINTS)  # class frequencies as the stream sees them
            idx = np.concatenate([inst_idx, uni_idx])
            pf, ctx, mask = pool.features(idx, rng, augment=True, geometry=cfg.geometry, color_drop=color_drop)
            emb, logits = model(
                torch.from_numpy(pf),
                torch.from_numpy(ctx) if use_ctx else None,
                torch.from_numpy(mask) if use_ctx else None,
            )
            labels = torch.from_numpy(pool.sample_class[idx])
            inst = torch.from_numpy(pool.sample_instance[inst_idx])
            lt = semihard_triplet_loss(emb[: len(inst_idx)], inst)
            lc = ce(logits, labels)
            opt.zero_grad()
            (lt + lc).backward()
            opt.step()
            sched.step()
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


def widen(trained: MCPNet, cfg: NetConfig) -> MCPNet:
    """A network of `cfg` (more point features appended) that computes what `trained` computed: the weights
    of the new inputs start at zero, every other weight is copied."""
    model = MCPNet(cfg)
    state = trained.state_dict()
    new = model.state_dict()
    for key, value in state.items():
        if new[key].shape == value.shape:
            new[key] = value.clone()
        else:  # the first layer of point_mlp: [context, point features], the added features at the end
            grown = torch.zeros_like(new[key])
            grown[:, : value.shape[1]] = value
            new[key] = grown
    model.load_state_dict(new)
    return model


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
            opt.zero_grad()
            (lt + lc).backward()
            opt.step()
            sched.step()
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


def stage_uris(uris: Iterable[str], cfg: NetConfig, log: bool = True) -> list[Mission]:
    """Staged missions of simulator URIs."""
    missions = []
    for uri in uris:
        t0 = time.perf_counter()
        missions.append(stage_mission(open_uri(uri), cfg))
        if log:
            m = missions[-1]
            print(
                f"staged {uri}: {len(m.rows)} points, {len(m.positions)} voxels ({time.perf_counter() - t0:.1f} s)",
                file=sys.stderr,
                flush=True,
            )
    return missions


KINDS: Final[tuple[str, ...]] = ("mcpnet", "mcpnet-nocontext", "pointnet")


def transfer_config() -> NetConfig:
    """The transfer candidate's configuration (#12): the point features followed by the geometry features."""
    features = POINT_FEATURES + GEOMETRY_FEATURES
    return NetConfig(kind="mcpnet", point_dim=len(features), features=features)


def train(
    out: Path | None = None,
    seed: int = 0,
    epochs: int | None = None,
    force: bool = False,
    kinds: tuple[str, ...] = KINDS,
) -> dict[str, Any]:
    """Stage the training missions, train MCPNet, MCPNet without context and PointNet, write their weights
    (the shipped ones: plain missions of both families).

    `out` is the MCPNet weights file (default models/weights/mcpnet.pt); the baselines go beside it.
    `kinds` limits which networks are trained.
    """
    torch.set_num_threads(1)  # on a shared 2-core machine a second intra-op thread mostly waits
    out = Path(out) if out is not None else WEIGHTS_DIR / "mcpnet.pt"
    paths = {
        "mcpnet": out,
        "mcpnet-nocontext": out.with_name(out.stem + "_nocontext.pt"),
        "pointnet": out.with_name("pointnet.pt") if out.stem == "mcpnet" else out.with_name(out.stem + "_pointnet.pt"),
    }
    paths = {k: p for k, p in paths.items() if k in kinds}
    for p in paths.values():
        if p.exists() and not force:
            raise OutputError("weights file exists; pass --force to overwrite", p)
    pointnet_epochs = POINTNET_EPOCHS if epochs is None else epochs
    epochs = EPOCHS if epochs is None else epochs
    start = time.perf_counter()
    base = NetConfig()
    missions = stage_all(TRAIN_SEEDS, TRAIN_SCANS, base)
    pool = Pool(missions)
    figures: dict[str, Any] = {
        "train_seeds": list(TRAIN_SEEDS),
        "families": list(FAMILIES),
        "sensor": SENSOR,
        "scans_per_mission": TRAIN_SCANS,
        "training_points": len(pool),
        "epochs": epochs,
        "pointnet_epochs": pointnet_epochs,
        "range_m": base.range_m,
        "seed": seed,
        "staging_seconds": round(time.perf_counter() - start, 1),
    }
    for kind in ("mcpnet", "mcpnet-nocontext"):
        if kind not in kinds:
            continue
        cfg = NetConfig(kind=kind)
        model, fig = train_mcpnet(pool, cfg, epochs, seed)
        fig["parameters"] = num_parameters(model)
        save_weights(paths[kind], model, cfg, {**figures, **fig})
        figures[kind] = {k: v for k, v in fig.items() if k != "history"} | {"final": fig["history"][-1]}
    if "pointnet" in kinds:
        cfg = NetConfig(kind="pointnet")
        model, fig = train_pointnet(missions, cfg, pointnet_epochs, seed)
        fig["parameters"] = num_parameters(model)
        save_weights(paths["pointnet"], model, cfg, {**figures, **fig})
        figures["pointnet"] = {k: v for k, v in fig.items() if k != "history"} | {"final": fig["history"][-1]}
    figures["weights"] = {k: str(p) for k, p in paths.items()}
    figures["sizes_bytes"] = {k: p.stat().st_size for k, p in paths.items()}
    figures["total_seconds"] = round(time.perf_counter() - start, 1)
    return figures


def train_transfer(
    out: Path | None = None,
    seed: int = 0,
    epochs: int | None = None,
    force: bool = False,
    init: Path | None = None,
) -> dict[str, Any]:
    """The transfer candidate (#12, not shipped: it lost to the shipped MCPNet on validation, see README):
    the families' MCPNet (`init`, default the shipped models/weights/mcpnet.pt, which `train` makes) widened
    by the geometry features and fine-tuned on randomised missions of the training generators, colour dropped
    for half the points. Writes models/weights/mcpnet_transfer.pt unless `out` says otherwise; run it with
    `--set label.weights=...`."""
    from aftershock.models.mcpnet import load_model

    torch.set_num_threads(1)
    out = Path(out) if out is not None else WEIGHTS_DIR / "mcpnet_transfer.pt"
    if out.exists() and not force:
        raise OutputError("weights file exists; pass --force to overwrite", out)
    init = Path(init) if init is not None else WEIGHTS_DIR / "mcpnet.pt"
    first, first_cfg, _ = load_model(init, kind="mcpnet")
    epochs = TRANSFER_EPOCHS if epochs is None else epochs
    start = time.perf_counter()
    uris = transfer_uris(TRANSFER_SEEDS, TRANSFER_SCANS)
    pool = Pool(stage_uris(uris, NetConfig()))
    recipe = {
        "train_seeds": sorted(set(TRAIN_SEEDS) | set(TRANSFER_SEEDS)),
        "generators": list(split.TRAIN_GENERATORS),
        "held_out_generator": split.HELDOUT_GENERATOR,
        "missions": uris,
        "scans_per_mission": TRANSFER_SCANS,
        "color_drop": TRANSFER_COLOR_DROP,
        "init": init.name,
        "fine_tune_epochs": epochs,
        "training_points": len(pool),
        "range_m": first_cfg.range_m,
        "seed": seed,
        "staging_seconds": round(time.perf_counter() - start, 1),
    }
    cfg = transfer_config()
    model, fig = train_mcpnet(
        pool,
        cfg,
        epochs,
        seed,
        color_drop=TRANSFER_COLOR_DROP,
        init=first,
        learning_rate=TRANSFER_LEARNING_RATE,
    )
    fig["parameters"] = num_parameters(model)
    save_weights(out, model, cfg, {**recipe, **fig})
    return (
        recipe
        | {k: v for k, v in fig.items() if k != "history"}
        | {
            "weights": str(out),
            "size_bytes": out.stat().st_size,
            "total_seconds": round(time.perf_counter() - start, 1),
        }
    )
