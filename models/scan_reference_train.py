"""`python -m aftershock.models.scan_reference_train [OUT]`: the per-scan statistics of MCPNet's training missions.

The missions are those `aftershock train mcpnet` stages (`transfer_uris` over the training seeds: every training
generator, a sensor and a robot drawn per mission, randomised conditions), every EVERY-th scan; each scan is cut
to the indoor labelling range and put in a voxel map cell grid with its true pose, as training stages it. Writes
the low and high of each statistic of pipeline.scan_stats to OUT (default: the shipped
models/weights/scan_reference.json), which the stream's distribution check reads. About 5 minutes on one core.
"""

from __future__ import annotations

import json
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Final

import numpy as np

from aftershock.models.mcpnet_train import TRAIN_SEEDS, TRANSFER_SCANS, transfer_uris
from aftershock.pipeline.config import Config
from aftershock.pipeline.scan_stats import REFERENCE_FILE, ScanStats, returns_per_voxel, scan_stats
from aftershock.pipeline.types import Scan

EVERY: Final = 10  # scans of a mission measured (consecutive scans of one sensor differ little)


def kept_per_voxel(scan: Scan, range_m: float, voxel_m: float) -> float | None:
    """Returns kept for labelling (horizontal range in the sensor frame) per voxel of the world map they fill."""
    p = scan.points
    keep = np.isfinite(p).all(axis=1) & (np.hypot(p[:, 0], p[:, 1]) <= range_m)
    pose = scan.gt_pose if scan.gt_pose is not None else np.eye(4)
    world = p[keep] @ pose[:3, :3].T + pose[:3, 3]
    voxels = len(np.unique(np.floor(world / voxel_m).astype(np.int64), axis=0))
    return returns_per_voxel(int(keep.sum()), voxels)


def measure(uris: list[str], every: int = EVERY) -> list[ScanStats]:
    from aftershock import sources

    cfg = Config()
    out = []
    for i, uri in enumerate(uris):
        for scan in sources.open(uri, every=every):
            out.append(scan_stats(scan, kept_per_voxel(scan, cfg.label.indoor_range_m, cfg.map.voxel_size_m)))
        print(f"{i + 1}/{len(uris)} {uri}: {len(out)} scans", file=sys.stderr)
    return out


def reference(stats: list[ScanStats], measured_on: str) -> dict[str, object]:
    table: dict[str, dict[str, float]] = {}
    for name in asdict(stats[0]):
        values = np.array([v for s in stats if (v := asdict(s)[name]) is not None], np.float64)
        if len(values):
            p1, p99 = np.percentile(values, (1, 99))
            table[name] = {"low": values.min(), "high": values.max(), "p01": p1, "p99": p99}
    clean = {k: {q: round(float(x), 4) for q, x in v.items()} for k, v in table.items()}
    return {"measured_on": measured_on, "scans": len(stats), "statistics": clean}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    out = Path(args[0]) if args else REFERENCE_FILE
    uris = transfer_uris(TRAIN_SEEDS, TRANSFER_SCANS)
    what = f"every {EVERY}th scan of MCPNet's {len(uris)} training missions (transfer_uris, seeds {TRAIN_SEEDS[0]}-"
    what += f"{TRAIN_SEEDS[-1]}, {TRANSFER_SCANS} scans each)"
    data = reference(measure(uris), what)
    out.write_text(json.dumps(data, indent=2) + "\n")
    print(f"wrote {out}: {data['scans']} scans", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
