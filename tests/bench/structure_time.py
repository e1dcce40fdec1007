"""Where the structure stage's time goes: the StructureModel's methods wrapped with timers (the end-of-run
`finish` left out), then one `aftershock` command in this process; prints ms a scan per method.

    python tests/bench/structure_time.py run "sim://disaster?seed=900&scans=150&sensor=vlp16" --export DIR --json
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
from collections import defaultdict
from collections.abc import Callable
from time import perf_counter
from typing import Any

from aftershock.pipeline.structure import model as M

PARTS = (
    "explain", "take", "_element_embeddings",
    "update", "apply", "_add_rows", "_update_slabs", "_join_elements", "_refit_tiles", "_fuse", "_support",
    "_fit_walls", "_merge_walls", "_join_block_walls", "_fit_columns", "_fit_beams",
)  # fmt: skip
spent: dict[str, float] = defaultdict(float)
finishing = [False]


def _timed(name: str, f: Callable[..., Any]) -> Callable[..., Any]:
    def g(self: M.StructureModel, *args: Any, **kwargs: Any) -> Any:
        t0 = perf_counter()
        try:
            return f(self, *args, **kwargs)
        finally:
            if not finishing[0]:
                spent[name] += perf_counter() - t0

    return g


def _finish(f: Callable[..., Any]) -> Callable[..., Any]:
    def g(self: M.StructureModel, *args: Any) -> Any:
        finishing[0] = True
        try:
            return f(self, *args)
        finally:
            finishing[0] = False

    return g


def main(argv: list[str]) -> None:
    for name in PARTS:
        setattr(M.StructureModel, name, _timed(name, getattr(M.StructureModel, name)))
    M.StructureModel.finish = _finish(M.StructureModel.finish)  # type: ignore[method-assign]
    from aftershock.pipeline.cli import main as cli

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        cli(argv)
    summary = json.loads(out.getvalue())
    t, scans = summary["mean_timings_ms"], summary["scans"]
    print("stage ms/scan", {k: round(v, 2) for k, v in t.items()})
    print("structure / register", round(t["structure"] / t["register"], 3))
    for name, s in sorted(spent.items(), key=lambda kv: -kv[1]):
        print(f"{name:20s} {1e3 * s / scans:7.2f} ms/scan")


if __name__ == "__main__":
    main(sys.argv[1:])
