"""The structure model's faster steps (issue #28, its cost a scan) give what the steps they replace gave, bit for
bit: the lookup tables against `np.isin` / `np.unique`, the crossing test's grids against its sets, `np.cov`'s
own steps, the longest run against `np.split`, and the RANSAC refinements that stop once their inliers repeat
against the three rounds they ran before."""

from __future__ import annotations

import numpy as np
import pytest

from aftershock.pipeline.damage.drift import fit_plane_lsq, ransac_plane
from aftershock.pipeline.structure.lookup import member, sorted_union
from aftershock.pipeline.structure.model import _cov2, _crossing_share, _longest_run, ransac_line

RNG_SEEDS = range(40)


def _crossing_by_sets(face: np.ndarray, around: np.ndarray, line: np.ndarray, thr: float, cell: float) -> float:
    """The crossing test as it was written first (sets of packed cell keys)."""
    if not len(face) or not len(around):
        return 0.0
    direction = np.array([-line[1], line[0]])
    side = around[:, :2] @ line[:2] + line[2]
    near = (np.abs(side) > 1.5 * thr) & (np.abs(side) < 3 * cell / 2)
    around, side = around[near], side[near]

    def keys(p: np.ndarray) -> np.ndarray:
        c = np.floor(np.c_[p[:, :2] @ direction, p[:, 2]] / cell).astype(np.int64)
        return (c[:, 0] << 32) ^ (c[:, 1] & 0xFFFFFFFF)

    own = keys(face)
    front, back = np.unique(keys(around[side > 0])), np.unique(keys(around[side < 0]))
    return float(np.mean(np.isin(own, front) & np.isin(own, back)))


def _ransac_line_three_rounds(
    xy: np.ndarray, thr: float, iterations: int, rng: np.random.Generator, context: np.ndarray | None
) -> tuple[np.ndarray | None, np.ndarray]:
    """`ransac_line` as it was: the same draws, always three rounds of refinement, `np.cov`."""
    n = len(xy)
    i, j = rng.integers(0, n, size=(2, iterations))
    d = xy[j] - xy[i]
    length = np.hypot(d[:, 0], d[:, 1])
    good = length > 2 * thr
    if not good.any():
        return None, np.zeros(n, bool)
    normal = np.c_[-d[good, 1], d[good, 0]] / length[good, None]
    offset = -np.einsum("ij,ij->i", normal, xy[i[good]])
    sample = xy[rng.choice(n, size=min(n, 1000), replace=False)]
    best = int(np.argmax((np.abs(sample @ normal.T + offset) < thr).sum(axis=0)))
    nb, ob = normal[best], float(offset[best])
    every = xy if context is None or not len(context) else np.concatenate([xy, context])
    for _ in range(3):
        on = np.abs(every @ nb + ob) < thr
        if on.sum() < 3:
            break
        centre = every[on].mean(axis=0)
        _, vec = np.linalg.eigh(np.cov((every[on] - centre).T))
        nb = vec[:, 0]
        ob = float(-nb @ centre)
    return np.r_[nb, ob], np.abs(xy @ nb + ob) < thr


def _ransac_plane_three_rounds(
    points: np.ndarray, thr: float, iterations: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """`ransac_plane` as it was: the same draws, always three rounds of least squares."""
    n = len(points)
    tri = points[rng.integers(0, n, size=(iterations, 3))]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    good = norm > 1e-12
    normals, tri = normals[good] / norm[good, None], tri[good]
    d = -np.einsum("ij,ij->i", normals, tri[:, 0])
    sample = points[rng.choice(n, size=min(n, 4000), replace=False)]
    best = int(np.argmax((np.abs(sample @ normals.T + d) < thr).sum(axis=0)))
    plane = np.append(normals[best], d[best])
    for _ in range(3):
        inliers = np.abs(points @ plane[:3] + plane[3]) < thr
        if inliers.sum() < 3:
            break
        plane = fit_plane_lsq(points[inliers])
    return plane, np.abs(points @ plane[:3] + plane[3]) < thr


def _wall_scene(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Points seen from above of two walls meeting at a corner, furniture, noise; and more of the block around."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 3, 600)
    wall = np.c_[t, 0.02 * rng.standard_normal(600)]
    side = np.c_[0.02 * rng.standard_normal(300), rng.uniform(0, 2, 300)]
    clutter = rng.uniform([0.5, 0.5], [2.5, 1.5], (int(rng.integers(50, 400)), 2))
    xy = np.concatenate([wall, side, clutter]) @ np.array([[np.cos(seed), np.sin(seed)], [-np.sin(seed), np.cos(seed)]])
    return xy + rng.uniform(-20, 20, 2), rng.uniform(-3, 6, (int(rng.integers(0, 500)), 2))


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_membership_and_union_tables_agree_with_isin_and_unique(seed: int) -> None:
    rng = np.random.default_rng(seed)
    size = int(rng.integers(1, 300))
    elem = rng.integers(-1, size, int(rng.integers(0, 2000))).astype(np.int32)
    ids = rng.choice(size, int(rng.integers(0, size + 1)), replace=False)
    for given in (ids, ids.tolist(), set(ids.tolist()), {int(i): None for i in ids}.keys()):
        assert np.array_equal(member(elem, given, size), np.isin(elem, ids))
    n = int(rng.integers(1, 5000))
    parts = [rng.integers(0, n, int(rng.integers(0, 3000))) for _ in range(int(rng.integers(1, 5)))]
    assert np.array_equal(sorted_union(n, *parts), np.unique(np.concatenate(parts)))


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_crossing_share_on_grids_is_the_share_on_sets(seed: int) -> None:
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0, np.pi)
    n = np.array([np.cos(angle), np.sin(angle)])
    line = np.r_[n, rng.uniform(-2, 2)]
    along = np.array([-n[1], n[0]])
    u = rng.uniform(-3, 3, 400)
    face = np.c_[(u[:, None] * along - line[2] * n) + 0.03 * rng.standard_normal((400, 2)), rng.uniform(0, 2.5, 400)]
    off = rng.uniform(-0.5, 0.5, 3000) * rng.choice([0.3, 1.0])  # both sides, or mostly near the face
    v = rng.uniform(-4, 4, 3000)
    around = np.c_[v[:, None] * along + (off - line[2])[:, None] * n, rng.uniform(-0.5, 3, 3000)]
    for cell in (0.2, 0.1):
        got = _crossing_share(face, around, line, 0.06, cell)
        assert got == _crossing_by_sets(face, around, line, 0.06, cell)
    assert _crossing_share(face, around[:0], line, 0.06, 0.2) == 0.0


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_cov_steps_and_longest_run_are_numpys_own(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(int(rng.integers(3, 4000)), 2)) * rng.uniform(0.01, 30) + rng.uniform(-50, 50, 2)
    centred = pts - pts.mean(axis=0)
    assert np.array_equal(_cov2(centred), np.cov(centred.T))
    values = np.sort(rng.exponential(rng.uniform(0.05, 1.0), int(rng.integers(1, 300))).cumsum())
    order = rng.permutation(len(values))
    gap = float(rng.uniform(0.1, 1.0))
    expected = max(np.split(order, np.flatnonzero(np.diff(values) > gap) + 1), key=len)
    assert np.array_equal(_longest_run(order, values, gap), expected)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_ransac_line_stopping_early_finds_the_line_three_rounds_found(seed: int) -> None:
    xy, context = _wall_scene(seed)
    for ctx in (None, context):
        line, on = ransac_line(xy, 0.06, 80, np.random.default_rng(seed), ctx)
        ref_line, ref_on = _ransac_line_three_rounds(xy, 0.06, 80, np.random.default_rng(seed), ctx)
        assert line is not None and ref_line is not None
        assert np.array_equal(line, ref_line) and np.array_equal(on, ref_on)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_ransac_plane_stopping_early_finds_the_plane_three_rounds_found(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-5, 5, (3000, 2))
    floor = np.c_[xy[:2000], 0.01 * rng.standard_normal(2000) + 0.002 * xy[:2000, 0]]
    clutter = np.c_[xy[2000:], rng.uniform(0, 1.5, 1000)]
    points = np.concatenate([floor, clutter])[rng.permutation(3000)]
    plane, inliers = ransac_plane(points, 0.06, 100, np.random.default_rng(seed))
    ref_plane, ref_inliers = _ransac_plane_three_rounds(points, 0.06, 100, np.random.default_rng(seed))
    assert np.array_equal(plane, ref_plane) and np.array_equal(inliers, ref_inliers)
