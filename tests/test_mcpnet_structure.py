"""The colour-free MCPNet reading the structure model's evidence (#28): staged for training as the stream gives it,
read by the labeller from the stream's live model where the weights name it, and older weights unchanged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aftershock.models.mcpnet import load_model, point_inputs, save_weights
from aftershock.models.mcpnet_train import Mission, Pool, mcpnet_config, open_uri, stage_mission, train_transfer
from aftershock.models.netconfig import STRUCTURE_FEATURES, STRUCTURE_TRANSFER_FEATURES, TRANSFER_FEATURES
from aftershock.pipeline.classes import SemanticClass
from aftershock.pipeline.structure.features import FEATURES, NOTHING_KNOWN

TRAIN_URI = "sim://office?seed=5&scans=12"
RUN_URI = "sim://office?seed=7&scans=12&color=0"


@pytest.fixture(scope="module")
def staged() -> Mission:
    return stage_mission(open_uri(TRAIN_URI), mcpnet_config(structure=True))


@pytest.fixture(scope="module")
def structure_weights(staged: Mission, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A colour-free network that reads the structure features, trained for one short epoch on one mission."""
    cfg = mcpnet_config(structure=True)
    model, _ = train_transfer(Pool([staged]), cfg, 1, 0, log=False)
    path = tmp_path_factory.mktemp("weights") / "structure.pt"
    save_weights(path, model, cfg, {})
    return path


def test_staging_gives_each_point_the_evidence_of_the_model_as_it_stood(staged: Mission) -> None:
    """The first scan's points were seen before any element was known; once the floor is found, floor points lie
    on it (height above the floor plane about 0) whatever the sensor's height."""
    assert FEATURES == STRUCTURE_FEATURES and staged.structure.shape == (len(staged.rows), len(FEATURES))
    first = staged.structure[staged.sample_scan == 0]
    assert len(first) and (first == np.asarray(NOTHING_KNOWN, np.float32)).all()
    height = staged.structure[:, FEATURES.index("height_above_floor")]
    on_floor = (staged.classes[staged.rows] == SemanticClass.FLOOR.value) & (height < NOTHING_KNOWN[0])
    assert on_floor.sum() > 200 and np.percentile(np.abs(height[on_floor]), 90) < 0.05
    walls = staged.structure[:, FEATURES.index("wall_distance")] < NOTHING_KNOWN[1]
    assert walls.mean() > 0.1  # walls were confirmed as the map grew
    # the pool keeps every training point's row of evidence; a layout without it stages none
    pool = Pool([staged])
    assert pool.structure.shape == (len(pool), len(FEATURES))
    plain = stage_mission(open_uri("sim://office?seed=5&scans=2"), mcpnet_config())
    assert plain.structure.shape == (0, len(FEATURES)) and Pool([plain]).structure.shape[1] == 0


def test_the_structure_columns_follow_the_weights_layout() -> None:
    rng = np.random.default_rng(3)
    base = rng.normal(size=(5, 7)).astype(np.float32)
    offsets, wide = rng.normal(size=(5, 50, 6)), rng.normal(size=(5, 32, 3))
    mask, wide_mask = np.ones((5, 50), bool), np.ones((5, 32), bool)
    evidence = rng.normal(size=(5, len(FEATURES))).astype(np.float32)
    cfg = mcpnet_config(structure=True)
    assert cfg.features == STRUCTURE_TRANSFER_FEATURES and cfg.structure and not mcpnet_config().structure
    x = point_inputs(cfg, base, offsets, mask, wide, wide_mask, evidence)
    np.testing.assert_array_equal(x[:, len(TRANSFER_FEATURES) :], evidence)
    np.testing.assert_array_equal(
        x[:, : len(TRANSFER_FEATURES)], point_inputs(mcpnet_config(), base, offsets, mask, wide, wide_mask)
    )


def test_weights_that_read_the_structure_run_in_the_stream(structure_weights: Path) -> None:
    """The stream hands its structure model to the labeller; the network's inputs then carry the model's evidence,
    and its labels depend on it."""
    from aftershock import sources
    from aftershock.pipeline.config import ClusterConfig, load_config
    from aftershock.pipeline.label import hand_structure
    from aftershock.pipeline.labellers.mcpnet import MCPNetLabeller
    from aftershock.pipeline.stream import run_stream
    from aftershock.pipeline.types import RunInfo

    _, net, _ = load_model(structure_weights, kind="mcpnet")
    assert net.features == STRUCTURE_TRANSFER_FEATURES
    cfg = load_config(None, [f"label.weights_no_color={structure_weights}"])
    res = run_stream(sources.open(RUN_URI), cfg, [], RunInfo(source=RUN_URI, source_kind="sim"), lambda _t: None)
    assert len(res.vmap) > 1000 and res.labeller == "mcpnet" and res.structure is not None
    assert res.structure.has_floor
    labeller = MCPNetLabeller(cfg, ClusterConfig().beta_indoor, weights_no_color=structure_weights)
    assert labeller.reads_structure and labeller.structure is None
    rows = np.arange(len(res.vmap))
    origin = res.poses[-1][:3, 3]
    blind, _ = labeller.predict_probs(res.vmap, rows, origin, 0.0, use_color=False)
    hand_structure(labeller, res.structure)
    assert labeller.structure is res.structure
    evidence = labeller.structure_evidence(res.vmap.positions, origin)
    assert (evidence[:, FEATURES.index("height_above_floor")] < NOTHING_KNOWN[0]).mean() > 0.3
    seeing, _ = labeller.predict_probs(res.vmap, rows, origin, 0.0, use_color=False)
    assert np.abs(seeing - blind).max() > 1e-3


def test_the_shipped_colour_free_weights_read_no_structure() -> None:
    """Weights trained before #28 load as before and label the same with or without the structure model."""
    from aftershock import sources
    from aftershock.pipeline.config import ClusterConfig, load_config
    from aftershock.pipeline.label import hand_structure
    from aftershock.pipeline.labellers.mcpnet import MCPNetLabeller
    from aftershock.pipeline.stream import run_stream
    from aftershock.pipeline.types import RunInfo

    cfg = load_config(None, [])
    labeller = MCPNetLabeller(cfg, ClusterConfig().beta_indoor)
    assert labeller.mono_net.features == TRANSFER_FEATURES and not labeller.reads_structure
    res = run_stream(sources.open(RUN_URI), cfg, [], RunInfo(source=RUN_URI, source_kind="sim"), lambda _t: None)
    rows = np.arange(len(res.vmap))
    origin = res.poses[-1][:3, 3]
    before, _ = labeller.predict_probs(res.vmap, rows, origin, 0.0, use_color=False)
    assert res.structure is not None
    hand_structure(labeller, res.structure)
    after, _ = labeller.predict_probs(res.vmap, rows, origin, 0.0, use_color=False)
    np.testing.assert_array_equal(after, before)
