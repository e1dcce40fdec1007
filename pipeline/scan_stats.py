"""Is a scan like the scans the networks learnt from? Per-scan statistics against the training distribution.

The learned labellers were trained on simulated missions (models/mcpnet_train.py, `transfer_uris`): a few
sensors of 16 and 32 beams, indoor ranges. A log whose scans differ much (an OS1-128, a terrestrial scanner, an
outdoor street) is labelled by networks that never saw its like, and nothing in the labels says so. Each scan's
statistics are compared with the range the training scans covered (`models/weights/scan_reference.json`, made by
`python -m aftershock.models.scan_reference_train`); a statistic outside it, widened by TOLERANCE either side,
gives one warning per run and reason, in the log and the run's `warnings`.

The first scan and every CHECK_EVERY-th registered scan after it are checked. Statistics (sensor frame):
`points` (returns a scan: density), `range_m` (their median range), `beams` (distinct rings, where the log has
them; not measured otherwise), `vertical_fov_deg` (elevation span, 0.5th to 99.5th percentile: the beam
pattern), `returns_per_voxel` (points kept for labelling per map voxel they fall in).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Final

import numpy as np

from aftershock.models.weights_file import WEIGHTS_DIR
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.types import Frame, Scan

REFERENCE_FILE: Final = WEIGHTS_DIR / "scan_reference.json"
TOLERANCE: Final = 0.25  # a statistic this share beyond the training range's ends is outside it
SAMPLE: Final = 4096  # points looked at for the range and elevation statistics (every k-th)
CHECK_EVERY: Final = 10  # scans checked: the first and every 10th after it (a log's sensor does not change)
MIN_RANGE_M: Final = 0.05  # nearer returns are the zeros organised clouds put where nothing returned

# statistic -> the reason a warning names, and what the statistic is in words
REASONS: Final[dict[str, tuple[str, str]]] = {
    "points": ("point density", "returns a scan"),
    "range_m": ("range", "median range (m)"),
    "beams": ("beam pattern", "beams"),
    "vertical_fov_deg": ("beam pattern", "vertical field of view (deg)"),
    "returns_per_voxel": ("returns per voxel", "returns per map voxel"),
}


@dataclass(frozen=True)
class ScanStats:
    points: int
    range_m: float
    beams: int | None  # None: the log has no ring numbers
    vertical_fov_deg: float
    returns_per_voxel: float | None  # None: nothing kept for labelling


def returns_per_voxel(kept_points: int, voxels: int) -> float | None:
    return kept_points / voxels if voxels else None


def scan_stats(scan: Scan, per_voxel: float | None) -> ScanStats:
    """The statistics of one scan in its sensor frame; `per_voxel` (returns per map voxel) comes from the
    labelling stage (`returns_per_voxel`). Returns are counted exactly; range and elevation are read from every
    k-th point (at most SAMPLE)."""
    p = scan.points
    n = len(p)
    sample = p[:: max(1, n // SAMPLE)]
    r = np.sqrt(np.einsum("ij,ij->i", sample, sample))
    ok = np.isfinite(r) & (r >= MIN_RANGE_M)
    # the zeros and NaNs organised clouds hold where nothing returned are no returns
    valid = np.isfinite(p[:, 0]) & ((p[:, 0] != 0) | (p[:, 1] != 0) | (p[:, 2] != 0))
    if ok.any():
        q = sample[ok]
        el = np.degrees(np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1])))
        lo, hi = np.percentile(el, (0.5, 99.5))
        fov, med = float(hi - lo), float(np.median(r[ok]))
    else:
        fov, med = 0.0, 0.0
    beams = None
    if scan.ring is not None and valid.any():
        beams = int(np.count_nonzero(np.bincount(scan.ring[valid])))
    return ScanStats(int(valid.sum()), med, beams, fov, per_voxel)


@dataclass(frozen=True)
class Reference:
    """The [low, high] each statistic covered over the training scans, and where that was measured."""

    bounds: dict[str, tuple[float, float]]
    measured_on: str

    @classmethod
    def load(cls, path: Path = REFERENCE_FILE) -> Reference:
        try:
            data = json.loads(Path(path).read_text())
            bounds = {k: (float(v["low"]), float(v["high"])) for k, v in data["statistics"].items()}
            return cls(bounds, str(data.get("measured_on", "")))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(
                f"not a readable scan reference ({exc}); `python -m aftershock.models.scan_reference_train`", path
            ) from None

    def outside(self, stats: ScanStats) -> list[tuple[str, float, tuple[float, float]]]:
        """(statistic, value, training range) of every measured statistic outside the widened range."""
        out = []
        for name, value in asdict(stats).items():
            if value is None or name not in self.bounds:
                continue
            lo, hi = self.bounds[name]
            if value < lo * (1 - TOLERANCE) or value > hi * (1 + TOLERANCE):
                out.append((name, float(value), (lo, hi)))
        return out


def _figure(v: float) -> str:
    return f"{v:,.0f}" if abs(v) >= 100 else f"{v:.3g}"


class DistributionCheck:
    """Warns once per run and reason when a scan lies outside what the networks were trained on."""

    def __init__(self, reference: Reference, notice: Callable[[str], None]) -> None:
        self.reference = reference
        self.notice = notice
        self.warnings: list[str] = []
        self._said: set[str] = set()
        self._seen = 0

    def check(self, frame: Frame) -> None:
        if frame.map_rows is None or not frame.registration_ok:
            return
        self._seen += 1
        if (self._seen - 1) % CHECK_EVERY:
            return
        rpv = returns_per_voxel(len(frame.map_rows.points), len(frame.map_rows.first_points))
        for name, value, (lo, hi) in self.reference.outside(scan_stats(frame.scan, rpv)):
            reason, words = REASONS[name]
            if reason in self._said:
                continue
            self._said.add(reason)
            text = (
                f"{reason} outside the training data (first at scan {frame.seq}): {words} {_figure(value)}, the "
                f"networks were trained on {_figure(lo)}-{_figure(hi)}; its labels may be wrong"
            )
            self.warnings.append(text)
            self.notice(text)
