"""LRGNet: features, network, growth, small-segment absorption, determinism, the refine command, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from aftershock.models.lrgnet import LRGNet, load_weights, num_parameters, save_weights
from aftershock.models.lrgnet_train import (
    GENERATORS,
    HELDOUT_SEEDS,
    TRAIN_SEEDS,
    VALIDATION_SEEDS,
    WARMUP_STEPS,
    batch_tensors,
    lr_factor,
    make_samples,
    room_variant,
    simulate_growth,
    voxel_truth,
    without_color,
)
from aftershock.models.transfer_split import HELDOUT_GENERATOR
from aftershock.pipeline.cli import main
from aftershock.pipeline.cloud_io import write_cloud
from aftershock.pipeline.config import LRGNET_MODE_DEFAULTS, LRGNetConfig
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.geometry import attach_small_segments
from aftershock.pipeline.refine import LAYOUTS, baseline_cloud, load_network, refine_cloud, scores, weight_settings
from aftershock.pipeline.refine.baselines import Baseline
from aftershock.pipeline.refine.features import (
    NUM_FEATURES,
    PLANE_FEATURES,
    region_centre,
    step_features,
    voxelise,
)
from aftershock.pipeline.refine.grow import Grower, Growth, seed_order
from aftershock.pipeline.refine.merge import merge_coplanar, split_creases
from aftershock.pipeline.types import LabelledCloud


# ----------------------------------------------------------------------------- synthetic scenes
def _plane(origin, u, v, spacing: float, rng: np.random.Generator) -> np.ndarray:
    u, v = np.asarray(u, float), np.asarray(v, float)
    nu, nv = max(2, int(np.linalg.norm(u) / spacing)), max(2, int(np.linalg.norm(v) / spacing))
    a, b = np.meshgrid(np.linspace(0, 1, nu), np.linspace(0, 1, nv), indexing="ij")
    pts = np.asarray(origin, float) + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
    return pts + rng.normal(0, 0.003, pts.shape)


def _box(lo, hi, spacing: float, rng: np.random.Generator) -> np.ndarray:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    ex, ey, ez = np.diag(hi - lo)
    faces = [(lo, ex, ey), (lo + ez, ex, ey), (lo, ex, ez), (lo + ey, ex, ez), (lo, ey, ez), (lo + ex, ey, ez)]
    return np.vstack([_plane(o, u, v, spacing, rng) for o, u, v in faces])


def _cloud(parts: list[np.ndarray], rng: np.random.Generator) -> LabelledCloud:
    pts = np.vstack(parts)
    inst = np.concatenate([np.full(len(p), i + 1) for i, p in enumerate(parts)]).astype(np.uint32)
    palette = rng.integers(40, 220, (len(parts) + 1, 3))
    colors = np.clip(palette[inst] + rng.normal(0, 5, (len(pts), 3)), 0, 255).astype(np.uint8)
    return LabelledCloud(pts, colors, None, np.full(len(pts), 12, np.uint16), inst)


def tiny_room(seed: int = 0) -> LabelledCloud:
    """A 1.5 x 1.2 m corner (floor, wall) with a box: ~500 voxels."""
    rng = np.random.default_rng(seed)
    parts = [
        _plane((0, 0, 0), (1.5, 0, 0), (0, 1.2, 0), 0.05, rng),
        _plane((0, 0, 0), (1.5, 0, 0), (0, 0, 1.0), 0.05, rng),
        _box((0.6, 0.5, 0.05), (1.0, 0.9, 0.4), 0.05, rng),
    ]
    return _cloud(parts, rng)


def small_room(seed: int = 0) -> LabelledCloud:
    """A 3 x 2.5 x 1.5 m room (floor and two walls) with two boxes: ~3k voxels."""
    rng = np.random.default_rng(seed)
    parts = [
        _plane((0, 0, 0), (3, 0, 0), (0, 2.5, 0), 0.05, rng),
        _plane((0, 0, 0), (3, 0, 0), (0, 0, 1.5), 0.05, rng),
        _plane((0, 0, 0), (0, 2.5, 0), (0, 0, 1.5), 0.05, rng),
        _box((0.8, 0.8, 0.05), (1.4, 1.3, 0.7), 0.05, rng),
        _box((2.0, 1.4, 0.05), (2.6, 2.1, 0.5), 0.05, rng),
    ]
    return _cloud(parts, rng)


def apart_boxes(seed: int = 0) -> LabelledCloud:
    """Two boxes 1 m apart and a 3-point fragment 0.25 m from the first: three connected components."""
    rng = np.random.default_rng(seed)
    parts = [
        _box((0, 0, 0), (0.5, 0.5, 0.5), 0.05, rng),
        _box((1.5, 0, 0), (2.0, 0.5, 0.5), 0.05, rng),
        np.array([[0.75, 0.25, 0.25], [0.76, 0.26, 0.25], [0.77, 0.25, 0.26]]),
    ]
    return _cloud(parts, rng)


def biased_net(add: float, remove: float = -20.0) -> LRGNet:
    """A real LRGNet whose output layers are set by hand to always (or never) add / remove."""
    torch.manual_seed(0)
    net = LRGNet()
    with torch.no_grad():
        for head, bias in ((net.add_head, add), (net.remove_head, remove)):
            last = head.layers[-1]
            last.weight.zero_()
            last.bias.copy_(torch.tensor([0.0, bias]))
    return net.eval()


@pytest.fixture(scope="module")
def weights_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real (randomly initialised, seeded) weights file with a correct header."""
    path = tmp_path_factory.mktemp("w") / "lrgnet.pt"
    torch.manual_seed(0)
    save_weights(path, LRGNet(), weight_settings(LRGNetConfig()), {})
    return path


# ----------------------------------------------------------------------------- features
def test_features_shape_and_ranges() -> None:
    cloud = small_room()
    vc = voxelise(cloud, 0.1)
    m = len(vc)
    assert vc.features.shape == (m, NUM_FEATURES) and vc.features.dtype == np.float32
    assert 1500 < m < len(cloud)
    room = vc.features[:, 3:6]
    assert room.min() >= 0 and room.max() <= 1 and np.allclose(room.max(axis=0), 1)
    assert np.allclose(np.linalg.norm(vc.features[:, 9:12], axis=1), 1, atol=1e-4)
    assert vc.features[:, 2].min() == pytest.approx(0, abs=1e-6)  # z above the floor
    shape = vc.features[:, 13:16]  # planarity, linearity, verticality
    assert shape.min() >= 0 and shape.max() <= 1 + 1e-5
    assert vc.voxel_of_point.shape == (len(cloud),) and vc.voxel_of_point.max() == m - 1
    # Floor voxels away from walls and boxes: flat (curvature ~ 0) with normals up.
    x, y = vc.points[:, 0], vc.points[:, 1]
    floor = (cloud.instance_ids[vc.first_point] == 1) & (x > 1.6) & (x < 2.8) & (y > 0.3) & (y < 1.1)
    assert floor.sum() > 50
    assert np.median(vc.curvature[floor]) < 0.01
    assert np.all(vc.features[floor, 11] > 0.99)
    assert np.all(vc.features[floor, 15] > 0.99) and np.median(vc.features[floor, 13]) > 0.8  # flat, horizontal
    x_wall = cloud.instance_ids[vc.first_point] == 2
    assert np.median(vc.features[x_wall, 15]) < 0.05  # a wall: not horizontal at all
    # Adjacency is symmetric: 26-neighbourhood of touching voxels.
    a = vc.adjacency
    i, k = np.nonzero(a >= 0)
    assert np.all(np.any(a[a[i, k]] == i[:, None], axis=1))


def test_step_normalisation_is_relative_to_region_median() -> None:
    vc = voxelise(small_room(), 0.1)
    region = np.arange(0, len(vc), 7)
    centre = region_centre(vc.features, region)
    f = step_features(vc.features, region, centre)
    assert np.allclose(np.median(f[:, 0:2], axis=0), 0, atol=1e-5)
    assert np.allclose(np.median(f[:, 6:13], axis=0), 0, atol=1e-5)
    assert np.array_equal(f[:, 2:6], vc.features[region, 2:6])  # z and room-normalised xyz untouched
    assert np.array_equal(f[:, 13:16], vc.features[region, 13:16])  # the local shape stays absolute


def test_plane_features_of_layout_3() -> None:
    """Distance to the region's plane and |cos| to its normal: zero and one on the region's own wall, large
    distance and small cosine on the floor beside it; training computes them as inference does."""
    cloud = small_room()
    vc = voxelise(cloud, 0.1)
    on = cloud.instance_ids[vc.first_point]
    wall = np.flatnonzero(on == 2)
    floor = np.flatnonzero(on == 1)
    centre = region_centre(vc.features, wall[::3])
    f_wall = step_features(vc.features, wall, centre, plane=True)
    f_floor = step_features(vc.features, floor, centre, plane=True)
    assert f_wall.shape == (len(wall), NUM_FEATURES + PLANE_FEATURES)
    assert np.median(f_wall[:, 16]) < 0.02 and np.median(f_wall[:, 17]) > 0.98
    assert np.median(f_floor[:, 16]) > 0.3 and np.median(f_floor[:, 17]) < 0.1
    np.testing.assert_array_equal(f_wall[:, :NUM_FEATURES], step_features(vc.features, wall, centre))
    samples = make_samples([cloud], LRGNetConfig(), np.random.default_rng(0), points=32)
    xi, xn, _, _ = batch_tensors(samples, np.arange(3), None, plane=True)
    for b in range(3):
        feats = samples.features[samples.scene[b]]
        for x, idx in ((xi, samples.inliers[b]), (xn, samples.neighbours[b])):
            expected = step_features(feats, idx, samples.centre[b], plane=True)
            np.testing.assert_allclose(x[b].numpy(), expected, atol=1e-6)


# ----------------------------------------------------------------------------- network
def test_network_shapes_parameters_and_batch_independence() -> None:
    net = LRGNet().eval()
    assert net.in_features == NUM_FEATURES
    assert num_parameters(net) == 791_428  # ~0.79 M as in the study (its 13 inputs: 791,044)
    torch.manual_seed(1)
    xi, xn = torch.randn(3, 512, NUM_FEATURES), torch.randn(3, 300, NUM_FEATURES)
    with torch.no_grad():
        rm, add = net(xi, xn)
        assert rm.shape == (3, 512, 2) and add.shape == (3, 300, 2)
        alone = net(xi[1:2], xn[1:2])
        assert torch.allclose(alone[0][0], rm[1], atol=1e-5) and torch.allclose(alone[1][0], add[1], atol=1e-5)
        # The split first head layer equals the layer on the joined 1088-wide vector.
        g = net.encode(xi, xn)
        local = torch.relu(net.add_head.layers[0].weight.new_zeros(1))  # keep type checkers quiet
        local, _ = net.neighbour_branch(xn)
        joined = torch.cat([g[:, None, :].expand(-1, local.shape[1], -1), local], dim=-1)
        x = torch.relu(net.add_head.layers[0](joined))
        x = torch.relu(net.add_head.layers[1](x))
        assert torch.allclose(net.add_head.layers[2](x), add, atol=1e-4)


# ----------------------------------------------------------------------------- growth
def test_growth_covers_a_connected_object_and_stops_without_neighbours() -> None:
    cloud = apart_boxes()
    cfg = LRGNetConfig(min_segment_points=1, crease_angle_deg=0)  # growth alone: no crease split of the box faces
    truth = cloud.instance_ids
    first = refine_cloud(cloud, cfg, net=biased_net(add=20.0))
    box = int(first.instance_ids[truth == 2][0])
    res = refine_cloud(cloud, cfg, net=biased_net(add=20.0), record_object=box)
    assert np.array_equal(res.instance_ids, first.instance_ids)
    # Always adding: each connected component becomes exactly one object.
    for t in (1, 2, 3):
        assert len(np.unique(res.instance_ids[truth == t])) == 1
    assert len(np.unique(res.instance_ids)) == 3
    assert res.steps is not None and len(res.steps) == res.steps_per_object[box - 1] > 1
    inl, nb = res.steps[-1]
    assert len(np.intersect1d(inl, nb)) == 0 and len(nb) > 0
    assert np.all(truth[inl] == 2) and np.all(truth[nb] == 2)


def test_seeds_flat_reliable_voxels_first() -> None:
    """Seeds by increasing curvature, voxels with few occupied neighbours (edges, stray points) after all others."""
    vc = voxelise(small_room(), 0.1)
    occupied = (vc.adjacency >= 0).sum(axis=1)
    order = seed_order(vc, 6)
    assert sorted(order.tolist()) == list(range(len(vc)))
    reliable = occupied[order] >= 6
    n = int(reliable.sum())
    assert 0 < n < len(vc) and reliable[:n].all() and not reliable[n:].any()
    assert np.all(np.diff(vc.curvature[order[:n]]) >= 0) and np.all(np.diff(vc.curvature[order[n:]]) >= 0)
    assert vc.curvature[order[0]] < 0.01
    assert np.array_equal(seed_order(vc, 0), np.argsort(vc.curvature, kind="stable"))


def test_growth_stops_when_nothing_is_added_and_at_the_step_cap() -> None:
    vc = voxelise(apart_boxes(), 0.1)
    never = Grower(vc, biased_net(add=-20.0), LRGNetConfig()).grow(0)
    assert never.steps == 1 and len(never.region) == 1
    capped = Grower(vc, biased_net(add=20.0), LRGNetConfig(max_steps=2)).grow(0)
    assert capped.steps == 2 and 1 < len(capped.region) < len(vc) / 2


def test_growth_stops_when_the_region_does_not_expand_for_two_steps() -> None:
    """The stopping rule alone, with the decisions scripted: grow, then swap one point for another twice."""

    class Scripted(Grower):
        def probabilities(self, region: np.ndarray, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            self.network_steps += 1
            rm = np.zeros(len(region), np.float32)
            add = np.zeros(len(candidates), np.float32)
            add[0] = 1.0
            if self.network_steps > 1:
                rm[-1] = 1.0  # one out, one in: the region does not expand
            else:
                add[:3] = 1.0
            return rm, add

    line = LabelledCloud(np.stack([np.arange(40) * 0.1 + 0.05, np.full(40, 0.05), np.full(40, 0.05)], axis=1))
    g = Scripted(voxelise(line, 0.1), biased_net(0.0), LRGNetConfig()).grow(20)
    assert g.steps == 3 and g.not_expanding == 2 and len(g.region) == 3


def test_the_flat_region_gate_stops_a_plane_at_its_crease() -> None:
    """With `flat_gate_deg`, a flat region (part of the floor) may take floor voxels but not wall voxels; a region
    that is not flat (floor and wall together) or still small may take either."""
    vc = voxelise(small_room(), 0.1)
    normal_z = np.abs(vc.features[:, 11])
    floor = np.flatnonzero((vc.points[:, 2] < 0.1) & (normal_z > 0.95) & (vc.points[:, 0] > 0.2))
    wall = np.flatnonzero((vc.points[:, 1] < 0.1) & (normal_z < 0.05) & (vc.points[:, 2] > 0.3))
    assert len(floor) > 40 and len(wall) > 20
    floor, wall = np.random.default_rng(0).permutation(floor), np.random.default_rng(1).permutation(wall)
    grower = Grower(vc, LRGNet().eval(), LRGNetConfig(flat_gate_deg=20))
    region, candidates = floor[:30], np.concatenate([floor[30:40], wall[:10]])
    assert np.array_equal(grower.within_plane(region, candidates), np.r_[np.ones(10, bool), np.zeros(10, bool)])
    assert grower.within_plane(np.concatenate([floor[:20], wall[10:20]]), candidates).all()
    assert grower.within_plane(floor[:5], candidates).all()


def test_small_segments_take_the_label_of_their_nearest_neighbour() -> None:
    cloud = apart_boxes()
    cfg = LRGNetConfig(min_segment_points=10, crease_angle_deg=0)  # growth and clean-up alone, no crease split
    res = refine_cloud(cloud, cfg, net=biased_net(add=20.0))
    frag, box1 = cloud.instance_ids == 3, cloud.instance_ids == 1
    assert len(np.unique(res.instance_ids[frag])) == 1
    assert res.instance_ids[frag][0] == res.instance_ids[box1][0]
    assert len(np.unique(res.instance_ids)) == 2


def test_search_is_seeded_and_deterministic() -> None:
    cloud = apart_boxes()
    net = biased_net(add=0.5, remove=-2.0)  # P(add) ~ 0.6, P(remove) ~ 0.1: sampled decisions vary
    for search in ("restart", "beam"):
        cfg = LRGNetConfig(search=search, restarts=3, max_steps=4, seed=5)
        a, b = refine_cloud(cloud, cfg, net=net), refine_cloud(cloud, cfg, net=net)
        assert np.array_equal(a.instance_ids, b.instance_ids)
        assert a.steps_per_object == b.steps_per_object
    vc = voxelise(cloud, 0.1)
    start = Growth(np.array([0]))
    grown = [Grower(vc, net, LRGNetConfig(seed=s))._run(start, sample=True, record=False).region for s in (5, 5, 6)]
    assert np.array_equal(grown[0], grown[1]) and not np.array_equal(grown[0], grown[2])


# ----------------------------------------------------------------------------- training data
def test_simulated_growth_labels_match_the_truth() -> None:
    cloud = small_room()
    vc = voxelise(cloud, 0.1)
    truth = voxel_truth(vc, cloud)
    assert set(np.unique(truth)) == {1, 2, 3, 4, 5}
    steps = simulate_growth(vc, truth, np.random.default_rng(0), 64, 32)
    assert len(steps) > 10
    for si, sn, rm, add, centre in steps[:20]:
        assert si.shape == (64,) and sn.shape == (32,) and centre.shape == (10,)
        target = truth[si][~rm]
        assert len(np.unique(target)) <= 1  # kept inliers all belong to one object
        assert np.all((truth[sn] == (target[0] if len(target) else -1)) == add) or not len(target)
    samples = make_samples([cloud], LRGNetConfig(), np.random.default_rng(0), points=32)
    xi, xn, rm, add = batch_tensors(samples, np.arange(4), np.random.default_rng(0))
    assert xi.shape == (4, 32, NUM_FEATURES) and xn.shape == (4, 32, NUM_FEATURES)
    assert rm.shape == (4, 32) and add.shape == (4, 32)
    assert torch.allclose(xi[..., 9:12].norm(dim=-1), xi[..., 9:12].norm(dim=-1))  # finite


def test_training_schedule_and_buildings() -> None:
    """Warm-up to the peak learning rate, cosine to zero; training and held-out buildings never share a seed."""
    total = 1000
    f = np.array([lr_factor(k, total) for k in range(total + 1)])
    assert f[0] == pytest.approx(1 / WARMUP_STEPS) and f[WARMUP_STEPS - 1] == pytest.approx(1.0)
    assert np.all(np.diff(f[WARMUP_STEPS - 1 :]) <= 1e-12) and f[total] == pytest.approx(0.0, abs=1e-12)
    assert f[(total + WARMUP_STEPS) // 2] == pytest.approx(0.5, abs=0.01)
    assert HELDOUT_GENERATOR not in TRAIN_SEEDS and set(GENERATORS) <= set(TRAIN_SEEDS) == set(HELDOUT_SEEDS)
    for g, seeds in TRAIN_SEEDS.items():
        assert len(seeds) > 1 and len({*seeds, *VALIDATION_SEEDS[g], *HELDOUT_SEEDS[g]}) == len(seeds) + 2


def test_training_rooms_without_color_are_what_inference_sees() -> None:
    """Colour-free training rooms carry no colour at all, so their colour features are zero as at inference;
    a room variant keeps most points, each moved by at most a few centimetres, with its labels."""
    cloud = small_room()
    plain = without_color(cloud)
    assert plain.colors is None and np.array_equal(plain.instance_ids, cloud.instance_ids)
    assert np.all(voxelise(plain, 0.1).features[:, 6:9] == 0) and voxelise(cloud, 0.1).features[:, 6:9].max() > 0
    rng = np.random.default_rng(0)
    variants = [room_variant(cloud, rng) for _ in range(20)]
    assert 5 < sum(v.colors is None for v in variants) < 15
    tree = cKDTree(cloud.points)
    for v in variants:
        assert 0.65 * len(cloud) < len(v) <= len(cloud) and len(v.instance_ids) == len(v)
        dist, nearest = tree.query(v.points)
        assert dist.max() < 0.06 and np.mean(cloud.instance_ids[nearest] == v.instance_ids) > 0.95


# ----------------------------------------------------------------------------- consolidation
def test_coplanar_pieces_merge_and_other_segments_do_not() -> None:
    """A floor cut into four pieces becomes one; the wall at right angles and the box on the floor stay apart."""
    cloud = small_room()
    vc = voxelise(cloud, 0.1)
    truth = voxel_truth(vc, cloud)
    labels = truth.copy()
    floor = truth == 1
    x, y = vc.points[:, 0], vc.points[:, 1]
    labels[floor] = 10 + (x[floor] > 1.5) + 2 * (y[floor] > 1.2)  # four pieces of one floor
    merged = merge_coplanar(vc, labels, 5.0, 0.05)
    assert len(np.unique(merged[floor])) == 1
    for t in (2, 3, 4, 5):
        assert np.array_equal(merged[truth == t], labels[truth == t])
    assert len(np.unique(merged)) == 5
    assert np.array_equal(merge_coplanar(vc, truth, 5.0, 0.05), truth)  # nothing to merge


def test_a_segment_round_a_crease_is_cut_and_small_faces_stay_whole() -> None:
    """Floor and both walls grown as one segment come apart at their edges (each keeps most of its voxels in a
    segment of its own); a box whose faces are under the size limit stays one segment, while a face of the other
    box reaches it (50 voxels: 0.6 x 0.65 m, a table top) and comes off; nothing else moves."""
    cloud = small_room()
    vc = voxelise(cloud, 0.1)
    truth = voxel_truth(vc, cloud)
    labels = np.where(np.isin(truth, (1, 2, 3)), 1, truth)  # the structure leaked into one segment
    cut = split_creases(vc, labels, 15.0, 50)
    main = [np.bincount(cut[truth == t]).argmax() for t in (1, 2, 3)]
    assert len(set(main)) == 3
    for t, m in zip((1, 2, 3), main, strict=True):
        assert np.mean(cut[truth == t] == m) > 0.8
    assert np.array_equal(cut[truth == 5], labels[truth == 5])
    assert len(np.unique(cut[truth == 4])) == 2
    assert np.array_equal(split_creases(vc, truth, 15.0, 60), truth)  # one plane per segment: nothing to cut
    assert np.array_equal(split_creases(vc, labels, 15.0, 10_000), labels)  # no part that large


# ----------------------------------------------------------------------------- baselines
@pytest.mark.parametrize("name", [Baseline.THRESHOLD, Baseline.SMOOTHNESS, Baseline.FPFH])
def test_baselines_segment_a_simple_room(name: Baseline) -> None:
    cloud = small_room()
    res = baseline_cloud(cloud, name, LRGNetConfig())
    assert res.instance_ids.shape == (len(cloud),) and res.instance_ids.min() >= 1
    s = scores(cloud.instance_ids, res.instance_ids)
    assert 0 <= s["nmi"] <= 1 and s["predicted_instances"] >= 2


# ----------------------------------------------------------------------------- the command
def test_refine_command_json(tmp_path: Path, weights_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ply = write_cloud(tmp_path / "room.ply", tiny_room())
    out = tmp_path / "refined.ply"
    args = ["refine", str(ply), "--truth", "--json", "--weights", str(weights_file), "--set", "lrgnet.max_steps=4"]
    assert main([*args, "--no-baselines", "--out", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    for key in ("nmi", "ami", "ari", "precision", "recall", "mean_iou", "segments", "steps_per_object"):
        assert key in report
    assert 0 <= report["nmi"] <= 1 and report["points"] == len(tiny_room())
    assert out.is_file()
    assert main([*args, "--no-baselines", "--out", str(out)]) == 2  # exists without --force
    assert "already exists" in capsys.readouterr().err
    mono = tiny_room()
    mono.colors = None  # a cloud without colour is grown, and reported, with the colour-free settings
    main(["refine", str(write_cloud(tmp_path / "mono.ply", mono)), "--json", "--weights", str(weights_file)])
    mono_report = json.loads(capsys.readouterr().out)
    assert report["colour"] is True and report["settings"] == LRGNET_MODE_DEFAULTS[True]
    assert mono_report["colour"] is False and mono_report["settings"] == LRGNET_MODE_DEFAULTS[False]


def test_refine_command_bad_input(tmp_path: Path, weights_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["refine", str(tmp_path / "missing.ply")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("aftershock: error:") and "missing.ply" in err and err.count("\n") == 1
    room = tiny_room()
    room.instance_ids = None
    ply = write_cloud(tmp_path / "nolabels.ply", room)
    assert main(["refine", str(ply), "--truth", "--weights", str(weights_file)]) == 2
    assert "instance_id" in capsys.readouterr().err
    wrong = tmp_path / "wrong.pt"
    save_weights(wrong, LRGNet(), {**weight_settings(LRGNetConfig()), "voxel_size_m": 0.2}, {})
    assert main(["refine", str(ply), "--weights", str(wrong)]) == 2
    err = capsys.readouterr().err
    assert "wrong.pt" in err and "voxel_size_m" in err and "aftershock train lrgnet" in err
    other = tmp_path / "other_layout.pt"  # a layout this version does not know
    save_weights(other, LRGNet(20), {**weight_settings(LRGNetConfig()), "features": 20, "feature_version": 3}, {})
    assert main(["refine", str(ply), "--weights", str(other)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "other_layout.pt" in err and "layout 3 (20 features)" in err
    assert "aftershock train lrgnet --force" in err
    with pytest.raises(InputError, match="layout 2 \\(13 features\\)"):
        save_weights(other, LRGNet(13), {**weight_settings(LRGNetConfig()), "features": 13}, {})
        load_network(LRGNetConfig(weights=str(other)))
    with pytest.raises(InputError, match="not an LRGNet weights file"):
        torch.save({"x": 1}, tmp_path / "other.pt")
        load_weights(tmp_path / "other.pt", weight_settings(LRGNetConfig()), LAYOUTS)


def test_weights_of_the_older_layout_read_its_first_columns(tmp_path: Path) -> None:
    """13-feature weights (layout 1, before the local shape) still run, on the first 13 columns, and give the same
    segmentation as the same network fed those columns by hand."""
    path = tmp_path / "layout1.pt"
    torch.manual_seed(0)
    net13 = LRGNet(13)
    save_weights(path, net13, {**weight_settings(LRGNetConfig()), "features": 13, "feature_version": 1}, {})
    cfg = LRGNetConfig(weights=str(path), max_steps=6, merge_angle_deg=0, crease_angle_deg=0)  # growth alone
    loaded = load_network(cfg)
    assert loaded.in_features == 13
    cloud = small_room()
    res = refine_cloud(cloud, cfg)
    vc = voxelise(cloud, 0.1)
    vc.features = vc.features[:, :13].copy()
    torch.manual_seed(cfg.seed)
    seg = Grower(vc, net13.eval(), cfg).segment()
    by_hand = attach_small_segments(vc.points, seg.labels, cfg.min_segment_points)[vc.voxel_of_point]
    assert np.array_equal(res.instance_ids, by_hand) and res.steps_per_object == seg.steps_per_object
    assert len(np.unique(res.instance_ids)) > 1


def test_settings_follow_the_clouds_color_mode() -> None:
    """Growth and consolidation take the defaults of the cloud's mode (with colour or without), a value the user
    sets serves both modes, and `refine_cloud` on a cloud without colour is the run with the colour-free values
    given by hand."""
    mono = small_room()
    mono.colors = None
    with_color, without = LRGNET_MODE_DEFAULTS[True], LRGNET_MODE_DEFAULTS[False]
    assert with_color.keys() == without.keys() and with_color != without
    assert LRGNetConfig().for_color(True).model_dump(include=set(with_color)) == with_color
    assert LRGNetConfig().for_color(False).model_dump(include=set(without)) == without
    assert LRGNetConfig(add_threshold=0.7).for_color(False).add_threshold == 0.7
    net = LRGNet().eval()
    assert Grower(voxelise(mono, 0.1), net, LRGNetConfig()).cfg.add_threshold == without["add_threshold"]
    assert Grower(voxelise(small_room(), 0.1), net, LRGNetConfig()).cfg.add_threshold == with_color["add_threshold"]
    cfg = LRGNetConfig(max_steps=20)
    by_default = refine_cloud(mono, cfg).instance_ids
    assert np.array_equal(by_default, refine_cloud(mono, LRGNetConfig(max_steps=20, **without)).instance_ids)
    assert not np.array_equal(by_default, refine_cloud(mono, LRGNetConfig(max_steps=20, **with_color)).instance_ids)


def test_shipped_weights_segment_a_simple_room() -> None:
    """The shipped weights load with the default settings and find the room's surfaces and boxes."""
    cloud = small_room()
    res = refine_cloud(cloud, LRGNetConfig())
    s = scores(cloud.instance_ids, res.instance_ids)
    assert s["nmi"] > 0.6 and s["ari"] > 0.4, s
    assert np.mean(res.steps_per_object) > 1


def test_layer_widths_travel_in_the_header(tmp_path: Path) -> None:
    """A narrower network is saved with its widths and loads as itself; widths that do not fit are refused."""
    narrow = LRGNet(branch_widths=(32, 32, 32, 64, 256), head_widths=(128, 64, 2))
    path = tmp_path / "narrow.pt"
    save_weights(path, narrow, weight_settings(LRGNetConfig()), {})
    net = load_network(LRGNetConfig(weights=str(path)))
    assert net.branch_widths == (32, 32, 32, 64, 256) and net.head_widths == (128, 64, 2)
    assert num_parameters(net) == num_parameters(narrow) < num_parameters(LRGNet()) // 3
    x = torch.rand(1, 8, NUM_FEATURES)
    for a, b in zip(net(x, x), narrow(x, x), strict=True):
        torch.testing.assert_close(a, b)
    blob = torch.load(path, weights_only=True)
    blob["header"]["settings"]["branch_widths"] = [64, 64, 64, 128, 512]
    torch.save(blob, path)
    with pytest.raises(InputError, match=r"narrow\.pt.*do not fit the network"):
        load_network(LRGNetConfig(weights=str(path)))


def test_weights_of_layout_3_grow_with_the_plane_features(tmp_path: Path) -> None:
    """A file trained with the plane features loads as an 18-input network and grows a room."""
    path = tmp_path / "plane.pt"
    save_weights(path, LRGNet(NUM_FEATURES + PLANE_FEATURES), weight_settings(LRGNetConfig(), plane=True), {})
    net = load_network(LRGNetConfig(weights=str(path)))
    assert net.in_features == NUM_FEATURES + PLANE_FEATURES
    res = refine_cloud(tiny_room(), LRGNetConfig(weights=str(path)))
    assert len(res.instance_ids) == len(tiny_room()) and res.segments >= 1
