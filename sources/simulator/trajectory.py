"""A robot's path through a story: free space on an occupancy grid, a tour of the rooms planned through it.

The grid is laid on the story's (possibly drifted and tilted) floor; a cell is free when the robot's body,
probed at three heights, keeps `CLEARANCE_M` from every surface. Paths between room waypoints are
shortest paths on the 8-connected grid, weighted to keep away from obstacles, then smoothed and
resampled. The robot walks the loop start -> rooms -> start at constant speed with a legged gait's sway.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

if TYPE_CHECKING:
    from aftershock.sources.simulator.robots import RobotSpec
    from aftershock.sources.simulator.scene import Room, Scene

CELL_M: Final = 0.1
CLEARANCE_M: Final = 0.28  # robot half width plus a margin
PROBE_HEIGHTS_M: Final = (0.4, 0.9, 1.5)
SENSOR_HEIGHT_M: Final = 0.9
WALK_SPEED_MPS: Final = 1.0
TURN_RATE_RAD_S: Final = 0.8  # fastest turn of a walking robot
TURN_M_PER_RAD: Final = 1.5  # a distance-triggered scanner also scans every ~10 degrees of turning (at 0.25 m)
WAYPOINT_TILE_M: Final = 5.0
GAIT_HZ: Final = 1.8
GAIT_TILT_DEG: Final = 0.6
GAIT_BOB_M: Final = 0.01


@dataclass(slots=True)
class FreeGrid:
    """Free cells of one story in its floor frame (undamaged x, y; the floor transform maps to the world)."""

    story: int
    floor_z: float
    floor_matrix: np.ndarray  # 4 x 4
    clearance: np.ndarray  # (nx, ny) distance to the nearest surface (min over probe heights)
    free: np.ndarray  # (nx, ny) bool: free and in the largest connected free region

    @property
    def shape(self) -> tuple[int, int]:
        return self.free.shape

    def cell_xy(self, cells: np.ndarray) -> np.ndarray:
        return (np.asarray(cells, dtype=np.float64) + 0.5) * CELL_M

    def world_point(self, cell: tuple[int, int] | np.ndarray, height: float) -> np.ndarray:
        x, y = self.cell_xy(np.asarray(cell))
        return (self.floor_matrix @ np.array([x, y, self.floor_z + height, 1.0]))[:3]

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        return np.floor(np.asarray(xy) / CELL_M).astype(np.int64)

    def is_free(self, xy: np.ndarray) -> np.ndarray:
        c = self.cell_of(xy).reshape(-1, 2)
        inside = (c >= 0).all(1) & (c[:, 0] < self.shape[0]) & (c[:, 1] < self.shape[1])
        out = np.zeros(len(c), bool)
        out[inside] = self.free[c[inside, 0], c[inside, 1]]
        return out

    def best_cell_in(self, x0: float, y0: float, x1: float, y1: float) -> tuple[int, int] | None:
        """The free cell with the most clearance inside a rectangle (None if none is free)."""
        i0, j0 = max(int(np.floor(x0 / CELL_M)), 0), max(int(np.floor(y0 / CELL_M)), 0)
        i1, j1 = min(int(np.ceil(x1 / CELL_M)), self.shape[0]), min(int(np.ceil(y1 / CELL_M)), self.shape[1])
        if i1 <= i0 or j1 <= j0:
            return None
        sub = np.where(self.free[i0:i1, j0:j1], self.clearance[i0:i1, j0:j1], -1.0)
        if sub.max() <= 0:
            return None
        i, j = np.unravel_index(int(np.argmax(sub)), sub.shape)
        return (i0 + int(i), j0 + int(j))


def free_space(scene: Scene, story: int) -> FreeGrid:
    """The occupancy grid of a story, probed against the scene's damaged mesh."""
    w, d = scene.truth.footprint_m
    nx, ny = int(np.ceil(w / CELL_M)), int(np.ceil(d / CELL_M))
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    xy = (np.stack([ii, jj], -1).reshape(-1, 2) + 0.5) * CELL_M
    mat = scene.floor_transform(story)
    fz = scene.floor_z[story]
    clear = np.full(len(xy), np.inf)
    for h in PROBE_HEIGHTS_M:
        q = np.c_[xy, np.full(len(xy), fz + h)] @ mat[:3, :3].T + mat[:3, 3]
        clear = np.minimum(clear, scene.raycaster.distance(q))
    ok = clear.reshape(nx, ny) > CLEARANCE_M
    labels, n = ndimage.label(ok)
    if n == 0:
        raise RuntimeError(f"story {story} of this scene has no free space")
    sizes = ndimage.sum(ok, labels, index=np.arange(1, n + 1))
    free = labels == (int(np.argmax(sizes)) + 1)
    # Horizontal room to move: distance to the nearest blocked cell (the probes also see floor and ceiling).
    room = ndimage.distance_transform_edt(np.pad(ok, 1))[1:-1, 1:-1] * CELL_M + CLEARANCE_M - CELL_M / 2
    return FreeGrid(story, fz, mat, room, free)


def _grid_graph(grid: FreeGrid) -> csr_matrix:
    nx, ny = grid.shape
    idx = np.arange(nx * ny).reshape(nx, ny)
    rows, cols, weights = [], [], []
    # cost of a step: its length, more where clearance is small (keeps the robot off the walls)
    penalty = 1.0 + 0.6 / np.maximum(grid.clearance, 0.05)
    for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
        ia = slice(max(0, -di), nx - max(0, di))
        ja = slice(max(0, -dj), ny - max(0, dj))
        ib = slice(max(0, di), nx - max(0, -di))
        jb = slice(max(0, dj), ny - max(0, -dj))
        a, b = grid.free[ia, ja], grid.free[ib, jb]
        a_idx, b_idx = idx[ia, ja], idx[ib, jb]
        both = a & b
        if di and dj:  # a diagonal step may not cut the corner of a blocked cell
            both &= grid.free[ib, ja] & grid.free[ia, jb]
        pa, pb = a_idx[both], b_idx[both]
        length = np.hypot(di, dj) * CELL_M
        w = length * 0.5 * (penalty.reshape(-1)[pa] + penalty.reshape(-1)[pb])
        rows += [pa, pb]
        cols += [pb, pa]
        weights += [w, w]
    r, c, wt = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    return csr_matrix((wt, (r, c)), shape=(nx * ny, nx * ny))


def _path(pred: np.ndarray, target: int) -> list[int]:
    out = [target]
    while pred[out[-1]] >= 0:
        out.append(int(pred[out[-1]]))
    return out[::-1]


@dataclass(slots=True)
class Trajectory:
    """A closed loop through a story: walked at `speed`, turning at most `TURN_RATE_RAD_S` (the robot slows
    down, or turns on the spot, where the path bends), repeated; sensor poses at any time."""

    grid: FreeGrid
    s: np.ndarray  # (M,) arc length of the samples
    xy: np.ndarray  # (M, 2) in the floor frame
    yaw: np.ndarray  # (M,) heading, unwrapped; the last sample equals the first modulo 2 pi
    time: np.ndarray  # (M,) when the robot is at each sample
    progress: np.ndarray  # (M,) metres walked plus TURN_M_PER_RAD per radian turned (triggers scans)
    waypoints: np.ndarray  # (W, 2)
    speed: float = WALK_SPEED_MPS
    gait_phase: float = 0.0
    # the robot (robots.py): sensor mount and body motion; the defaults are the legged robot's
    sensor_height_m: float = SENSOR_HEIGHT_M
    tilt_rad: float = 0.0
    sway_rad: float = float(np.deg2rad(GAIT_TILT_DEG))
    bob_m: float = GAIT_BOB_M
    gait_hz: float = GAIT_HZ

    @property
    def length(self) -> float:
        return float(self.s[-1])

    @property
    def period_s(self) -> float:
        """Time for one loop."""
        return float(self.time[-1])

    def _at(self, times: np.ndarray, values: np.ndarray) -> np.ndarray:
        t = np.mod(np.asarray(times, np.float64), self.period_s)
        return np.interp(t, self.time, values)

    def xy_at(self, times: np.ndarray) -> np.ndarray:
        return np.stack([self._at(times, self.xy[:, 0]), self._at(times, self.xy[:, 1])], axis=-1)

    def time_at_progress(self, progress: np.ndarray) -> np.ndarray:
        """When the robot has made this much progress (loops counted)."""
        p = np.asarray(progress, np.float64)
        loops, rest = np.divmod(p, self.progress[-1])
        return loops * self.period_s + np.interp(rest, self.progress, self.time)

    def poses(self, times: np.ndarray) -> np.ndarray:
        """Sensor -> world 4 x 4 poses (N, 4, 4) at `times` (seconds since the mission start)."""
        t = np.atleast_1d(np.asarray(times, np.float64))
        x, y, yaw = self._at(t, self.xy[:, 0]), self._at(t, self.xy[:, 1]), self._at(t, self.yaw)
        ph = 2 * np.pi * self.gait_hz * t + self.gait_phase
        roll = self.sway_rad * np.sin(ph)
        pitch = self.sway_rad * 0.6 * np.sin(2 * ph + 1.0) + self.tilt_rad
        z = self.grid.floor_z + self.sensor_height_m + self.bob_m * np.sin(2 * ph)
        cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
        rot = np.empty((len(t), 3, 3))
        rot[:, 0, 0], rot[:, 0, 1], rot[:, 0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
        rot[:, 1, 0], rot[:, 1, 1], rot[:, 1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
        rot[:, 2, 0], rot[:, 2, 1], rot[:, 2, 2] = -sp, cp * sr, cp * cr
        floor = self.grid.floor_matrix
        out = np.zeros((len(t), 4, 4))
        out[:, :3, :3] = floor[:3, :3] @ rot
        out[:, :3, 3] = np.c_[x, y, z] @ floor[:3, :3].T + floor[:3, 3]
        out[:, 3, 3] = 1.0
        return out


def _timing(
    s: np.ndarray, yaw: np.ndarray, speed: float, turn_rate: float = TURN_RATE_RAD_S
) -> tuple[np.ndarray, np.ndarray]:
    """Time and progress along the samples: each step takes its walking time or its turning time."""
    ds, dyaw = np.diff(s), np.abs(np.diff(yaw))
    dt = np.maximum(ds / speed, dyaw / turn_rate)
    return np.r_[0.0, np.cumsum(dt)], np.r_[0.0, np.cumsum(ds + TURN_M_PER_RAD * dyaw)]


def plan_tour(
    scene: Scene, story: int, seed: int, speed: float = WALK_SPEED_MPS, robot: RobotSpec | None = None
) -> Trajectory:
    """Start at one end of the corridor, visit every reachable room (nearest first), come back.

    `robot` sets the mount, turn rate and sway (default: the legged robot the simulator always had);
    `speed` is the driving speed."""
    rng = np.random.default_rng([scene.seed, seed, story, 11])
    grid = free_space(scene, story)
    rooms = [r for r in scene.rooms if r.story == story]
    corridor = next((r for r in rooms if r.kind == "corridor"), rooms[0])
    end = rng.integers(2)
    x0 = corridor.x0 if end == 0 else corridor.x1 - 3.0
    start = grid.best_cell_in(x0, corridor.y0, x0 + 3.0, corridor.y1)
    if start is None:
        i, j = np.argwhere(grid.free)[0]
        start = (int(i), int(j))
    goals = [c for r in rooms for c in _room_goals(grid, r)]
    graph = _grid_graph(grid)
    ny = grid.shape[1]
    flat = lambda c: int(c[0]) * ny + int(c[1])  # noqa: E731
    cur = flat(start)
    remaining = [flat(g) for g in goals]
    cells: list[int] = [cur]
    visited: list[int] = []
    while remaining:
        dist, pred = dijkstra(graph, indices=cur, return_predecessors=True)
        reach = [g for g in remaining if np.isfinite(dist[g])]
        if not reach:
            break
        nxt = min(reach, key=lambda g: dist[g])
        cells += _path(pred, nxt)[1:]
        visited.append(nxt)
        remaining = [g for g in reach if g != nxt]
        cur = nxt
    dist, pred = dijkstra(graph, indices=cur, return_predecessors=True)
    cells += _path(pred, flat(start))[1:]
    ij = np.stack([np.asarray(cells) // ny, np.asarray(cells) % ny], axis=1)
    xy = grid.cell_xy(ij)
    if len(xy) < 3:
        raise RuntimeError(f"story {story}: the robot has nowhere to go")
    xy = _smooth(xy, grid)
    s, xy = _resample(xy, 0.05)
    yaw = _heading(xy)
    # close the loop: turn on the spot at the start until facing the way the loop begins
    s, xy = np.r_[s, s[-1]], np.r_[xy, xy[-1:]]
    yaw = np.r_[yaw, yaw[0] + 2 * np.pi * np.round((yaw[-1] - yaw[0]) / (2 * np.pi))]
    turn_rate = TURN_RATE_RAD_S if robot is None else robot.turn_rate_rad_s
    time, progress = _timing(s, yaw, speed, turn_rate)
    keep = np.r_[True, np.diff(time) > 1e-9]
    wp = grid.cell_xy(np.array([[g // ny, g % ny] for g in visited])) if visited else xy[:1]
    return Trajectory(
        grid,
        s[keep],
        xy[keep],
        yaw[keep],
        time[keep],
        progress[keep],
        wp,
        speed=speed,
        gait_phase=float(rng.uniform(0, 2 * np.pi)),
        **({} if robot is None else _robot_motion(robot)),
    )


def _robot_motion(robot: RobotSpec) -> dict[str, float]:
    return {
        "sensor_height_m": robot.mount_height_m,
        "tilt_rad": float(np.deg2rad(robot.tilt_deg)),
        "sway_rad": float(np.deg2rad(robot.sway_deg)),
        "bob_m": robot.bob_m,
        "gait_hz": robot.gait_hz,
    }


def _room_goals(grid: FreeGrid, room: Room, tile_m: float = WAYPOINT_TILE_M) -> list[tuple[int, int]]:
    """The most open cell of each ~tile_m square of a room, so large rooms and corridors are walked through."""
    nx = max(round((room.x1 - room.x0) / tile_m), 1)
    ny = max(round((room.y1 - room.y0) / tile_m), 1)
    xs, ys = np.linspace(room.x0, room.x1, nx + 1), np.linspace(room.y0, room.y1, ny + 1)
    out = []
    for i in range(nx):
        for j in range(ny):
            c = grid.best_cell_in(xs[i], ys[j], xs[i + 1], ys[j + 1])
            if c is not None and grid.clearance[c] > 2 * CLEARANCE_M:
                out.append(c)
    return out


def _smooth(xy: np.ndarray, grid: FreeGrid, window: int = 9) -> np.ndarray:
    """Moving average of the cell path (closed loop), kept only where the path between the samples stays in
    free cells; near obstacles the raw cell path (which never cuts a blocked corner) is kept."""
    k = np.ones(window) / window
    pad = window // 2
    ext = np.r_[xy[-pad - 1 : -1], xy, xy[1 : pad + 1]]
    sm = np.stack([np.convolve(ext[:, i], k, mode="valid") for i in range(2)], axis=1)
    # smoothed points must sit in cells whose neighbours are all free, so short steps cannot clip a corner
    inner = FreeGrid(
        grid.story,
        grid.floor_z,
        grid.floor_matrix,
        grid.clearance,
        ndimage.binary_erosion(grid.free, np.ones((3, 3), bool)),
    )
    for grow in (0, 3, 9):
        bad = ~inner.is_free(sm)
        if grow and bad.any():
            bad = ndimage.binary_dilation(bad, iterations=grow)
        out = np.where(bad[:, None], xy, sm)
        if grid.is_free(_resample(out, 0.005)[1]).all():
            return out
    return xy


def _resample(xy: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    keep = np.r_[True, seg > 1e-9]
    s, xy = s[keep], xy[keep]
    ss = np.arange(0.0, s[-1], step)
    ss = np.r_[ss, s[-1]]
    return ss, np.stack([np.interp(ss, s, xy[:, 0]), np.interp(ss, s, xy[:, 1])], axis=1)


def _heading(xy: np.ndarray, ahead: int = 8, window: int = 9) -> np.ndarray:
    """Heading towards the point `ahead` samples on (0.4 m), unwrapped and averaged over `window` samples
    so the grid path's wiggles do not make the robot sway; at a dead end it flips by pi, which the
    turn-rate limit turns into turning on the spot."""
    d = xy[np.minimum(np.arange(len(xy)) + ahead, len(xy) - 1)] - xy
    d[-ahead:] = d[-ahead - 1]
    yaw = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    pad = window // 2
    ext = np.r_[np.full(pad, yaw[0]), yaw, np.full(pad, yaw[-1])]
    return np.convolve(ext, np.ones(window) / window, mode="valid")


def segment_clear(scene: Scene, trajectory: Trajectory, times: np.ndarray) -> np.ndarray:
    """For consecutive poses at `times`: does the straight move between them (at three body heights)
    cross no surface? One bool per move."""
    ok = np.ones(len(times) - 1, bool)
    floor = trajectory.grid.floor_matrix
    for h in PROBE_HEIGHTS_M:
        xy = trajectory.xy_at(times)
        p = np.c_[xy, np.full(len(xy), trajectory.grid.floor_z + h)] @ floor[:3, :3].T + floor[:3, 3]
        d = np.diff(p, axis=0)
        length = np.linalg.norm(d, axis=1)
        moving = length > 1e-9
        dirs = np.zeros_like(d)
        dirs[moving] = d[moving] / length[moving, None]
        t, _, _ = scene.raycaster.cast(p[:-1][moving], dirs[moving])
        sub = np.ones(len(d), bool)
        sub[moving] = t > length[moving]
        ok &= sub
    return ok
