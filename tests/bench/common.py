"""What the benchmarks share: the repository's paths, a child process that prints one JSON line, one labeller
streamed over pickled scans in its own process, and simulated scans pickled one at a time."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Final

from aftershock import sources
from aftershock.models.mcpnet_train import HELDOUT_SEEDS

REPO: Final = Path(__file__).resolve().parents[2]
DOCS: Final = REPO / "docs"
# keeps the rerun CLI from asking about analytics in every child
CHILD_ENV: Final = {"CI": "true", "RERUN_ANALYTICS": "0"}
# MCPNET_BENCH_SEEDS=900 limits the held-out seeds of MCPNet's and the objects' benchmarks, for a quicker run.
BENCH_SEEDS: Final = tuple(int(s) for s in os.environ.get("MCPNET_BENCH_SEEDS", "").split(",") if s) or HELDOUT_SEEDS


def run_child(script: str, *args: str | Path, timeout: float = 3600) -> tuple[dict[str, Any], float]:
    """Run `python -c script args...` in the repository; its last stdout line as JSON, and its wall time to exit."""
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", script, *map(str, args)],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=dict(os.environ, **CHILD_ENV),
        timeout=timeout,
    )
    wall = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1]), wall


# One run of the stream: scans from a pickle, a labeller, config overrides -> the map's scores and the run's figures.
STREAM_WORKER: Final = r"""
import json, pickle, resource, sys, tempfile
from pathlib import Path
from aftershock.pipeline.commands.evaluate import evaluate_map
from aftershock.pipeline.config import load_config
from aftershock.pipeline.stream import run_stream
from aftershock.pipeline.types import RunInfo
scans_path, labeller, overrides, rerun = sys.argv[1], sys.argv[2], json.loads(sys.argv[3]), sys.argv[4] == "1"
cfg = load_config(None, [f"label.labeller={labeller}", *overrides])
def scans():  # one scan in memory at a time, as from a log
    with open(scans_path, "rb") as f:
        while True:
            try:
                yield pickle.load(f)
            except EOFError:
                return
sinks = []
if rerun:
    from aftershock.sinks.rerun_sink import RerunSink
    sinks.append(RerunSink(Path(tempfile.mkdtemp()) / "bench.rrd", False, None, cfg.rerun))
res = run_stream(scans(), cfg, sinks, RunInfo(source=scans_path, source_kind="sim"), lambda _t: None)
out = evaluate_map(res.vmap)
out.update(
    timings=res.summary.mean_timings_ms,
    scans_per_second=res.summary.scans_per_second,
    scans=res.summary.scans,
    fragments=res.summary.fragments,
    peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    labeller=res.labeller,
)
print(json.dumps(out))
"""


def stream_labeller(
    scans: Path, labeller: str, overrides: list[str] | None = None, rerun: bool = False
) -> dict[str, Any]:
    """The whole stream with `labeller` over pickled scans, in a fresh process (so its peak memory is its own):
    `evaluate_map`'s scores with the stage timings, scans/s, fragments and peak RSS; `rerun` adds a recording."""
    out, _ = run_child(STREAM_WORKER, scans, labeller, json.dumps(overrides or []), "1" if rerun else "0")
    return out


def pickle_scans(uri: str, path: Path) -> Path:
    """Simulate once, to a file of pickled scans that a worker streams back one at a time."""
    with path.open("wb") as f:
        for scan in sources.open(uri):
            pickle.dump(scan, f)
    return path
