"""Replay the structure model over a mission's map, to choose its settings without rerunning the networks.

    python tests/bench/structure_replay.py dump "sim://office?seed=800&sensor=vlp16&..." office800.npz
    python tests/bench/structure_replay.py replay office800.npz [structure.key=value ...]

`dump` runs the stream once (networks and structure model) and keeps, per map voxel, its position, true class,
the network's class and score when it opened, the sensor's pose then, and the final classes. `replay` feeds those
voxels scan by scan into a fresh StructureModel (the current code, the given settings), scores the classes it
decides where it has a say (the network's final labels elsewhere) and prints column, beam, wall and floor IoU
with the columns and beams found. The networks' labels are those of the dumped run, so a replay reproduces the
eval's figures closely, not exactly (the network's instance votes saw the dumped run's structure).
"""

from __future__ import annotations

import sys
from itertools import pairwise

import numpy as np

from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.config import Environment, load_config
from aftershock.pipeline.metrics import semantic_scores
from aftershock.pipeline.structure import Kind, StructureModel
from aftershock.pipeline.voxel_map import VoxelMap


def dump(source: str, out: str, overrides: list[str]) -> None:
    from aftershock.pipeline.commands.evaluate import evaluate_map
    from aftershock.pipeline.mission import build_config, open_scans
    from aftershock.pipeline.stream import run_stream

    cfg = build_config(None, overrides, None, None, None, None, None, None)
    scans, info = open_scans(source, cfg, True)
    res = run_stream(scans, cfg, [], info, lambda _t: None)
    v, m, n = res.vmap, res.structure, len(res.vmap)
    if m is None:
        raise SystemExit("the structure model is off (structure.enabled=false): nothing to dump")
    iou = evaluate_map(v)["per_class_iou"]
    print(source, {k: round(x, 3) for k, x in iou.items()})
    np.savez(
        out,
        pos=v.positions[:n], truth=v.true_class_ids[:n], final=v.class_ids[:n], seq=v.first_seq[:n],
        net=m.net_cls[:n], net_score=m.net_score[:n], sz=m.sensor_z[:n], origin=m.sight.origins[:n], fused=m.fused[:n],
        voxel=v.voxel_size,
    )  # fmt: skip


def replay(path: str, overrides: list[str]) -> None:
    d = np.load(path)
    cfg = load_config(None, overrides).structure
    vmap = VoxelMap(float(d["voxel"]))
    model = StructureModel(cfg, Environment.INDOOR, vmap.voxel_size)
    seq = d["seq"]
    bounds = np.r_[0, np.flatnonzero(np.diff(seq)) + 1, len(seq)]
    for a, b in pairwise(bounds):  # one iteration per scan
        vmap.insert(d["pos"][a:b])
        vmap.class_ids[a:b] = d["net"][a:b]
        vmap.scores[a:b] = d["net_score"][a:b]
        model.observe(vmap, d["origin"][a])
        model.update(vmap, float(d["sz"][a]))
    model.finish(vmap)
    n = len(vmap)
    network = np.where(d["fused"] == UNLABELLED, d["final"], d["net"])
    pred = np.where(model.fused[:n] != UNLABELLED, model.fused[:n], network)
    iou = semantic_scores(d["truth"], pred).per_class_iou
    kinds = [e.kind for e in model.elements(vmap, scans=False)]
    shown = " ".join(f"{k} {iou[k]:.3f}" if k in iou else f"{k} -" for k in ("column", "beam", "wall", "floor"))
    print(f"{path}: {shown}; columns {kinds.count(Kind.COLUMN)}, beams {kinds.count(Kind.BEAM)}")


if __name__ == "__main__":
    if len(sys.argv) >= 4 and sys.argv[1] == "dump":
        dump(sys.argv[2], sys.argv[3], sys.argv[4:])
    elif len(sys.argv) >= 3 and sys.argv[1] == "replay":
        replay(sys.argv[2], sys.argv[3:])
    else:
        raise SystemExit(__doc__)
