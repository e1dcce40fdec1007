"""The simulator: deterministic buildings with consistent truth, a robot that never walks through walls,
scans whose points lie on the surfaces they are labelled with, MCAP files that read back exactly."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from aftershock import sources
from aftershock.pipeline.classes import NUM_CLASSES, SemanticClass
from aftershock.pipeline.errors import InputError
from aftershock.sources.simulated import open_simulated, parse_sim_uri
from aftershock.sources.simulator import (
    FAMILIES,
    PROFILES,
    Mission,
    build_scene,
    cracked_element,
    get_profile,
)
from aftershock.sources.simulator.recording import write_mission
from aftershock.sources.simulator.trajectory import (
    CLEARANCE_M,
    PROBE_HEIGHTS_M,
    TURN_RATE_RAD_S,
    plan_tour,
    segment_clear,
)

REPO = Path(__file__).resolve().parents[1]
SMALL = ("disaster", 2)  # a small two-story building keeps these tests quick
FURNITURE = {SemanticClass.TABLE, SemanticClass.CHAIR, SemanticClass.BOOKCASE, SemanticClass.CLUTTER}


@pytest.fixture(scope="module")
def scene():
    return build_scene(*SMALL)


@pytest.fixture(scope="module")
def mission(scene):
    return Mission(scene, get_profile("vlp16"), seed=SMALL[1], scans=12)


@pytest.fixture(scope="module")
def scans(mission):
    return list(mission)


# ------------------------------------------------------------------------------------------ scenes


def test_same_seed_same_building_other_seed_other_building():
    a, b, c = build_scene("office", 5), build_scene("office", 5), build_scene("office", 6)
    for name in ("vertices", "triangles", "class_ids", "instance_ids", "colors", "reflectivity"):
        assert np.array_equal(getattr(a.mesh, name), getattr(b.mesh, name)), name
    assert a.truth.instance_classes == b.truth.instance_classes
    assert a.mesh.vertices.shape != c.mesh.vertices.shape or not np.array_equal(a.mesh.vertices, c.mesh.vertices)


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_instance_ids_start_at_one_and_each_has_one_class(family):
    sc = build_scene(family, 1)
    ids = np.unique(sc.mesh.instance_ids)
    assert ids.min() == 1, "instance 0 means no object and is never a real one"
    assert set(ids.tolist()) <= set(sc.truth.instance_classes)
    # every triangle's class is its instance's class
    lut = np.zeros(ids.max() + 1, np.int64)
    for inst, cls in sc.truth.instance_classes.items():
        lut[inst] = cls
    assert np.array_equal(lut[sc.mesh.instance_ids], sc.mesh.class_ids)
    present = {SemanticClass(c) for c in np.unique(sc.mesh.class_ids)}
    assert present >= FURNITURE, "furniture appears in both families"


def test_families_differ_in_damage():
    office = [build_scene("office", s) for s in range(3)]
    disaster = [build_scene("disaster", s) for s in range(3)]
    for sc in office:
        assert SemanticClass.DEBRIS not in set(sc.mesh.class_ids.tolist())
        assert not sc.truth.cracks
        assert all(lv.drift_x_mm == lv.drift_y_mm == lv.tilt_x_deg == lv.tilt_y_deg == 0 for lv in sc.truth.levels)
    for sc in disaster:
        assert SemanticClass.DEBRIS in set(sc.mesh.class_ids.tolist())
        assert sc.truth.cracks
        upper = sc.truth.levels[1:]
        assert all(np.hypot(lv.drift_x_mm, lv.drift_y_mm) > 0 for lv in upper)
        assert all(0.05 <= max(abs(lv.tilt_x_deg), abs(lv.tilt_y_deg)) <= 1.5 for lv in upper)
        assert sc.truth.levels[0].matrix() == pytest.approx(np.eye(4))


def test_story_planes_are_where_the_floors_and_ceilings_are(scene):
    """The truth's floor/ceiling planes pass through the damaged mesh's slab faces."""
    m = scene.mesh
    normals = m.normals()
    for st in scene.truth.stories:
        # collapsed panels are separate instances, so every upward face of the floor is on the plane
        up = (m.instance_ids == st.floor_instance_id) & (normals[:, 2] > 0.99)
        v = m.vertices[m.triangles[up]].reshape(-1, 3)
        assert len(v) and np.abs(v @ st.floor_plane[:3] + st.floor_plane[3]).max() < 1e-6
        down = (m.instance_ids == st.ceiling_instance_id) & (normals[:, 2] < -0.99)
        v = m.vertices[m.triangles[down]].reshape(-1, 3)
        assert len(v) and np.abs(v @ st.ceiling_plane[:3] + st.ceiling_plane[3]).max() < 1e-6
        tilt = np.degrees(np.arccos(st.floor_plane[2]))
        assert tilt == pytest.approx(np.hypot(st.tilt_x_deg, st.tilt_y_deg), abs=0.02)


def test_cracks_lie_on_their_elements(scene):
    assert scene.truth.cracks
    for c in scene.truth.cracks:
        assert scene.truth.instance_classes[c.element_instance_id] in (
            SemanticClass.COLUMN,
            SemanticClass.WALL,
            SemanticClass.CEILING,
        )
        d = scene.raycaster.distance(c.polyline)
        assert np.median(d) < 0.01, "a crack's centre line lies on a surface"
        assert 0.0003 <= c.width_m <= 0.012 and c.depth_m > 0 and c.length_m > 0.1
        assert np.linalg.norm(c.direction) == pytest.approx(1.0)


# ------------------------------------------------------------------------------------------ sensor and motion


def test_profiles_are_data():
    vlp = get_profile("vlp16")
    assert vlp.rays == 16 * 1800 and vlp.rate_hz == 10
    dense = get_profile("dense")
    assert dense.rays == 360 * 126 and dense.max_range_m == 5.0
    for prof in PROFILES.values():
        d = prof.directions()
        assert d.shape == (prof.columns, prof.beams, 3)
        assert np.allclose(np.linalg.norm(d, axis=-1), 1.0)
        assert sorted(prof.rings().tolist()) == list(range(prof.beams))
        assert prof.times().max() < prof.sweep_s
    with pytest.raises(InputError):
        get_profile("nope")


def test_trajectory_never_crosses_a_wall(scene):
    tr = plan_tour(scene, 0, 0)
    assert tr.length > 10
    times = np.arange(0.0, tr.period_s, 0.05)
    assert tr.grid.is_free(tr.xy_at(times)).all(), "every position is in a free cell"
    assert segment_clear(scene, tr, times).all(), "no move between two positions passes through a surface"
    floor = tr.grid.floor_matrix
    xy = tr.xy_at(times)
    for h in PROBE_HEIGHTS_M:
        body = np.c_[xy, np.full(len(xy), tr.grid.floor_z + h)] @ floor[:3, :3].T + floor[:3, 3]
        assert scene.raycaster.distance(body).min() > CLEARANCE_M * 0.7
    poses = tr.poses(times)
    assert np.allclose(np.linalg.det(poses[:, :3, :3]), 1.0)
    heights = poses[:, 2, 3] - tr.grid.floor_z
    assert (heights > 0.8).all() and (heights < 1.0).all()
    speed = np.linalg.norm(np.diff(poses[:, :2, 3], axis=0), axis=1) / 0.05
    assert speed.max() < 1.5, "walking speed"
    yaw = np.unwrap(tr._at(times, tr.yaw))
    assert np.abs(np.diff(yaw)).max() / 0.05 <= TURN_RATE_RAD_S + 1e-6, "no spinning on the spot"
    ends = np.array([0.0, tr.period_s - 1e-9])
    assert tr.xy_at(ends)[0] == pytest.approx(tr.xy_at(ends)[1], abs=1e-6), "the loop closes"
    heading = tr._at(ends, tr.yaw)
    assert np.cos(heading[0] - heading[1]) == pytest.approx(1.0, abs=1e-6), "facing the same way"


def test_points_lie_on_the_surfaces_they_are_labelled_with(scene, mission, scans):
    """Each point, moved by the true pose at its own time, lands on the mesh; its label is the surface's."""
    start = scans[0].stamp_ns
    for scan in scans[::4]:
        assert scan.has_ground_truth and scan.gt_pose is not None
        t = (scan.stamp_ns - start) * 1e-9 + scan.times
        poses = mission.trajectory.poses(t)
        world = np.einsum("nij,nj->ni", poses[:, :3, :3], scan.points) + poses[:, :3, 3]
        d = scene.raycaster.distance(world)
        assert np.median(d) < 0.015 and np.percentile(d, 99) < 0.07  # range noise sigma 15 mm
        # the pose at the stamp is the published one
        assert mission.trajectory.poses(np.array([t[0] - scan.times[0]]))[0] == pytest.approx(scan.gt_pose)
        # ignoring the motion during the sweep leaves the points measurably off the surfaces
        naive = scan.points @ scan.gt_pose[:3, :3].T + scan.gt_pose[:3, 3]
        assert np.percentile(scene.raycaster.distance(naive), 90) > np.percentile(d, 90)
        assert scan.times.min() >= 0 and scan.times.max() < 0.1
        assert (np.diff(scan.times) >= -1e-4).sum() > 0.9 * len(scan)


def test_class_histogram_is_plausible(scans):
    cls = np.concatenate([s.class_ids for s in scans])
    hist = np.bincount(cls, minlength=NUM_CLASSES) / len(cls)
    structure = hist[[SemanticClass.CEILING, SemanticClass.FLOOR, SemanticClass.WALL, SemanticClass.COLUMN]].sum()
    assert 0.5 < structure < 0.98
    assert hist[SemanticClass.WALL] > 0.2
    assert (hist > 0).sum() >= 8, "a rich class mix"
    inst = np.concatenate([s.instance_ids for s in scans])
    assert inst.min() >= 1


# ------------------------------------------------------------------------------------------ outputs


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_same_seed_gives_byte_identical_mcap_and_identical_scans(tmp_path, scans):
    paths = []
    for i in range(2):
        sc = build_scene(*SMALL)
        m = Mission(sc, get_profile("vlp16"), seed=SMALL[1], scans=4)
        again = list(m)
        for a, b in zip(again, scans[:4], strict=True):
            for name in ("points", "intensity", "colors", "times", "ring", "class_ids", "instance_ids", "gt_pose"):
                assert np.array_equal(getattr(a, name), getattr(b, name)), name
            assert a.stamp_ns == b.stamp_ns
        p = tmp_path / f"m{i}.mcap"
        write_mission(p, again, truth=sc.truth, metadata={"seed": "2"})
        paths.append(p)
    assert _sha(paths[0]) == _sha(paths[1])
    other = tmp_path / "other.mcap"
    write_mission(other, Mission(build_scene("disaster", 3), get_profile("vlp16"), seed=3, scans=4))
    assert _sha(other) != _sha(paths[0])


def test_mcap_reads_back_through_sources_open(tmp_path, scene, scans):
    path = tmp_path / "mission.mcap"
    write_mission(path, scans, truth=scene.truth, metadata={"family": "disaster"})
    back = list(sources.open(path))
    assert len(back) == len(scans)
    for a, b in zip(scans, back, strict=True):
        assert a.stamp_ns == b.stamp_ns
        assert np.array_equal(a.points, b.points), "coordinates are float32-exact"
        assert np.array_equal(a.class_ids, b.class_ids) and np.array_equal(a.instance_ids, b.instance_ids)
        assert np.array_equal(a.colors, b.colors) and np.array_equal(a.intensity, b.intensity)
        assert np.abs(a.times - b.times).max() < 1e-9
        assert b.gt_pose == pytest.approx(a.gt_pose, abs=1e-9)
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        assert topics == {
            "/lidar/points": "sensor_msgs/msg/PointCloud2",
            "/ground_truth/pose": "geometry_msgs/msg/PoseStamped",
        }
        truth = json.loads(next(iter(reader.iter_attachments())).data)
    assert truth["stories"][1]["drift_x_mm"] == scene.truth.stories[1].drift_x_mm
    assert len(truth["cracks"]) == len(scene.truth.cracks)


def test_rerun_opens_the_mcap_as_points(tmp_path, scene, scans):
    """The Rerun viewer's own MCAP importer turns the mission into point clouds, all points kept."""
    from rrd_read import read_rrd

    path, rrd = tmp_path / "mission.mcap", tmp_path / "mission.rrd"
    write_mission(path, scans[:3], truth=scene.truth)
    rerun = Path(sys.executable).with_name("rerun")
    env = dict(os.environ, CI="true", RERUN_ANALYTICS="0")
    done = subprocess.run(
        [str(rerun), "mcap", "convert", str(path), "-o", str(rrd)], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    rows = read_rrd(rrd).rows("lidar/points", "Points3D:positions")
    assert [len(r) for r in rows] == [len(s) for s in scans[:3]]


def test_sim_uri_streams_the_same_scans(scans):
    spec = parse_sim_uri("sim://disaster?seed=2&sensor=vlp16&scans=12")
    assert (spec.family, spec.seed, spec.sensor, spec.scans) == ("disaster", 2, "vlp16", 12)
    got = list(sources.open("sim://disaster?seed=2&sensor=vlp16", max_scans=3, every=2))
    assert [s.seq for s in got] == [0, 2, 4]
    for a in got:
        assert np.array_equal(a.points, scans[a.seq].points)
        assert np.array_equal(a.class_ids, scans[a.seq].class_ids)
    late = list(open_simulated("sim://disaster?seed=2&scans=12", start_s=0.55, end_s=0.8))
    assert [s.seq for s in late] == [6, 7, 8]
    for bad in ("sim://atlantis", "sim://office?seed=x", "sim://office?colour=red", "sim://office?sensor=hdl64"):
        with pytest.raises(InputError):
            list(sources.open(bad))


def test_static_scan_is_labelled_and_on_the_surfaces(scene):
    cloud = scene.sample_static_cloud(spacing_m=0.1, seed=0)
    assert len(cloud) > 20_000
    keys = np.floor(cloud.points / 0.1).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == len(cloud), "one point per voxel"
    assert cloud.instance_ids.min() >= 1
    classes = set(np.unique(cloud.class_ids).tolist())
    assert {SemanticClass.FLOOR, SemanticClass.CEILING, SemanticClass.WALL, SemanticClass.COLUMN} <= classes
    d = scene.raycaster.distance(cloud.points[::20])
    assert np.percentile(d, 99) < 0.01
    # every story is covered, floors and ceilings alike
    for st in scene.truth.stories:
        for plane in (st.floor_plane, st.ceiling_plane):
            on = np.abs(cloud.points @ plane[:3] + plane[3]) < 0.02
            assert on.sum() > 1000


@pytest.mark.parametrize("kind", ["column", "wall", "slab", "beam"])
def test_cracked_element(kind):
    spacing = 0.01 if kind == "slab" else 0.004
    cloud, mask, cracks = cracked_element(kind, 4, spacing)
    assert len(cloud) == len(mask) and mask.dtype == bool
    assert 0.02 < mask.mean() < 0.2, "crack share like the field data"
    assert cracks and all(c.length_m > 0.05 and 0 < c.width_m <= 0.03 for c in cracks)
    # crack points are darker and lie below the surface around them
    lum = cloud.colors.astype(float).mean(1)
    assert lum[mask].mean() < lum[~mask].mean() - 10
    normal = cracks[0].normal
    face = np.abs(cloud.points @ normal - cracks[0].center @ normal) < 0.05
    depth = cloud.points @ normal - cracks[0].center @ normal
    assert np.median(depth[face & mask]) < np.median(depth[face & ~mask])
    # every crack point lies (in the plane of its face) inside the opening of a crack on that face
    from aftershock.sources.simulator.damage import distance_to_polylines

    faces = sorted({tuple(c.normal) for c in cracks})
    levels = [next(c.center @ np.asarray(n) for c in cracks if tuple(c.normal) == n) for n in faces]
    signed = np.stack([cloud.points @ np.asarray(n) - lv for n, lv in zip(faces, levels, strict=True)], axis=1)
    for i, n in enumerate(faces):
        on_face = [c for c in cracks if tuple(c.normal) == n]
        n_arr, level = np.asarray(n), levels[i]
        others = np.delete(signed, i, axis=1)
        clear = (others < -0.06).all(axis=1) if others.shape[1] else np.ones(len(cloud), bool)
        pts = cloud.points[mask & (np.abs(signed[:, i]) < 0.06) & clear]  # away from the column's corner
        flat = pts - np.outer(pts @ n_arr - level, n_arr)
        a = np.concatenate([c.polyline[:-1] for c in on_face])
        b = np.concatenate([c.polyline[1:] for c in on_face])
        w = np.concatenate([np.c_[c.widths[:-1], c.widths[1:]] for c in on_face])
        d, _ = distance_to_polylines(flat, a, b, w)
        assert np.percentile(d, 99) < 0.002  # grid jitter and scanner noise
    # the same cracks at another spacing
    _, _, again = cracked_element(kind, 4, spacing * 2)
    assert [c.length_m for c in again] == [c.length_m for c in cracks]
    assert cloud.class_ids[0] == (SemanticClass.FLOOR if kind == "slab" else SemanticClass[kind.upper()])


def test_simulate_command(tmp_path):
    exe = Path(sys.executable).with_name("aftershock")
    out, ply, truth = tmp_path / "m.mcap", tmp_path / "s.ply", tmp_path / "t.json"
    args = [str(exe), "simulate", "--out", str(out), "--scene", "office", "--seed", "1", "--scans", "3"]
    proc = subprocess.run(
        [*args, "--static-out", str(ply), "--static-spacing", "0.2", "--truth-out", str(truth), "--json"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["scans"] == 3 and summary["points_per_scan"] > 10_000
    assert summary["class_histogram"]["wall"] > 0
    from aftershock.pipeline.cloud_io import read_cloud

    cloud = read_cloud(ply)
    assert cloud.class_ids is not None and cloud.instance_ids.min() >= 1
    assert json.loads(truth.read_text())["family"] == "office"
    again = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and "already exists" in again.stderr
    bad = subprocess.run([*args[:3], str(tmp_path / "x.mcap"), "--scene", "moon"], capture_output=True, text=True)
    assert bad.returncode == 2 and "unknown scene generator" in bad.stderr and "Traceback" not in bad.stderr


def test_sample_recording_is_a_small_labelled_mission():
    path = REPO / "recordings" / "sample.mcap"
    assert path.stat().st_size <= 5 * 1024 * 1024
    scans = list(sources.open(path))
    assert len(scans) >= 20
    assert all(s.has_ground_truth and s.gt_pose is not None and s.times is not None for s in scans)


def test_cracked_element_variety_and_intact():
    """Branches start on their parent crack; openings vary along a crack; the same element without cracks has
    no crack point."""
    from aftershock.sources.simulator.damage import distance_to_polylines

    branched = 0
    for seed in range(6):
        cloud, mask, cracks = cracked_element("wall", seed, 0.006)
        for i, c in enumerate(cracks):
            others = [o for j, o in enumerate(cracks) if j != i]
            if others and len(c.polyline) == 8:  # a branch: its first point lies on another crack's opening
                a = np.concatenate([o.polyline[:-1] for o in others])
                b = np.concatenate([o.polyline[1:] for o in others])
                w = np.concatenate([np.c_[o.widths[:-1], o.widths[1:]] for o in others])
                d, _ = distance_to_polylines(c.polyline[:1], a, b, w)
                branched += int(d[0] <= 1e-9)
        # tapering to the ends, varying between: the widest point well above the typical opening
        assert np.median([c.widths.max() / np.median(c.widths) for c in cracks]) > 1.3
    assert branched >= 1
    cloud, mask, cracks = cracked_element("column", 3, 0.006, intact=True)
    assert len(cloud) > 1000 and not mask.any() and cracks == []
