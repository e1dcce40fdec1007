"""Train CrackEmbed on simulated cracked concrete (never on the evaluation masks): `aftershock train crackembed`.

Each training element is a column corner (two concrete faces meeting at an edge, randomly oriented) scanned
in lines at a random spacing, with cracks (recessed, darker polylines 2–40 mm wide) and spalls (rough dark
blobs). Every face, crack and spall is its own surface; a triplet loss pulls points of one surface together
and pushes different surfaces apart. The crack labels of the simulation are used only as surface identities.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Final

import numpy as np
import torch

from models.crackembed import WEIGHTS, CrackEmbed, point_inputs, save_weights
from pipeline.cloud_io import check_output

EPOCHS: Final = 30
STEPS_PER_EPOCH: Final = 20
ELEMENTS: Final = 40
SURFACES_PER_BATCH: Final = 16
POINTS_PER_SURFACE: Final = 16
MARGIN: Final = 1.0  # on squared distances between unit vectors (0..4), as the study's triplet loss
NEIGHBOURHOOD_M: Final = 0.01


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (N,) from 2-D points to the nearest of the segments a→b (S, 2)."""
    ab = b - a
    t = np.clip(((p[:, None, :] - a[None]) * ab[None]).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0, 1)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - closest, axis=-1).min(axis=1)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def cracked_corner(rng: np.random.Generator, spacing_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points (N, 3), colours (N, 3) uint8, surface ids (N,) and crack mask (N,) of one simulated element."""
    width, height = rng.uniform(0.3, 0.5), rng.uniform(0.4, 0.7)
    line = spacing_m * rng.uniform(1.0, 3.0)  # scan-line spacing
    base = np.array([0.85, 0.8, 0.7]) * rng.uniform(0.6, 1.1) + rng.normal(0, 0.04, 3)
    pts_all, col_all, sid_all, crack_all = [], [], [], []
    next_id = 0
    for face in range(2):
        u, v = np.meshgrid(np.arange(0, width, spacing_m), np.arange(0, height, line), indexing="ij")
        uv = np.stack([u.ravel(), v.ravel()], axis=1) + rng.normal(0, 0.2 * spacing_m, (u.size, 2))
        depth = rng.normal(0, 0.0008, len(uv))  # range noise
        shade = rng.uniform(0.8, 1.1) * (1 + 0.15 * (uv[:, 1] / height - 0.5) * rng.normal())
        rgb = base[None] * shade[:, None] + rng.normal(0, 0.03, (len(uv), 3))
        sid = np.full(len(uv), next_id)
        next_id += 1
        crack = np.zeros(len(uv), bool)
        for _ in range(rng.integers(1, 4)):  # cracks: random-walk polylines
            n_seg = 8
            start = rng.uniform([0, 0], [width, height])
            heading = rng.uniform(0, 2 * np.pi) + np.cumsum(rng.normal(0, 0.4, n_seg))
            step = rng.uniform(0.1, 0.6) / n_seg
            nodes = start + np.cumsum(np.c_[np.cos(heading), np.sin(heading)] * step, axis=0)
            nodes = np.vstack([start, nodes])
            w = rng.uniform(0.002, 0.04)
            hit = _segment_distance(uv, nodes[:-1], nodes[1:]) <= max(w / 2, 0.5 * spacing_m)
            depth[hit] -= rng.uniform(0.003, 0.03) * rng.uniform(0.3, 1.0, hit.sum())
            rgb[hit] *= rng.uniform(0.35, 0.75)
            rgb[hit] += rng.normal(0, 0.06, (hit.sum(), 3))
            sid[hit] = next_id
            next_id += 1
            crack |= hit
        if rng.random() < 0.5:  # a spall: rough, darker, browner blob
            centre, radius = rng.uniform([0, 0], [width, height]), rng.uniform(0.02, 0.08)
            hit = np.linalg.norm(uv - centre, axis=1) < radius
            depth[hit] -= rng.uniform(0.0, 0.02, hit.sum())
            rgb[hit] *= rng.uniform(0.4, 0.8) * np.array([1.0, 0.9, 0.8])
            sid[hit] = next_id
            next_id += 1
            crack |= hit
        if face == 0:  # x = depth, y = u, z = v; the second face turns about the shared edge
            pts = np.stack([-depth, uv[:, 0], uv[:, 1]], axis=1)
        else:
            pts = np.stack([uv[:, 0], -depth, uv[:, 1]], axis=1)
        pts_all.append(pts)
        col_all.append(rgb)
        sid_all.append(sid)
        crack_all.append(crack)
    pts = np.concatenate(pts_all) @ _random_rotation(rng).T
    colors = (np.clip(np.concatenate(col_all), 0, 1) * 255).astype(np.uint8)
    return pts, colors, np.concatenate(sid_all), np.concatenate(crack_all)


def _batch_all_triplet(emb: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Mean of the positive parts of all valid triplets (anchor, positive, negative) in the batch."""
    d = torch.cdist(emb, emb).pow(2)
    same = labels[:, None] == labels[None, :]
    eye = torch.eye(len(labels), dtype=torch.bool)
    pos = same & ~eye
    neg = ~same
    loss = d[:, :, None] - d[:, None, :] + MARGIN  # [a, p, n]
    valid = pos[:, :, None] & neg[:, None, :]
    vals = torch.relu(loss[valid])
    active = (vals > 1e-9).sum().clamp(min=1)
    return vals.sum() / active


def build_data(seed: int, elements: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Network inputs and global surface ids of all points of `elements` simulated elements."""
    rng = np.random.default_rng(seed)
    nbs, owns, sids = [], [], []
    offset = 0
    for _ in range(elements):  # one iteration per simulated element
        spacing = float(rng.uniform(0.002, 0.01))
        pts, colors, sid, _ = cracked_corner(rng, spacing)
        nb, own = point_inputs(pts, colors, NEIGHBOURHOOD_M, spacing)
        nbs.append(nb)
        owns.append(own)
        sids.append(sid + offset)
        offset += int(sid.max()) + 1
    return np.concatenate(nbs), np.concatenate(owns), np.concatenate(sids)


def train(out: Path | None = None, seed: int = 0, epochs: int | None = None, force: bool = False) -> dict:
    """Train on simulated elements and write the weights; returns the training figures."""
    path = Path(out) if out is not None else WEIGHTS
    check_output(path, force)
    torch.manual_seed(seed)
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    nb, own, sid = build_data(seed, ELEMENTS)
    uniq, inverse, counts = np.unique(sid, return_inverse=True, return_counts=True)
    usable = np.flatnonzero(counts >= 4)
    members = np.split(np.argsort(inverse, kind="stable"), np.cumsum(counts)[:-1])
    model = CrackEmbed()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    rng = np.random.default_rng(seed + 1)
    losses: list[float] = []
    n_epochs = epochs if epochs is not None else EPOCHS
    for _ in range(n_epochs):
        epoch_loss = 0.0
        for _ in range(STEPS_PER_EPOCH):
            chosen = rng.choice(usable, size=min(SURFACES_PER_BATCH, len(usable)), replace=False)
            idx = np.concatenate([rng.choice(members[s], size=POINTS_PER_SURFACE) for s in chosen])
            emb = model(torch.from_numpy(nb[idx]), torch.from_numpy(own[idx]))
            loss = _batch_all_triplet(emb, torch.from_numpy(inverse[idx]))
            opt.zero_grad()
            loss.backward()
            opt.step()
            epoch_loss += float(loss.detach())
        losses.append(epoch_loss / STEPS_PER_EPOCH)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {"seed": seed, "epochs": n_epochs, "elements": ELEMENTS, "points": len(sid), "surfaces": len(uniq)}
    save_weights(model, path, meta)
    return {
        "weights": str(path),
        "points": len(sid),
        "surfaces": len(uniq),
        "epochs": n_epochs,
        "first_loss": round(losses[0], 4),
        "final_loss": round(losses[-1], 4),
        "parameters": sum(p.numel() for p in model.parameters()),
        "seconds": round(time.perf_counter() - t0, 1),
    }
