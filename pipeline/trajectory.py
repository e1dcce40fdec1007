"""Trajectory error against true poses: ATE after a rigid (SE(3), Umeyama) alignment and RPE per frame and
per metre travelled. Poses are 4 x 4 sensor -> world matrices in matching order."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(slots=True)
class TrajectoryError:
    frames: int
    path_length_m: float
    ate_rmse_m: float  # absolute trajectory error of positions, after aligning the estimate to the truth
    ate_mean_m: float
    ate_max_m: float
    rpe_trans_m: float  # RMS of the relative translation error between consecutive frames
    rpe_rot_deg: float  # RMS of the relative rotation error between consecutive frames
    drift_percent: float  # relative translation error over segments of `segment_m`, in % of their length
    segment_m: float

    def as_dict(self) -> dict:
        return asdict(self)


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """R, t, s minimising || dst - (s R src + t) || over (N, 3) corresponding points (Umeyama 1991)."""
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    r = u @ sign @ vt
    var = (xs**2).sum() / len(src)
    s = float(np.trace(np.diag(d) @ sign) / var) if with_scale and var > 0 else 1.0
    t = mu_d - s * r @ mu_s
    return r, t, s


def _rotation_angle_deg(r: np.ndarray) -> np.ndarray:
    cos = (np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _relative(poses: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    return np.linalg.inv(poses[i]) @ poses[j]


def trajectory_error(estimate: np.ndarray, truth: np.ndarray, segment_m: float = 10.0) -> TrajectoryError:
    """Compare (N, 4, 4) estimated poses with (N, 4, 4) true poses."""
    est = np.asarray(estimate, np.float64).reshape(-1, 4, 4)
    gt = np.asarray(truth, np.float64).reshape(-1, 4, 4)
    if len(est) != len(gt):
        raise ValueError(f"{len(est)} estimated poses for {len(gt)} true poses")
    n = len(est)
    steps = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1) if n > 1 else np.zeros(0)
    length = float(steps.sum())
    if n < 2:
        return TrajectoryError(n, length, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, segment_m)
    r, t, _ = umeyama(est[:, :3, 3], gt[:, :3, 3])
    aligned = est[:, :3, 3] @ r.T + t
    err = np.linalg.norm(aligned - gt[:, :3, 3], axis=1)

    i = np.arange(n - 1)
    delta = np.linalg.inv(_relative(gt, i, i + 1)) @ _relative(est, i, i + 1)
    rpe_t = np.linalg.norm(delta[:, :3, 3], axis=1)
    rpe_r = _rotation_angle_deg(delta[:, :3, :3])

    # Segments: from every frame to the first frame at least `segment_m` further along the true path.
    travelled = np.r_[0.0, np.cumsum(steps)]
    end = np.searchsorted(travelled, travelled + segment_m)
    ok = end < n
    drift = 0.0
    if ok.any():
        a, b = np.flatnonzero(ok), end[ok]
        d = np.linalg.inv(_relative(gt, a, b)) @ _relative(est, a, b)
        seg_len = travelled[b] - travelled[a]
        drift = float(np.mean(np.linalg.norm(d[:, :3, 3], axis=1) / seg_len) * 100.0)
    return TrajectoryError(
        frames=n,
        path_length_m=length,
        ate_rmse_m=float(np.sqrt(np.mean(err**2))),
        ate_mean_m=float(err.mean()),
        ate_max_m=float(err.max()),
        rpe_trans_m=float(np.sqrt(np.mean(rpe_t**2))),
        rpe_rot_deg=float(np.sqrt(np.mean(rpe_r**2))),
        drift_percent=drift,
        segment_m=segment_m,
    )
