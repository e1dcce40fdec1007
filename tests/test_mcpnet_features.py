"""MCPNet's geometry features (#12) and the recorded feature layout."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aftershock.models.mcpnet import MCPNet, geometry_features, load_model, save_weights
from aftershock.models.mcpnet_train import transfer_config
from aftershock.models.netconfig import GEOMETRY_FEATURES, POINT_FEATURES, NetConfig
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


def test_both_layouts_run_and_others_are_refused(tmp_path: Path) -> None:
    new = transfer_config()
    assert new.features == POINT_FEATURES + GEOMETRY_FEATURES and new.geometry and new.point_dim == 12
    path = tmp_path / "transfer.pt"
    save_weights(path, MCPNet(new), new, {})
    _, cfg, _ = load_model(path, kind="mcpnet")
    assert cfg.geometry
    old = NetConfig()
    save_weights(tmp_path / "old.pt", MCPNet(old), old, {})
    assert not load_model(tmp_path / "old.pt")[1].geometry
    # a PointNet cannot read geometry (it has no context to compute it from)
    odd = NetConfig(kind="pointnet", point_dim=12, features=new.features)
    from aftershock.models.pointnet import PointNet

    save_weights(tmp_path / "pn.pt", PointNet(odd), odd, {})
    with pytest.raises(InputError, match=r"pn\.pt: weights use feature layout .*aftershock train mcpnet"):
        load_model(tmp_path / "pn.pt")


def test_widened_network_starts_where_the_trained_one_was() -> None:
    import torch

    from aftershock.models.mcpnet_train import widen

    torch.manual_seed(0)
    old = MCPNet(NetConfig())
    new = widen(old, transfer_config())
    p, c = torch.randn(8, 7), torch.randn(8, 50, 6)
    m = torch.ones(8, 50, dtype=torch.bool)
    e0, l0 = old(p, c, m)
    e1, l1 = new(torch.cat([p, torch.randn(8, 5)], dim=1), c, m)
    torch.testing.assert_close(e0, e1)
    torch.testing.assert_close(l0, l1)


def test_weights_with_geometry_run_through_the_stream(tmp_path: Path) -> None:
    """The labeller reads the layout from the weights file and computes the geometry features itself."""
    from aftershock import sources
    from aftershock.pipeline.config import load_config
    from aftershock.pipeline.stream import run_stream
    from aftershock.pipeline.types import RunInfo

    path = tmp_path / "geometry.pt"
    save_weights(path, MCPNet(transfer_config()), transfer_config(), {})
    cfg = load_config(None, [f"label.weights={path}"])
    uri = "sim://wing?seed=3&scans=4&color=0"
    res = run_stream(sources.open(uri), cfg, [], RunInfo(source=uri, source_kind="sim"), lambda _t: None)
    assert len(res.vmap) > 1000 and res.labeller == "mcpnet"
