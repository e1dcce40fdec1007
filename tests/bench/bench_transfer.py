"""Transfer benchmark (slow; `make bench-transfer`): the learned methods in-family and on a scene generator that
stayed out of all training and all choice of settings (`wing`, see models/transfer_split.py), with and without
colour, side by side with their baselines.

- MCPNet, MCPNet without context, PointNet (single scan) and normal + colour region growing, each streamed
  over the same missions (VLP-16 at 1.0 m on a wheeled robot, 1 m/s, 45 deg/s): OA, mean IoU, NMI, ARI,
  instance precision / recall, and per-class IoU, per generator and colour mode.
- LRGNet and its classical baselines on rooms cut from held-out buildings of the training generators and of
  `wing`, with and without colour: NMI / AMI / ARI / precision / recall (TRANSFER_LRGNET_WEIGHTS: other weights,
  TRANSFER_LRGNET_SETTINGS: other inference settings).

TRANSFER_SCANS (default 100) sets the mission length; TRANSFER_SEEDS (default 900,901) the test seeds;
TRANSFER_METHODS (default all) the online methods. `test_validation_choice` (run alone with -k) is how a
retrained MCPNet is chosen: candidate weights (TRANSFER_CANDIDATE) against the shipped ones on validation
seeds of the training generators only; the held-out generator and the test seeds play no part in it
(TRANSFER_VALIDATION_COLOR=0: the colour-free missions only; TRANSFER_VALIDATION_SCANS: their length).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Final

import numpy as np
import pytest
from common import pickle_scans, stream_labeller

from aftershock.models.transfer_split import (
    FAMILIES,
    HELDOUT_GENERATOR,
    TEST_SEEDS,
    TRAIN_GENERATORS,
    VALIDATION_SEEDS,
    bench_uri,
)
from aftershock.pipeline.classes import CLASS_NAMES

pytestmark = pytest.mark.timeout(7200)

SCANS: Final = int(os.environ.get("TRANSFER_SCANS", "100"))
SEEDS: Final = tuple(int(s) for s in os.environ.get("TRANSFER_SEEDS", "").split(",") if s) or TEST_SEEDS
METHODS: Final = tuple(
    m for m in os.environ.get("TRANSFER_METHODS", "mcpnet,mcpnet-nocontext,pointnet,region-growing").split(",") if m
)
# in-family = the generators any shipped weights were trained on; the hall joined training with #12
GENERATORS: Final = (*dict.fromkeys((*FAMILIES, *TRAIN_GENERATORS)), HELDOUT_GENERATOR)
KEYS: Final = ("overall_accuracy", "mean_iou", "nmi", "ari", "precision", "recall")
LRG_ROOMS: Final = 4
LRG_KEYS: Final = ("nmi", "ami", "ari", "precision", "recall")


@pytest.fixture(scope="module")
def missions(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, bool], list[Path]]:
    """Pickled scans of every (generator, colour) mission, simulated once."""

    assert not set(SEEDS) & set(range(100, 900)), "test seeds only"
    root = tmp_path_factory.mktemp("transfer")
    out: dict[tuple[str, bool], list[Path]] = {}
    for gen in GENERATORS:
        for color in (True, False):
            paths = []
            for seed in SEEDS:
                path = root / f"{gen}_{seed}_{'rgb' if color else 'mono'}.pkl"
                paths.append(pickle_scans(bench_uri(gen, seed, SCANS, color), path))
            out[(gen, color)] = paths
    return out


def _pooled(reps: list[dict[str, Any]]) -> dict[str, Any]:
    """Means over missions (overall accuracy weighted by points), per-class IoU averaged where present."""
    pts = np.array([r["evaluated_points"] for r in reps], float)
    out: dict[str, Any] = {k: float(np.mean([r[k] for r in reps])) for k in KEYS}
    out["overall_accuracy"] = float(
        np.sum([r["overall_accuracy"] * p for r, p in zip(reps, pts, strict=True)]) / pts.sum()
    )
    per: dict[str, list[float]] = {}
    for r in reps:
        for name, v in r["per_class_iou"].items():
            per.setdefault(name, []).append(v)
    out["per_class_iou"] = {k: float(np.mean(v)) for k, v in per.items()}
    out["label_ms"] = float(np.mean([r["timings"]["label"] for r in reps]))
    out["predicted_instances"] = float(np.mean([r["predicted_instances"] for r in reps]))
    out["true_instances"] = float(np.mean([r["true_instances"] for r in reps]))
    return out


def _overrides(method: str) -> list[str]:
    """TRANSFER_MCPNET_WEIGHTS measures other MCPNet weights than the shipped ones (e.g. a rejected candidate)."""
    weights = os.environ.get("TRANSFER_MCPNET_WEIGHTS")
    return [f"label.weights={weights}"] if weights and method == "mcpnet" else []


def test_mcpnet_transfer(missions: dict[tuple[str, bool], list[Path]]) -> None:
    table: dict[str, dict[tuple[str, bool], dict[str, Any]]] = {}
    for method in METHODS:
        table[method] = {}
        for key, paths in missions.items():
            table[method][key] = _pooled([stream_labeller(p, method, _overrides(method)) for p in paths])
            r = table[method][key]
            print(
                f"  {method:16s} {key[0]:9s} {'rgb ' if key[1] else 'mono'} OA {r['overall_accuracy'] * 100:5.1f} "
                f"mIoU {r['mean_iou'] * 100:5.1f} NMI {r['nmi'] * 100:5.1f} ARI {r['ari'] * 100:5.1f} "
                f"label {r['label_ms']:.1f} ms",
                flush=True,
            )
    seeds = ", ".join(map(str, SEEDS))
    print(f"\nmissions: seeds {seeds}, {SCANS} scans, {bench_uri('GEN', 0, SCANS).split('&', 3)[-1]}")
    print(f"held-out generator: {HELDOUT_GENERATOR} (never trained on, never used to choose a setting)")
    cols = [(g, c) for c in (True, False) for g in GENERATORS]
    print("\n| method | " + " | ".join(f"{g} {'rgb' if c else 'no colour'}" for g, c in cols) + " |")
    print("|---|" + "---|" * len(cols))
    for method, row in table.items():
        cells = [
            f"{row[k]['overall_accuracy'] * 100:.1f} / {row[k]['mean_iou'] * 100:.1f} / {row[k]['nmi'] * 100:.1f} / "
            f"{row[k]['ari'] * 100:.1f}"
            for k in cols
        ]
        print(f"| {method} | " + " | ".join(cells) + " |")
    print("(cells: overall accuracy / mean IoU / NMI / ARI, %)")
    for method in [m for m in ("mcpnet", "region-growing") if m in table]:
        print(f"\nper-class IoU, {method} (%)")
        print("| generator | colour | " + " | ".join(CLASS_NAMES) + " |")
        print("|---|---|" + "---|" * len(CLASS_NAMES))
        for g, c in cols:
            per = table[method][(g, c)]["per_class_iou"]
            cells = [f"{per[n] * 100:.0f}" if n in per else "–" for n in CLASS_NAMES]
            print(f"| {g} | {'rgb' if c else 'no'} | " + " | ".join(cells) + " |")
    if "mcpnet" not in table:
        return
    print("\ninstances shown / true, instance precision / recall at IoU 0.5 (mcpnet)")
    for g, c in cols:
        r = table["mcpnet"][(g, c)]
        print(
            f"  {g:9s} {'rgb ' if c else 'mono'} {r['predicted_instances']:.0f} / {r['true_instances']:.0f}, "
            f"P {r['precision']:.3f} R {r['recall']:.3f}"
        )
    m = table["mcpnet"][(HELDOUT_GENERATOR, False)]
    fam = [table["mcpnet"][(g, True)]["mean_iou"] for g in FAMILIES]
    checks = {
        "held-out, no colour: OA >= 85 %": m["overall_accuracy"] >= 0.85,
        "held-out, no colour: mean IoU >= 55 %": m["mean_iou"] >= 0.55,
        "held-out, no colour: NMI >= 0.80": m["nmi"] >= 0.80,
        "held-out, no colour: ARI >= 0.6": m["ari"] >= 0.6,
        "held-out, colour at least as good as without": table["mcpnet"][(HELDOUT_GENERATOR, True)]["mean_iou"]
        >= m["mean_iou"],
        "families (colour): mean IoU >= 0.61": float(np.mean(fam)) >= 0.61,
        "held-out, no colour: objects shown <= 2x true": m["predicted_instances"] <= 2 * m["true_instances"],
        "held-out, no colour: instance precision >= 0.5": m["precision"] >= 0.5,
        "held-out, no colour: instance recall >= 0.6": m["recall"] >= 0.6,
    }
    print("\ntargets:")
    for name, ok in checks.items():
        print(f"  {'met ' if ok else 'MISSED'} {name}")
    # The benchmark reports; it fails only if MCPNet does not beat the classical baseline on its own ground.
    if "region-growing" in table:
        assert all(
            table["mcpnet"][(g, True)]["mean_iou"] > table["region-growing"][(g, True)]["mean_iou"] for g in FAMILIES
        )


def test_validation_choice(tmp_path: Path) -> None:
    """Candidate MCPNet weights (TRANSFER_CANDIDATE, comma-separated) against the shipped ones (or
    TRANSFER_SHIPPED) on validation missions of the training generators."""

    candidates = [c for c in os.environ.get("TRANSFER_CANDIDATE", "").split(",") if c]
    if not candidates:
        pytest.skip("set TRANSFER_CANDIDATE=weights.pt[,other.pt]")
    scans = int(os.environ.get("TRANSFER_VALIDATION_SCANS", "60"))
    shipped = os.environ.get("TRANSFER_SHIPPED")
    # TRANSFER_VALIDATION_COLOR=0: the colour-free missions only (what judges the colour-free network)
    colors = (True, False) if os.environ.get("TRANSFER_VALIDATION_COLOR", "1") != "0" else (False,)
    # TRANSFER_VALIDATION_GENERATORS: training generators whose validation missions judge (never the held-out one)
    gens = tuple(os.environ.get("TRANSFER_VALIDATION_GENERATORS", ",".join(TRAIN_GENERATORS)).split(","))
    if HELDOUT_GENERATOR in gens:
        raise ValueError(f"TRANSFER_VALIDATION_GENERATORS: {HELDOUT_GENERATOR} is the held-out generator")
    weights = {"shipped": [f"label.weights={shipped}"] if shipped else []}
    weights |= {Path(c).stem: [f"label.weights={c}"] for c in candidates}
    rows: dict[str, dict[tuple[str, bool], dict[str, Any]]] = {name: {} for name in weights}
    for gen in gens:
        for color in colors:
            paths = []
            for seed in VALIDATION_SEEDS[:1]:
                paths.append(pickle_scans(bench_uri(gen, seed, scans, color), tmp_path / f"{gen}_{seed}_{color}.pkl"))
            for name, overrides in weights.items():
                rows[name][(gen, color)] = r = _pooled([stream_labeller(p, "mcpnet", overrides) for p in paths])
                print(
                    f"  validation {name:9s} {gen:9s} {'rgb ' if color else 'mono'} "
                    f"OA {r['overall_accuracy'] * 100:5.1f} mIoU {r['mean_iou'] * 100:5.1f} "
                    f"NMI {r['nmi'] * 100:5.1f} ARI {r['ari'] * 100:5.1f}",
                    flush=True,
                )
    score, family, mono = {}, {}, {}
    for name, row in rows.items():
        m = {k: float(np.mean([r[k] for r in row.values()])) for k in ("overall_accuracy", "mean_iou", "nmi", "ari")}
        print(f"validation mean, {name}: " + ", ".join(f"{k} {v * 100:.1f}" for k, v in m.items()))
        # The ship rule, fixed before looking: (mean IoU + NMI) / 2 over the missions, colour-free and rgb alike,
        # and in-family with colour (office, disaster) at most 2 points of mean IoU below the shipped weights.
        score[name] = float(np.mean([(r["mean_iou"] + r["nmi"]) / 2 for r in row.values()]))
        family[name] = float(np.mean([row[(g, True)]["mean_iou"] for g in FAMILIES])) if True in colors else 0.0
        # Since the labeller picks a network per kind of log, the colour-free network is judged on the
        # colour-free missions alone: (mean IoU + NMI) / 2 over them (the rule of the 6-epoch run, fixed before it).
        mono[name] = float(np.mean([(row[(g, False)]["mean_iou"] + row[(g, False)]["nmi"]) / 2 for g in gens]))
        if set(gens) != set(TRAIN_GENERATORS):  # the shipped weights' own generators apart
            own = np.mean([(row[(g, False)]["mean_iou"] + row[(g, False)]["nmi"]) / 2 for g in TRAIN_GENERATORS])
            print(f"colour-free (mIoU + NMI) / 2 over {'+'.join(TRAIN_GENERATORS)}, {name}: {own * 100:.2f}")
        for (g, c), r in row.items():
            per = ", ".join(f"{n} {v * 100:.0f}" for n, v in r["per_class_iou"].items())
            print(f"  per-class IoU, {name} {g} {'rgb' if c else 'mono'}: {per}")
    for name in list(weights)[1:]:
        ok = score[name] > score["shipped"] and family[name] >= family["shipped"] - 0.02
        print(
            f"ship rule for logs without colour, {name}: (mIoU + NMI) / 2 over the colour-free missions "
            f"{mono[name] * 100:.2f} against {mono['shipped'] * 100:.2f} -> "
            f"{'ship' if mono[name] > mono['shipped'] else 'do not ship'}"
        )
        if True not in colors:
            continue
        print(
            f"ship rule, {name}: (mIoU + NMI) / 2 {score[name] * 100:.1f} against {score['shipped'] * 100:.1f}; "
            f"in-family rgb mIoU {family[name] * 100:.1f} against {family['shipped'] * 100:.1f} -> "
            f"{'ship' if ok else 'do not ship'}"
        )


def test_lrgnet_transfer() -> None:
    import torch

    from aftershock.models.lrgnet_train import GENERATORS, HELDOUT_SEEDS, building_rooms, without_color
    from aftershock.pipeline.config import LRGNetConfig
    from aftershock.pipeline.refine import WEIGHTS_DIR, baseline_cloud, load_network, refine_cloud, scores
    from aftershock.pipeline.refine.baselines import Baseline
    from aftershock.pipeline.refine.features import voxelise

    torch.set_num_threads(1)
    # TRANSFER_LRGNET_WEIGHTS measures other LRGNet weights than the shipped ones (e.g. a rejected candidate)
    weights = os.environ.get("TRANSFER_LRGNET_WEIGHTS") or str(WEIGHTS_DIR / "lrgnet.pt")
    # TRANSFER_LRGNET_SETTINGS ("key=value,...") measures other inference settings (e.g. crease_angle_deg=0)
    settings = dict(kv.split("=") for kv in os.environ.get("TRANSFER_LRGNET_SETTINGS", "").split(",") if kv)
    cfg = LRGNetConfig(weights=weights, **settings)
    net = load_network(cfg)
    domains = {g: [r for s in HELDOUT_SEEDS[g] for r in building_rooms(g, s)] for g in GENERATORS}
    domains[HELDOUT_GENERATOR] = [r for s in SEEDS for r in building_rooms(HELDOUT_GENERATOR, s)]
    rng = np.random.default_rng(0)
    domains = {k: [v[i] for i in sorted(rng.permutation(len(v))[:LRG_ROOMS])] for k, v in domains.items() if len(v)}
    baselines = [b for b in Baseline if b != Baseline.MCPNET]
    results: dict[str, dict[tuple[str, bool], dict[str, float]]] = {}
    for dom, rooms in domains.items():
        for color in (True, False):
            rs = rooms if color else [without_color(r) for r in rooms]
            rows = [scores(r.instance_ids, refine_cloud(r, cfg, net=net).instance_ids) for r in rs]
            results.setdefault("lrgnet", {})[(dom, color)] = {k: float(np.mean([x[k] for x in rows])) for k in LRG_KEYS}
            for b in baselines:
                rows = []
                for r in rs:
                    vc = voxelise(r, cfg.voxel_size_m, cfg.delta_m)
                    rows.append(scores(r.instance_ids, baseline_cloud(r, b, cfg, vc).instance_ids))
                results.setdefault(b.value, {})[(dom, color)] = {
                    k: float(np.mean([x[k] for x in rows])) for k in LRG_KEYS
                }
            lr = results["lrgnet"][(dom, color)]
            print(
                f"  lrgnet {dom:9s} {'rgb ' if color else 'mono'} AMI {lr['ami']:.3f} ARI {lr['ari']:.3f}", flush=True
            )
    cols = [(d, c) for c in (True, False) for d in domains]
    where = f"held-out buildings of lrgnet_train; {HELDOUT_GENERATOR}: seeds {', '.join(map(str, SEEDS))}"
    print(f"\nLRGNet weights {weights} {settings or 'default settings'}; rooms: {LRG_ROOMS} per domain ({where})")
    print("| method | " + " | ".join(f"{d} {'rgb' if c else 'no colour'}" for d, c in cols) + " |")
    print("|---|" + "---|" * len(cols))
    for name, row in results.items():
        cells = [" / ".join(f"{row[k][m]:.3f}" for m in LRG_KEYS) for k in cols]
        print(f"| {name} | " + " | ".join(cells) + " |")
    print("(cells: NMI / AMI / ARI / precision / recall)")
    m = results["lrgnet"][(HELDOUT_GENERATOR, False)]
    best = {
        k: max(v[(HELDOUT_GENERATOR, False)][k] for n, v in results.items() if n != "lrgnet") for k in ("ami", "ari")
    }
    print("\ntargets (held-out generator, no colour):")
    for name, ok in {
        "AMI >= 0.85": m["ami"] >= 0.85,
        "ARI >= 0.85": m["ari"] >= 0.85,
        "precision >= 0.5": m["precision"] >= 0.5,
        "recall >= 0.6": m["recall"] >= 0.6,
        "ahead of every classical baseline by >= 0.03 AMI and ARI": m["ami"] - best["ami"] >= 0.03
        and m["ari"] - best["ari"] >= 0.03,
    }.items():
        print(f"  {'met ' if ok else 'MISSED'} {name}")
    assert m["nmi"] > 0.3
