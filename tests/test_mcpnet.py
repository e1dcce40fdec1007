"""MCPNet: batch independence, the colour-free mode, weights files (shipped, missing, mismatched) and a short
simulated run through the stream."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from aftershock import sources
from aftershock.models.mcpnet import (
    MCPNet,
    context_draws,
    context_features,
    default_weights,
    load_model,
    num_parameters,
    point_features,
    point_inputs_of_rows,
    row_offsets,
    save_weights,
)
from aftershock.models.mcpnet_train import (
    AFFINITY_RADIUS_M,
    BATCH_INSTANCES,
    CROP_POINTS,
    HELDOUT_SEEDS,
    LINK_NEGATIVE,
    LINK_POSITIVE,
    POINTS_PER_INSTANCE,
    TRAIN_SEEDS,
    Pool,
    affinity_loss,
    mcpnet_config,
    semihard_triplet_loss,
    stage_uris,
    transfer_uris,
    weighted_class_loss,
)
from aftershock.models.netconfig import NetConfig
from aftershock.pipeline.classes import NUM_CLASSES, UNLABELLED
from aftershock.pipeline.config import ClusterConfig, Config, Environment
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.label import Labeller, make_labeller
from aftershock.pipeline.labellers.mcpnet import MCPNetLabeller, distinct_pairs, top_class
from aftershock.pipeline.stream import run_stream
from aftershock.pipeline.types import LabelledCloud, RunInfo
from aftershock.pipeline.voxel_map import VoxelMap

SIM = "sim://office?seed=950&sensor=vlp16&scans=25"
MAX_WEIGHTS_BYTES = 5 * 1024 * 1024


def _inputs(n: int, seed: int, cfg: NetConfig) -> list[torch.Tensor]:
    """Random point features, context, mask and (with a wider context) the wider context and its mask."""
    g = torch.Generator().manual_seed(seed)
    out = [torch.randn(n, cfg.point_dim, generator=g), torch.randn(n, 50, 6, generator=g)]
    out.append(torch.rand(n, 50, generator=g) > 0.2)
    if cfg.coarse_points:
        out += [torch.randn(n, cfg.coarse_points, 3, generator=g), torch.rand(n, cfg.coarse_points, generator=g) > 0.2]
    return out


@pytest.mark.parametrize("kind", ["mcpnet", "mcpnet-nocontext"])
def test_a_points_output_does_not_depend_on_its_batch_mates(kind: str) -> None:
    model, cfg, _ = load_model(default_weights(kind), kind=kind)
    one = _inputs(1, 0, cfg)
    alone = model(*one)
    for seed in (1, 2):
        others = _inputs(63, seed, cfg)
        emb, logits = model(*(torch.cat([o[:20], x, o[20:]]) for x, o in zip(one, others, strict=True)))
        torch.testing.assert_close(emb[20:21], alone[0], atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(logits[20:21], alone[1], atol=1e-4, rtol=1e-5)


def test_context_draws_depend_on_the_voxel_only() -> None:
    keys = np.array([5, 17, -3, 1 << 40])
    u = context_draws(keys, 50)
    assert u.shape == (4, 50) and (u >= 0).all() and (u < 1).all()
    np.testing.assert_array_equal(context_draws(keys[[2, 0]], 50), u[[2, 0]])
    assert 0.4 < u.mean() < 0.6


def test_labeller_predictions_do_not_depend_on_which_rows_are_asked_with() -> None:
    rng = np.random.default_rng(0)
    vmap = VoxelMap(0.1, 50)
    pts = rng.uniform(-1, 1, (800, 3))
    vmap.insert(pts, rng.integers(0, 255, (800, 3)).astype(np.uint8))
    labeller = MCPNetLabeller(Config(), ClusterConfig().beta_indoor)
    origin = np.zeros(3)
    rows = np.arange(len(vmap))
    probs_all, emb_all = labeller.predict_probs(vmap, rows, origin, -1.0, True)
    pick = rows[[7, 300, 2]]
    probs_few, emb_few = labeller.predict_probs(vmap, pick, origin, -1.0, True)
    np.testing.assert_array_equal(top_class(probs_few)[0], top_class(probs_all)[0][pick])
    np.testing.assert_allclose(emb_few, emb_all[pick], atol=1e-5)


@pytest.mark.parametrize("name", ["mcpnet", "mcpnet-nocontext", "pointnet", "region-growing"])
def test_every_labeller_is_built_for_the_environment_it_is_given(name: str) -> None:
    """The environment and the name are arguments (not fields of a copied config): the labellers with
    embeddings link voxels at the cluster section's β for that environment; every one can vote instances."""
    cfg = Config()
    for environment in (Environment.INDOOR, Environment.OUTDOOR):
        labeller = make_labeller(name, cfg, environment)
        assert isinstance(labeller, Labeller) and labeller.name == name
        if labeller.embedding_dim:
            assert labeller.beta == cfg.cluster.link_beta(environment)
    assert cfg.cluster.link_beta(Environment.OUTDOOR) == cfg.cluster.beta_outdoor != cfg.cluster.beta_indoor
    assert cfg.label.environment is Environment.AUTO and cfg.label.labeller == "mcpnet"  # left as it was


@pytest.mark.parametrize("color", [True, False])
def test_distinct_pairs_pool_what_the_draws_pool(color: bool) -> None:
    """The labeller feeds each distinct neighbour once; the network on all draws (repeats included) gives
    the same classes and embeddings."""
    rng = np.random.default_rng(3)
    vmap = VoxelMap(0.1, 50)
    pts = np.r_[rng.uniform(-1, 1, (1500, 3)), rng.uniform(5, 5.4, (30, 3))]  # dense and sparse parts
    vmap.insert(pts, rng.integers(0, 255, (len(pts), 3)).astype(np.uint8))
    labeller = MCPNetLabeller(Config(), ClusterConfig().beta_indoor)
    rows = np.arange(len(vmap))
    origin = np.zeros(3)
    probs, emb = labeller.predict_probs(vmap, rows, origin, -1.0, color)
    cls, score = top_class(probs)
    colors = vmap.colors if color else None
    pf = point_features(vmap.positions, colors, origin, -1.0)
    ctx_rows = vmap.context_rows(vmap.positions, 0.3, 50, uniform=context_draws(vmap.keys, 50))
    owner, neighbour = distinct_pairs(ctx_rows)
    assert len(owner) < 0.9 * (ctx_rows >= 0).sum()  # repeats were there to leave out
    drawn = {(i, int(j)) for i, row in enumerate(ctx_rows) for j in row if j >= 0}
    assert sorted(zip(owner.tolist(), neighbour.tolist(), strict=True)) == sorted(drawn)
    c, m = context_features(vmap.positions, colors, rows, ctx_rows)
    model, net = (labeller.model, labeller.net) if color else (labeller.mono_model, labeller.mono_net)
    wide_rows = labeller.wide_context_rows(vmap, rows, net)
    pf = point_inputs_of_rows(net, pf, vmap.positions, rows, ctx_rows, wide_rows)
    wide = [] if wide_rows is None else [torch.from_numpy(a) for a in row_offsets(vmap.positions, rows, wide_rows)]
    with torch.inference_mode():
        e_ref, logits = model(torch.from_numpy(pf), torch.from_numpy(c), torch.from_numpy(m), *wide)
        p_ref, c_ref = torch.softmax(logits, dim=1).max(dim=1)
    np.testing.assert_array_equal(cls, c_ref.numpy())
    np.testing.assert_allclose(score, p_ref.numpy(), atol=1e-5)
    np.testing.assert_allclose(emb, e_ref.numpy(), atol=1e-5)


def test_triplet_loss_is_the_semi_hard_rule() -> None:
    g = torch.Generator().manual_seed(0)
    emb = torch.nn.functional.normalize(torch.randn(30, 4, generator=g), dim=1)
    labels = torch.randint(0, 4, (30,), generator=g)
    d = (2 - 2 * emb @ emb.T).clamp_min(0).numpy()
    lab = labels.numpy()
    expect = []
    for a in range(30):
        for p in range(30):
            if a == p or lab[a] != lab[p]:
                continue
            negs = d[a][lab != lab[a]]
            beyond = negs[negs > d[a, p]]
            dn = beyond.min() if len(beyond) else negs.max()
            expect.append(max(0.0, 1.0 + d[a, p] - dn))
    assert float(semihard_triplet_loss(emb, labels)) == pytest.approx(float(np.mean(expect)), rel=1e-5)


def test_local_instance_batches_hold_neighbouring_instances_of_one_mission() -> None:
    """A local triplet batch: 16 whole instances of one mission, the anchor's nearest by centroid; a global one
    draws over every mission. Centroids are those of each instance's own training points."""
    pool = Pool(stage_uris(transfer_uris((100,), 25)[:2], mcpnet_config(), log=False))
    rng = np.random.default_rng(0)
    for _ in range(5):
        inst = pool.sample_instance[pool.local_instance_batch(rng)].reshape(-1, POINTS_PER_INSTANCE)
        which = np.searchsorted(pool.sample_instance[pool.inst_order][pool.inst_start], inst[:, 0])
        mine = pool.inst_mission == pool.inst_mission[which[0]]
        assert len(inst) == min(BATCH_INSTANCES, mine.sum())  # a mission with fewer instances gives them all
        assert (inst == inst[:, :1]).all() and len(np.unique(inst[:, 0])) == len(inst)
        assert len(np.unique(inst[:, 0] >> 32)) == 1  # one mission
        dist = np.linalg.norm(pool.inst_centre[which] - pool.inst_centre[which[0]], axis=1)
        others = np.linalg.norm(pool.inst_centre[mine] - pool.inst_centre[which[0]], axis=1)
        assert dist.max() <= np.sort(others)[len(inst) - 1] + 1e-9  # the nearest ones, none skipped
    k = 3
    own = pool.inst_order[pool.inst_start[k] : pool.inst_start[k] + pool.inst_count[k]]
    assert np.allclose(pool.positions[pool.rows[own]].mean(axis=0), pool.inst_centre[k])
    spread = {int(i >> 32) for _ in range(20) for i in pool.sample_instance[pool.instance_batch(rng)]}
    assert spread == {0, 1}


def test_crop_batches_are_pieces_of_one_mission_with_boundaries() -> None:
    """A crop: CROP_POINTS distinct training points of one mission, the nearest ones around a point, so it is a
    compact piece of the map (never two missions' points, whose coordinates overlap) holding several instances."""
    pool = Pool(stage_uris(transfer_uris((100,), 25)[:2], mcpnet_config(), log=False))
    rng = np.random.default_rng(0)
    several = 0
    for _ in range(20):
        crop = pool.crop_batch(rng)
        assert len(crop) == CROP_POINTS == len(np.unique(crop))
        assert len(np.unique(pool.mission[crop])) == 1
        where = pool.positions[pool.rows[crop]]
        assert np.ptp(where, axis=0).max() < 4.0  # 256 voxels of 0.1 m on surfaces: about a metre across
        mine = pool.mission == pool.mission[crop[0]]
        outside = pool.positions[pool.rows[np.setdiff1d(np.flatnonzero(mine), crop)]]
        # the nearest points of one of its own: no point left out is nearer that anchor than a point taken
        reach_in = np.linalg.norm(where[:, None] - where[None], axis=2).max(axis=1)
        reach_out = np.linalg.norm(where[:, None] - outside[None], axis=2).min(axis=1)
        assert (reach_in <= reach_out + 1e-9).any()
        several += len(np.unique(pool.sample_instance[crop])) >= 2
    assert several >= 15


def test_affinity_loss_by_hand() -> None:
    """Only pairs within AFFINITY_RADIUS_M count, points of no instance never; one instance's pairs cost their
    shortfall below LINK_POSITIVE squared, two instances' their excess over LINK_NEGATIVE, averaged apart."""

    def unit(deg: float) -> list[float]:
        return [np.cos(np.radians(deg)), np.sin(np.radians(deg))]

    emb = torch.tensor([unit(0), unit(30), unit(10), unit(90), unit(0)], dtype=torch.float32, requires_grad=True)
    labels = torch.tensor([1, 1, 2, 2, 0])
    r = AFFINITY_RADIUS_M
    positions = np.array([[0, 0, 0], [0.5 * r, 0, 0], [0, 0.5 * r, 0], [10, 0, 0], [0, 0, 0.5 * r]])
    loss = affinity_loss(emb, labels, positions)
    same = (LINK_POSITIVE - np.cos(np.radians(30))) ** 2  # points 0 and 1
    # points 0-2 (cos 10 deg) and 1-2 (cos 20 deg); point 3 is far, point 4 is of no instance
    apart = np.mean([max(np.cos(np.radians(a)) - LINK_NEGATIVE, 0) ** 2 for a in (10, 20)])
    assert loss.detach().item() == pytest.approx(same + apart, rel=1e-5)
    loss.backward()
    assert emb.grad is not None and float(emb.grad[3].abs().sum()) == 0.0 and float(emb.grad[4].abs().sum()) == 0.0
    lone = affinity_loss(emb, labels, positions * 100)  # no pairs in reach: no loss, still differentiable
    assert lone.detach().item() == 0.0 and lone.requires_grad


@pytest.mark.parametrize("class_weights", [None, [1.0, 3.0, 0.5]])
def test_crop_points_class_loss_weight(class_weights: list[float] | None) -> None:
    """A crop batch's class loss: its own points at weight 1 count as the uniform ones (the plain mean), at 0 not
    at all (the mean over the uniform ones), at 0.5 half as much as each uniform point."""
    gen = torch.Generator().manual_seed(0)
    logits, labels = torch.randn(10, 3, generator=gen), torch.randint(0, 3, (10,), generator=gen)
    w = None if class_weights is None else torch.tensor(class_weights)
    ce = torch.nn.CrossEntropyLoss(weight=w)
    assert float(weighted_class_loss(ce, logits, labels, 4, 1.0)) == pytest.approx(float(ce(logits, labels)))
    assert float(weighted_class_loss(ce, logits, labels, 4, 0.0)) == pytest.approx(float(ce(logits[4:], labels[4:])))
    per = torch.nn.functional.cross_entropy(logits, labels, reduction="none")
    cw = torch.ones(3) if w is None else w
    share = torch.tensor([0.5] * 4 + [1.0] * 6) * cw[labels]
    by_hand = float((per * share).sum() / share.sum())
    assert float(weighted_class_loss(ce, logits, labels, 4, 0.5)) == pytest.approx(by_hand)


def test_training_and_heldout_seeds_are_disjoint() -> None:
    assert not set(TRAIN_SEEDS) & set(HELDOUT_SEEDS)
    assert int(SIM.split("seed=")[1].split("&")[0]) not in TRAIN_SEEDS


@pytest.mark.parametrize("kind", ["mcpnet", "mcpnet-nocontext", "pointnet"])
def test_shipped_weights_load_and_are_small(kind: str) -> None:
    path = default_weights(kind)
    model, cfg, figures = load_model(path, kind=kind)
    assert cfg.kind == kind
    assert path.stat().st_size < MAX_WEIGHTS_BYTES
    # trained on training seeds only (MCPNet since #12 on a subset of them, with the other generators)
    assert set(figures["train_seeds"]) <= set(TRAIN_SEEDS) and not set(figures["train_seeds"]) & set(HELDOUT_SEEDS)
    if kind == "mcpnet":
        assert 140_000 < num_parameters(model) < 150_000  # the study's ~146 k


def test_missing_and_mismatched_weights_are_refused_by_name(tmp_path: Path) -> None:
    missing = tmp_path / "nope.pt"
    with pytest.raises(InputError, match=r"nope\.pt.*aftershock train mcpnet"):
        load_model(missing)
    other = NetConfig(features=("x", "y", "z"), point_dim=3)
    bad = tmp_path / "other_layout.pt"
    save_weights(bad, MCPNet(other), other, {})
    with pytest.raises(InputError, match=r"other_layout\.pt.*feature layout"):
        load_model(bad)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(InputError, match=r"junk\.pt"):
        load_model(junk)


def test_bad_weights_through_the_cli(tmp_path: Path) -> None:
    bad = tmp_path / "mismatched.pt"
    other = NetConfig(width=32)
    torch.save(
        {
            "format": "aftershock-mcpnet",
            "version": 1,
            "config": other.to_dict(),
            "figures": {},
            "state": MCPNet(other).state_dict() | {"extra": torch.zeros(1)},
        },
        bad,
    )
    sim = "sim://office?seed=951&sensor=vlp16&scans=3"
    for path, what in ((tmp_path / "missing.pt", "not found"), (bad, "do not fit")):
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "aftershock.pipeline",
                "eval",
                sim,
                "--labeller",
                "mcpnet",
                "--set",
                f"label.weights={path}",
                "-q",
            ],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert out.returncode == 2, out.stderr
        assert str(path) in out.stderr and what in out.stderr and "aftershock train mcpnet" in out.stderr
        assert "Traceback" not in out.stderr


@pytest.fixture(scope="module")
def sim_scans() -> list:
    return list(sources.open(SIM))


def _accuracy(vmap: VoxelMap) -> float:
    known = vmap.true_class_ids != UNLABELLED
    return float((vmap.class_ids[known] == vmap.true_class_ids[known]).mean())


@pytest.mark.parametrize("color", [True, False])
def test_a_short_simulated_run_labels_points(sim_scans: list, color: bool) -> None:
    scans = sim_scans
    if not color:
        scans = [s.select(np.ones(len(s), bool)) for s in sim_scans]
        for s in scans:
            s.colors = None
    result = run_stream(iter(scans), Config(), [], RunInfo(source=SIM, source_kind="sim"), lambda _t: None)
    vmap = result.vmap
    assert result.labeller == "mcpnet"
    assert len(vmap) > 500
    assert (vmap.class_ids != UNLABELLED).all()
    np.testing.assert_allclose(np.linalg.norm(vmap.embeddings, axis=1), 1.0, atol=1e-4)
    # Every voxel was given an instance; what the user gets are objects of the minimum size, and the small
    # fragments left over (hidden as 0) are a minor part of the map.
    ids, counts = np.unique(vmap.instance_ids, return_counts=True)
    assert (counts[ids > 0] >= Config().cluster.min_object_voxels).all()
    assert (vmap.instance_ids > 0).mean() > 0.8, (vmap.instance_ids > 0).mean()
    truth = vmap.true_class_ids[vmap.true_class_ids != UNLABELLED]
    majority = np.bincount(truth).max() / len(truth)  # what calling everything a wall would score
    # A building never trained on: with colour better than the majority class, without it far above chance.
    assert _accuracy(vmap) > (majority + 0.05 if color else 3 / NUM_CLASSES)


def test_embed_cloud_gives_unit_embeddings_per_point() -> None:
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 3, (2000, 3))
    labeller = MCPNetLabeller(Config(), ClusterConfig().beta_indoor)
    emb = labeller.embed_cloud(LabelledCloud(pts, rng.integers(0, 255, (2000, 3)).astype(np.uint8)))
    assert emb.shape == (2000, 50)
    np.testing.assert_allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-4)
