"""`aftershock report DIR`: the site assessment report of a `run --export` or `batch` folder, as one
self-contained HTML file and `report.json` with the same content."""

from __future__ import annotations

import json
from pathlib import Path

import typer


def report(
    folder: Path = typer.Argument(..., help="A `run --export` folder or a `batch --out` folder."),
    out: Path | None = typer.Option(
        None, "--out", help="The HTML file (default DIR/report.html); report.json is written beside it."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing report."),
    config: Path | None = typer.Option(None, "--config", help="Config file (TOML/JSON): the [report] limits."),
    set_: list[str] | None = typer.Option(
        None, "--set", help="Override a setting: report.drift_restricted_ratio=0.004"
    ),
    as_json: bool = typer.Option(False, "--json", help="Print report.json on stdout (nothing else there)."),
) -> None:
    """Storey drift and tilt, cracks, debris, an ATC-20 evidence checklist and a suggested (advisory) posting,
    with a plan view per storey."""
    from aftershock.pipeline.cloud_io import check_output, write_atomically
    from aftershock.pipeline.config import load_config
    from aftershock.pipeline.report.build import make_report
    from aftershock.pipeline.report.html import render

    cfg = load_config(config, set_)
    html_path = out if out is not None else folder / "report.html"
    json_path = html_path.with_suffix(".json")
    if folder.is_dir():  # a missing folder is reported by name below, before any output is made
        for path in (html_path, json_path):
            check_output(path, force)
    result = make_report(folder, cfg)
    text = json.dumps(result.data, indent=2) + "\n"
    page = render(result)
    write_atomically(json_path, lambda tmp: tmp.write_text(text))
    write_atomically(html_path, lambda tmp: tmp.write_text(page))
    if as_json:
        print(text, end="")
        return
    site = result.data["site"]
    for m in result.data["missions"]:
        if m["status"] == "failed":
            print(f"{m['name']}: failed: {m['error']}")
            continue
        drift = ", ".join(
            f"storey {s['index']} "
            + (
                f"{s['drift_mm']:.1f} mm ({s['drift_ratio_text']})"
                if s["drift_mm"] is not None
                else "drift not measured"
            )
            for s in m["storeys"]
        )
        found = [i["item"] for i in m["checklist"] if i["status"] == "found"]
        print(
            f"{m['name']}: {drift}; evidence found: {', '.join(found) or 'none'}; "
            f"suggested posting {m['posting']['suggested']} (advisory)"
        )
    if site["suggested_posting"]:
        print(f"site: suggested posting {site['suggested_posting']} (advisory: the engineer decides)")
    print(f"report: {html_path}")
    print(f"report data: {json_path}")
