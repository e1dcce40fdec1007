"""MCPNet's shape features at two scales (#12), the recorded feature layout, and how training drops colour."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aftershock.models.mcpnet import (
    MCPNet,
    geometry_features,
    load_model,
    point_inputs,
    save_weights,
    wide_geometry_features,
)
from aftershock.models.mcpnet_train import Pool, mcpnet_config, open_uri, stage_mission
from aftershock.models.netconfig import (
    COARSE_GEOMETRY_FEATURES,
    GEOMETRY_FEATURES,
    POINT_FEATURES,
    TRANSFER_FEATURES,
    NetConfig,
)
from aftershock.pipeline.errors import InputError


def _patch(kind: str, rng: np.random.Generator, n: int = 50) -> np.ndarray:
    u, v = rng.uniform(-0.15, 0.15, n), rng.uniform(-0.15, 0.15, n)
    z = np.zeros(n)
    return {
        "floor": np.c_[u, v, z],
        "wall": np.c_[u, z, v],
        "pole": np.c_[z + rng.normal(0, 0.003, n), z + rng.normal(0, 0.003, n), u],
        "clutter": rng.uniform(-0.15, 0.15, (n, 3)),
    }[kind]


def test_geometry_features_tell_floor_wall_pole_and_clutter_apart() -> None:
    rng = np.random.default_rng(0)
    kinds = ("floor", "wall", "pole", "clutter")
    offsets = np.stack([_patch(k, rng) for k in kinds])
    mask = np.ones(offsets.shape[:2], bool)
    g = dict(zip(kinds, geometry_features(offsets, mask), strict=True))
    nz, plan, lin, sph, dz = (GEOMETRY_FEATURES.index(n) for n in GEOMETRY_FEATURES)
    assert g["floor"][nz] > 0.99 and g["wall"][nz] < 0.05
    assert g["floor"][plan] > 0.6 and g["wall"][plan] > 0.6 and g["clutter"][plan] < 0.5
    assert g["pole"][lin] > 0.9 and g["clutter"][sph] > 0.3
    assert g["floor"][dz] < 0.01 and g["wall"][dz] > 0.5
    # turning about z changes nothing; too few neighbours give zeros
    c, s = np.cos(0.7), np.sin(0.7)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    assert np.allclose(geometry_features(offsets @ rot.T, mask), geometry_features(offsets, mask), atol=1e-5)
    few = mask.copy()
    few[:, 2:] = False
    assert not geometry_features(offsets, few).any()


def test_the_wider_view_sees_what_lies_above_and_below() -> None:
    """A table top: the wider context reaches down to the floor 0.7 m below; absent neighbours count for nothing."""
    rng = np.random.default_rng(1)
    top = np.c_[rng.uniform(-0.4, 0.4, (20, 2)), np.zeros(20)]
    floor = np.c_[rng.uniform(-0.7, 0.7, (12, 2)), np.full(12, -0.7)]
    offsets = np.r_[top, floor][None]
    mask = np.ones((1, 32), bool)
    mask[0, -2:] = False
    offsets[0, -2:, 2] = 5.0  # not drawn: must not count
    g = wide_geometry_features(offsets, mask)[0]
    assert g[COARSE_GEOMETRY_FEATURES.index("dz_max_wide")] == pytest.approx(0.0)
    assert g[COARSE_GEOMETRY_FEATURES.index("dz_min_wide")] == pytest.approx(-0.7)
    assert not wide_geometry_features(offsets, np.zeros_like(mask)).any()


def test_point_inputs_follow_the_weights_layout() -> None:
    rng = np.random.default_rng(2)
    base = rng.normal(size=(4, len(POINT_FEATURES))).astype(np.float32)
    offsets, wide = rng.normal(size=(4, 50, 6)), rng.normal(size=(4, 32, 3))
    mask, wide_mask = np.ones((4, 50), bool), np.ones((4, 32), bool)
    cfg = mcpnet_config()
    x = point_inputs(cfg, base, offsets, mask, wide, wide_mask)
    assert x.shape == (4, len(TRANSFER_FEATURES)) and "x" not in cfg.features and "y" not in cfg.features
    np.testing.assert_array_equal(x[:, cfg.features.index("z")], base[:, 2])
    np.testing.assert_allclose(x[:, cfg.features.index("planarity")], geometry_features(offsets[..., :3], mask)[:, 1])
    np.testing.assert_array_equal(point_inputs(NetConfig(), base), base)  # the baselines' layout


def test_the_layout_is_checked_by_name(tmp_path: Path) -> None:
    cfg = mcpnet_config()
    path = tmp_path / "mcpnet.pt"
    save_weights(path, MCPNet(cfg), cfg, {})
    _, loaded, _ = load_model(path, kind="mcpnet")
    assert loaded.features == TRANSFER_FEATURES and loaded.coarse_points > 0
    n = len(TRANSFER_FEATURES)
    refused = {
        # the rejected candidate of the session before (7 point + 5 shape features, no wider context)
        "candidate.pt": NetConfig(point_dim=12, features=POINT_FEATURES + GEOMETRY_FEATURES),
        # the wider features without the wider context to compute them from
        "nowide.pt": NetConfig(point_dim=n, features=TRANSFER_FEATURES),
        # a baseline cannot read shape (it has no context to compute it from)
        "nocontext.pt": NetConfig(kind="mcpnet-nocontext", point_dim=n, features=TRANSFER_FEATURES),
    }
    for name, bad in refused.items():
        save_weights(tmp_path / name, MCPNet(bad), bad, {})
        with pytest.raises(InputError, match=rf"{name.replace('.', '[.]')}: .*aftershock train mcpnet --force"):
            load_model(tmp_path / name)


def test_color_is_dropped_per_mission() -> None:
    """A robot without a camera has no colour for the whole log: training drops it mission by mission."""
    cfg = mcpnet_config()
    missions = [stage_mission(open_uri(f"sim://office?seed={s}&scans=3"), cfg) for s in (5, 6)]
    pool = Pool(missions)
    assert pool.wide.shape[1] == cfg.coarse_points and (pool.wide >= 0).mean() > 0.9
    idx = np.arange(len(pool))
    has = cfg.features.index("has_color")
    seen = set()
    for seed in range(8):
        pf, ctx, _, wide, _ = pool.features(idx, np.random.default_rng(seed), True, cfg, 0.5, per_mission=True)
        for m in (0, 1):
            flags = np.unique(pf[pool.mission == m, has])
            assert len(flags) == 1  # all of a mission's points with colour, or none
            seen.add((m, float(flags[0])))
            if flags[0] == 0.0:
                assert not ctx[pool.mission == m, :, 3:6].any()
        assert wide.shape == (len(pool), cfg.coarse_points, 3)
    assert len(seen) == 4  # both missions were shown both ways


def test_weights_with_a_wider_view_run_through_the_stream(tmp_path: Path) -> None:
    """The labeller reads the layout from the weights file and computes both scales of shape itself."""
    from aftershock import sources
    from aftershock.pipeline.config import load_config
    from aftershock.pipeline.stream import run_stream
    from aftershock.pipeline.types import RunInfo

    path = tmp_path / "wide.pt"
    save_weights(path, MCPNet(mcpnet_config()), mcpnet_config(), {})
    cfg = load_config(None, [f"label.weights={path}"])
    uri = "sim://wing?seed=3&scans=4&color=0"
    res = run_stream(sources.open(uri), cfg, [], RunInfo(source=uri, source_kind="sim"), lambda _t: None)
    assert len(res.vmap) > 1000 and res.labeller == "mcpnet"


def test_training_missions_never_touch_the_held_out_generator_or_seeds() -> None:
    from aftershock.models import transfer_split as split
    from aftershock.models.mcpnet_train import TRANSFER_SCANS, transfer_uris

    uris = transfer_uris(split.TRAIN_SEEDS, TRANSFER_SCANS)
    assert len(uris) == len(split.TRAIN_SEEDS) * len(split.TRAIN_GENERATORS)
    assert not any(split.HELDOUT_GENERATOR in u for u in uris)
    seeds = {int(u.split("seed=")[1].split("&")[0]) for u in uris}
    assert seeds == set(split.TRAIN_SEEDS) and not seeds & set(split.VALIDATION_SEEDS + split.TEST_SEEDS)


def test_logs_without_color_get_the_color_free_network(tmp_path: Path) -> None:
    """The shipped colour-free network: the layout with shape at two scales, trained on the training generators
    only; the labeller runs it on logs without colour, and a weights file named alone serves both kinds of log."""
    from aftershock.models.mcpnet import default_weights
    from aftershock.models.transfer_split import HELDOUT_GENERATOR, TRAIN_SEEDS
    from aftershock.pipeline.config import ClusterConfig, load_config
    from aftershock.pipeline.labellers.mcpnet import NO_COLOR, MCPNetLabeller

    path = default_weights(NO_COLOR)
    assert path.name == "mcpnet_nocolor.pt" and path.stat().st_size < 5 * 1024 * 1024
    _, cfg, figures = load_model(path, kind="mcpnet")
    assert cfg.features == TRANSFER_FEATURES and cfg.coarse_points > 0
    assert set(figures["train_seeds"]) <= set(TRAIN_SEEDS) and HELDOUT_GENERATOR not in figures["generators"]
    assert not any(HELDOUT_GENERATOR in u for u in figures["missions"])
    shipped = MCPNetLabeller(load_config(None, []), ClusterConfig().beta_indoor)
    assert shipped.mono_weights == path and shipped.mono_net.features == TRANSFER_FEATURES
    assert shipped.net.features == POINT_FEATURES  # logs with colour: the families' network
    one = MCPNetLabeller(load_config(None, [f"label.weights={path}"]), ClusterConfig().beta_indoor, weights=path)
    assert one.mono_weights == path and one.net.features == TRANSFER_FEATURES
    other = tmp_path / "narrow.pt"
    narrow = NetConfig(embed_dim=8)
    save_weights(other, MCPNet(narrow), narrow, {})
    with pytest.raises(InputError, match=r"narrow\.pt: embeds in 8 dimensions"):
        MCPNetLabeller(load_config(None, []), ClusterConfig().beta_indoor, weights_no_color=other)
