"""New voxels the structure model already explains skip the network (#28): on a confirmed element when they
arrive, they take its class, its confidence and an embedding the clustering joins to the element's object."""

from __future__ import annotations

import numpy as np

from aftershock import sources
from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.classes import SemanticClass as C
from aftershock.pipeline.config import Environment, load_config
from aftershock.pipeline.label import label_frame
from aftershock.pipeline.labellers.mcpnet import MCPNetLabeller
from aftershock.pipeline.stream import StreamResult, run_stream
from aftershock.pipeline.structure import StructureModel
from aftershock.pipeline.types import Frame, RunInfo
from aftershock.pipeline.voxel_map import VoxelMap

MISSION = "sim://office?seed=3&sensor=vlp16&scans=15&robot=wheeled&height=1&speed=1&turn=45&color=0"


def _run(*overrides: str, uri: str = MISSION) -> StreamResult:
    cfg = load_config(None, list(overrides))
    return run_stream(sources.open(uri), cfg, [], RunInfo(source=uri, source_kind="sim"), lambda _t: None)


def test_voxels_on_a_confirmed_element_skip_the_network_and_keep_class_confidence_and_object() -> None:
    res = _run()
    model, vmap = res.structure, res.vmap
    assert model is not None
    n = len(vmap)
    given = np.flatnonzero(~model.has_net[:n])
    assert len(given) > 0.1 * n  # a good share of an office lies on its floor and walls when first seen
    assert res.labeller == "mcpnet"
    # the classes the structure gave are the elements' (or what its fusion made of them at the end)
    on = model.elem[given] >= 0
    assert on.mean() > 0.95
    assert np.array_equal(vmap.class_ids[given[on]], model.kind_cls[given[on]])
    # a confidence from the element's support (its voxels), as the fusion gives every voxel on an element
    assert (vmap.scores[given[on]] > 0).all()
    assert np.array_equal(vmap.scores[given[on]], model.fused_score[given[on]])
    # each joined an object with the network-labelled voxels of its element, not one object per voxel; those the
    # openings (found at the end of the run) made window or door left their wall and are not the skip's to judge
    opening = np.isin(vmap.class_ids[given], [int(C.WINDOW), int(C.DOOR)])
    inst = vmap.instance_ids[given[~opening]]
    # no more of them in no object (id 0: fragments too small, see pipeline.cluster) than of the network's voxels
    assert (inst == 0).mean() <= (vmap.instance_ids[:n][model.has_net[:n]] == 0).mean() + 0.01
    inst = inst[inst > 0]
    labelled = np.zeros(int(vmap.instance_ids[:n].max()) + 1, bool)
    labelled[vmap.instance_ids[:n][model.has_net[:n]]] = True
    assert labelled[inst].mean() > 0.95
    sizes = np.bincount(vmap.instance_ids[:n])
    assert (sizes[inst] > 1).mean() > 0.99


def test_without_the_skip_the_network_labels_every_voxel() -> None:
    res = _run("structure.skip_explained=false")
    assert res.structure is not None
    assert res.structure.has_net[: len(res.vmap)].all()


def test_a_log_with_colour_skips_only_when_asked() -> None:
    """With colour the skip cost the validation missions objects and mean IoU: off unless asked for."""
    coloured = MISSION.replace("color=0", "color=1")
    for asked in (False, True):
        res = _run(f"structure.skip_with_colour={str(asked).lower()}", uri=coloured)
        assert res.structure is not None
        assert bool((~res.structure.has_net[: len(res.vmap)]).any()) == asked


class _Counting(MCPNetLabeller):
    """The shipped network, counting the voxels it is given."""

    counted: list[int]

    def label(self, vmap: VoxelMap, new_rows: np.ndarray, frame: Frame) -> np.ndarray:
        self.counted.append(len(new_rows))
        return super().label(vmap, new_rows, frame)


def test_the_network_is_given_only_the_voxels_the_structure_does_not_explain_and_apply_writes_only_changes() -> None:
    cfg = load_config()
    labeller = _Counting(cfg, cfg.cluster.link_beta(Environment.INDOOR))
    labeller.counted = []
    vmap = VoxelMap.from_config(cfg.map, labeller.embedding_dim)
    model = StructureModel(cfg.structure, Environment.INDOOR, vmap.voxel_size)
    given = 0
    written: list[float] = []  # share of the map `apply` wrote, per scan
    for scan in sources.open(MISSION):  # the true poses: the map is levelled
        pose = scan.gt_pose
        assert pose is not None
        frame = Frame(scan, pose=pose, world_points=scan.points @ pose[:3, :3].T + pose[:3, 3])
        label_frame(frame, vmap, labeller, cfg.label.indoor_range_m, model.explain)
        rows = frame.map_rows
        assert rows is not None
        assert labeller.counted[-1] == len(rows.new_rows) - len(rows.given)
        assert np.isin(rows.given, rows.new_rows).all()
        assert (vmap.class_ids[rows.given] == model.kind_cls[rows.given]).all()
        # the labeller's instance votes count them with the element's class and confidence
        assert (labeller.raw_class[rows.given] == vmap.class_ids[rows.given]).all()
        given += len(rows.given)
        assert frame.rewritten is not None  # the rows its instance votes rewrote
        model.update(vmap, float(pose[2, 3]))
        model.apply(vmap, frame.rewritten)
        # only the rows whose class changed were written, yet the map holds the structure's class wherever it
        # has a say and the labeller's own elsewhere
        n = len(vmap)
        written.append(model.last_applied / n)
        fused = model.fused[:n]
        expected = np.where(fused != UNLABELLED, fused, model.lab_cls[:n])
        assert np.array_equal(vmap.class_ids[:n], expected)
    assert given > 0.1 * len(vmap)
    assert np.mean(written[5:]) < 0.5
    assert sum(labeller.counted) + given == len(vmap)
