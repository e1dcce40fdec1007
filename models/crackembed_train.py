"""Train CrackEmbed on simulated cracked concrete (never on the evaluation masks): `aftershock train crackembed`.

Training elements are the simulator's cracked columns, walls, beams and slabs (`sources.simulator.cracks`: branching,
tapering cracks with spalled edges on bare or painted concrete with stains, dirt streaks, shade and occlusion;
seeds below 100; seeds from 100 on are kept for testing on unseen elements), each at a random spacing (1.5–5 mm;
slabs, evaluated on a 1 cm grid, 4–10 mm) and cropped to a 0.6 m window around one of its cracks. The
intact concrete (with its stains, streaks and pits) is one surface, each crack another; a triplet loss pulls
points of one surface together and pushes different surfaces apart. The simulation's crack marks serve only
as surface identities.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Final

import numpy as np
import torch

from aftershock.models.crackembed import WEIGHTS, CrackEmbed, point_inputs, save_weights
from aftershock.models.optimise import descend
from aftershock.pipeline.cloud_io import check_output
from aftershock.pipeline.damage.measure import components

EPOCHS: Final = 30
STEPS_PER_EPOCH: Final = 20
ELEMENTS: Final = 40
SURFACES_PER_BATCH: Final = 16
POINTS_PER_SURFACE: Final = 16
MARGIN: Final = 1.0  # on squared distances between unit vectors (0..4), as the study's triplet loss
NEIGHBOURHOOD_M: Final = 0.01
KINDS: Final = ("column", "wall", "slab", "beam")
SPACING_M: Final = {"column": (0.0015, 0.005), "wall": (0.0015, 0.005), "beam": (0.0015, 0.005), "slab": (0.004, 0.01)}
WINDOW_M: Final = 0.6  # each training element is cropped to a window this wide around one of its cracks
HELD_OUT_SEEDS: Final = 100  # element seeds from here on are never trained on: they test unseen elements


def training_element(seed: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Points, colours and surface ids (0 = intact concrete, stains and pits included; k = the k-th crack) of
    a simulated cracked element (seeds below `HELD_OUT_SEEDS`), cropped to a random window, and its spacing."""
    from aftershock.sources.simulator.cracks import cracked_element

    kind = KINDS[seed % len(KINDS)]
    spacing = float(rng.uniform(*SPACING_M[kind]))
    cloud, mask, _ = cracked_element(kind, seed, spacing)
    pts = cloud.points
    crack_pts = pts[mask] if mask.any() else pts
    centre = crack_pts[rng.integers(len(crack_pts))]
    keep = np.all(np.abs(pts - centre) <= WINDOW_M / 2, axis=1)
    assert cloud.colors is not None, "simulated elements are coloured"
    pts, colors, mask = pts[keep], cloud.colors[keep], mask[keep]
    sid = np.zeros(len(pts), np.int64)
    sid[mask] = components(pts[mask], max(3.0 * spacing, 0.01), 1)
    return pts, colors, sid, spacing


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


def build_data(seed: int, elements: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Network inputs and global surface ids of all points of `elements` simulated elements, and the ids of
    the intact surfaces."""
    rng = np.random.default_rng(seed)
    nbs, owns, sids, intact = [], [], [], []
    offset = 0
    for i in range(elements):  # one iteration per simulated element
        pts, colors, sid, spacing = training_element(seed * elements + i, rng)
        nb, own = point_inputs(pts, colors, NEIGHBOURHOOD_M, spacing)
        nbs.append(nb)
        owns.append(own)
        sids.append(sid + offset)
        intact.append(offset)
        offset += int(sid.max()) + 1
    return np.concatenate(nbs), np.concatenate(owns), np.concatenate(sids), np.asarray(intact)


def train(out: Path | None = None, seed: int = 0, epochs: int | None = None, force: bool = False) -> dict:
    """Train on simulated elements and write the weights; returns the training figures."""
    path = Path(out) if out is not None else WEIGHTS
    check_output(path, force)
    torch.manual_seed(seed)
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    nb, own, sid, intact_ids = build_data(seed, ELEMENTS)
    uniq, inverse, counts = np.unique(sid, return_inverse=True, return_counts=True)
    usable = counts >= 4
    is_intact = np.isin(uniq, intact_ids)
    intact, cracks = np.flatnonzero(usable & is_intact), np.flatnonzero(usable & ~is_intact)
    members = np.split(np.argsort(inverse, kind="stable"), np.cumsum(counts)[:-1])
    model = CrackEmbed()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    rng = np.random.default_rng(seed + 1)
    losses: list[float] = []
    n_epochs = epochs if epochs is not None else EPOCHS
    for _ in range(n_epochs):
        epoch_loss = 0.0
        for _ in range(STEPS_PER_EPOCH):
            # A quarter of each batch is intact concrete (one surface per element, far rarer than cracks).
            n_intact = min(SURFACES_PER_BATCH // 4, len(intact))
            chosen = np.r_[
                rng.choice(intact, size=n_intact, replace=False),
                rng.choice(cracks, size=min(SURFACES_PER_BATCH - n_intact, len(cracks)), replace=False),
            ]
            idx = np.concatenate([rng.choice(members[s], size=POINTS_PER_SURFACE) for s in chosen])
            emb = model(torch.from_numpy(nb[idx]), torch.from_numpy(own[idx]))
            loss = _batch_all_triplet(emb, torch.from_numpy(inverse[idx]))
            descend(opt, loss)
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
