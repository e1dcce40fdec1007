"""The #28 round: the colour-free MCPNet with and without the structure model's evidence, one recipe for both.

The training missions are staged once, with a structure model beside the voxel map (so every point carries the
evidence it had when its voxel opened); then two children of this process train the two networks side by side
from that one pool (the same seeds, batches and epochs: only the inputs differ), into OUT/old.pt and OUT/new.pt.

    python -m aftershock.models.structure_round_train OUT [--epochs N] [--seed S] [--scans N]

Which weights ship is decided on validation missions afterwards (docs/decisions.md, round S1).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
from pathlib import Path
from typing import Any

from aftershock.models import mcpnet_train as mt
from aftershock.models import transfer_split as split
from aftershock.models.mcpnet import num_parameters, save_weights


def _train_one(pool: mt.Pool, structure: bool, epochs: int, seed: int, path: Path, recipe: dict[str, Any]) -> None:
    import torch

    torch.set_num_threads(1)
    cfg = mt.mcpnet_config(structure)
    rec = {**recipe, "structure_features": structure, "epochs": epochs}
    partial = path.with_suffix(".partial.pt")
    model, fig = mt.train_transfer(pool, cfg, epochs, seed, lambda m, f: save_weights(partial, m, cfg, {**rec, **f}))
    fig["parameters"] = num_parameters(model)
    save_weights(path, model, cfg, {**rec, **fig})
    partial.unlink(missing_ok=True)


def run(
    out: Path, epochs: int, seed: int = 0, scans: int = mt.TRANSFER_SCANS, seeds: tuple[int, ...] = mt.TRAIN_SEEDS
) -> None:
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    uris = mt.transfer_uris(seeds, scans, split.TRAIN_GENERATORS)
    pool = mt.Pool(mt.stage_uris(uris, mt.mcpnet_config(True), structure=True))
    recipe = {
        "train_seeds": list(seeds),
        "generators": list(split.TRAIN_GENERATORS),
        "held_out_generator": split.HELDOUT_GENERATOR,
        "missions": uris,
        "scans_per_mission": scans,
        "color_drop_per_mission": mt.TRANSFER_COLOR_DROP,
        "crop_batches": mt.TRANSFER_CROP_BATCHES,
        "affinity_weight": mt.TRANSFER_AFFINITY_WEIGHT,
        "training_points": len(pool),
        "seed": seed,
        "staging_seconds": round(time.perf_counter() - t0, 1),
    }
    print(f"staged {len(pool)} points in {recipe['staging_seconds']} s", file=sys.stderr, flush=True)
    ctx = mp.get_context("fork")  # the children share the staged pool
    jobs = [
        ctx.Process(target=_train_one, args=(pool, s, epochs, seed, out / name, recipe))
        for s, name in ((False, "old.pt"), (True, "new.pt"))
    ]
    for j in jobs:
        j.start()
    for j in jobs:
        j.join()
    codes = [j.exitcode for j in jobs]
    print(f"done in {time.perf_counter() - t0:.0f} s, exit codes {codes}", file=sys.stderr, flush=True)
    if any(codes):
        raise SystemExit(1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--epochs", type=int, default=mt.TRANSFER_EPOCHS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scans", type=int, default=mt.TRANSFER_SCANS)
    ap.add_argument("--train-seeds", type=int, default=len(mt.TRAIN_SEEDS), help="the first N training seeds")
    a = ap.parse_args()
    run(a.out, a.epochs, a.seed, a.scans, mt.TRAIN_SEEDS[: a.train_seeds])


if __name__ == "__main__":
    main()
