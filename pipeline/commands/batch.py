"""`aftershock batch SOURCE... --out DIR`: every mission of a site through the stream on Ray, one site index.

Exit codes: 0 every mission ok (or complete from an earlier run), 1 some missions failed (each reported in
the index and the table), 2 a user error before any mission ran (no sources, output folder of another
configuration, unreachable --address), 130 Ctrl-C (finished missions stay complete; the rest are redone
on the next run).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any, Final

import typer

from aftershock.pipeline.commands import CONFIG, LABELLER, OVERRIDES
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.progress import bar, enabled

TABLE_ROWS: Final = 40  # the terminal table stops here; the index has them all
NAME_WIDTH: Final = 24  # mission names in the progress bar
DEFAULT_WORKER_MEMORY_GB: Final = 2.0  # ample for a long mission with MCPNet's torch (docs/benchmarks/long-mission.md)


def _fmt(value: Any, spec: str = "") -> str:
    if value is None:
        return "-"
    return format(value, spec) if spec else str(value)


def print_table(rows: list[dict[str, Any]], index: Path, wall_s: float, workers: int) -> None:
    header = ("mission", "status", "scans", "path m", "ATE m", "voxels", "objects", "cracks", "drift mm", "time s")
    lines = [header]
    for r in rows[:TABLE_ROWS]:
        status = r["status"] + (" (earlier run)" if r.get("reused") else "")
        cracks = "-" if r.get("cracks") is None else f"{r['cracks']} ({r['severe_cracks']} severe)"
        lines.append(
            (
                r["mission"],
                status,
                _fmt(r.get("scans")),
                _fmt(r.get("path_length_m"), ".1f"),
                _fmt(r.get("ate_m"), ".3f"),
                _fmt(r.get("map_voxels")),
                _fmt(r.get("objects")),
                cracks,
                _fmt(r.get("worst_drift_mm"), ".1f"),
                _fmt(r.get("processing_s"), ".1f"),
            )
        )
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    for i, line in enumerate(lines):
        print("  ".join(c.ljust(w) if j < 2 else c.rjust(w) for j, (c, w) in enumerate(zip(line, widths, strict=True))))
        if i == 0:
            print("  ".join("-" * w for w in widths))
    if len(rows) > TABLE_ROWS:
        print(f"… and {len(rows) - TABLE_ROWS} more missions (all in the index)")
    for r in rows:
        if r.get("error") and r["status"] != "ok":
            print(f"{r['mission']}: {r['error']}")
    counts = _counts(rows)
    done = ", ".join(f"{n} {k}" for k, n in counts.items() if n)
    ran = f"; {wall_s:.1f} s on {workers} workers" if workers else ""
    print(f"{len(rows)} missions: {done}{ran}")
    print(f"site index: {index}")


def _short(name: str, width: int = NAME_WIDTH) -> str:
    """A mission's name cut for the progress bar (several share one line)."""
    return name if len(name) <= width else name[: width - 1] + "…"


def _counts(rows: list[dict[str, Any]]) -> dict[str, int]:
    return {
        "ok": sum(r["status"] == "ok" and not r.get("reused") for r in rows),
        "from an earlier run": sum(bool(r.get("reused")) for r in rows),
        "failed": sum(r["status"] == "failed" for r in rows),
        "interrupted": sum(r["status"] == "interrupted" for r in rows),
    }


def batch(
    sources: list[str] = typer.Argument(
        ..., help="Logs, folders of logs, globs, sim://… URIs, or text files listing them (one per line)."
    ),
    out: Path = typer.Option(..., "--out", help="Output folder: DIR/<mission>/ and DIR/missions.parquet."),
    workers: int | None = typer.Option(
        None, "--workers", min=1, help="Missions at a time (default: the cores; with --address the cluster's CPUs)."
    ),
    address: str | None = typer.Option(None, "--address", help="Join this Ray cluster (HOST:PORT of its head)."),
    damage: bool = typer.Option(False, "--damage", help="Cracks and story drift/tilt on each mission's map."),
    labeller: str | None = LABELLER,
    config: Path | None = CONFIG,
    overrides: list[str] | None = OVERRIDES,
    max_scans: int | None = typer.Option(None, "--max-scans", help="Stop each mission after this many scans."),
    worker_memory: float = typer.Option(
        DEFAULT_WORKER_MEMORY_GB,
        "--worker-memory",
        min=0.1,
        help="GB of memory per worker (Ray packs missions by it; bound enforced).",
    ),
    force: bool = typer.Option(False, "--force", help="Redo complete missions; write over another configuration."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    as_json: bool = typer.Option(False, "--json", help="Print the index rows as JSON."),
) -> None:
    """Run the stream (and with --damage the damage assessment) on many missions as Ray tasks."""
    from aftershock.pipeline.batch import folder as bf
    from aftershock.pipeline.batch import ray_pool
    from aftershock.pipeline.batch.site_index import INDEX_FILE, write_index
    from aftershock.pipeline.batch.sources import expand_sources, name_missions
    from aftershock.pipeline.mission import build_config

    if not math.isfinite(worker_memory):  # `inf` would be no bound at all, and no size Ray can pack by
        raise InputError(f"--worker-memory {worker_memory}: give the GB of memory one worker may take")
    cfg = build_config(config, overrides, labeller, max_scans=max_scans)
    if address is not None:
        ray_pool.check_reachable(address)  # before anything is written, even when every mission is complete
    out = out.expanduser().resolve()
    missions = expand_sources(sources, exclude=out)
    if not missions:
        raise InputError("no sources given")
    fingerprint, settings = bf.config_fingerprint(cfg, damage)
    bf.prepare_output(out, fingerprint, settings, force)
    missions = name_missions(missions, bf.taken_names(out))
    memory = int(worker_memory * 2**30)
    tasks, known, _ = bf.plan(missions, out, cfg, damage, force, memory)
    index = out / INDEX_FILE
    rows = list(known)
    write_index(index, bf.merge_index(out, rows, fingerprint))
    if not quiet and not as_json and known:
        reused = sum(bool(r.get("reused")) for r in known)
        if reused:
            print_note(f"{reused} missions complete from an earlier run (--force redoes them)")

    show = enabled(quiet)
    with bar(len(missions), "missions", unit="mission", show=show) as b:
        b.update(len(known))

        def on_update(row: dict[str, Any] | None, running: dict[str, tuple[int, float]]) -> None:
            if row is not None:
                rows.append(row)
                b.update(1)
                write_index(index, bf.merge_index(out, rows, fingerprint))  # up to date after every mission
            if running:
                shown = (f"{_short(k)} {n} scans {r:.1f}/s" for k, (n, r) in sorted(running.items()))
                b.set_postfix_str(" | ".join(shown))

        run = ray_pool.run_missions(tasks, address, workers, memory, on_update)
    finished = {r["mission"] for r in rows}
    rows.extend(r for r in run.rows if r["mission"] not in finished)  # interrupted ones
    all_rows = bf.merge_index(out, rows, fingerprint)
    write_index(index, all_rows)
    this_run = sorted((r for r in rows), key=lambda r: r["mission"])
    if as_json:
        payload = {
            "index": str(index),
            "workers": run.workers,
            "wall_time_s": round(run.wall_time_s, 3),
            "interrupted": run.interrupted,
            "counts": _counts(this_run),
            "missions": this_run,
        }
        print(json.dumps(payload, indent=2))
    else:
        print_table(this_run, index, run.wall_time_s, run.workers)
    if run.interrupted:
        print(
            "aftershock: interrupted; finished missions are complete, the others are redone next time",
            file=sys.stderr,
        )
        raise typer.Exit(130)
    if any(r["status"] != "ok" for r in this_run):
        raise typer.Exit(1)


def print_note(text: str) -> None:
    print(f"aftershock: {text}", file=sys.stderr)
