"""One self-contained HTML file of a report: styles inline, plan views inline as base64 PNG, no script and
nothing fetched from the network, so it opens from a USB stick and prints to PDF as it is."""

from __future__ import annotations

import base64
from html import escape
from typing import Any, Final

from aftershock.pipeline.report.build import Report

NOT_MEASURED: Final = "not measured"
STATUS_TEXT: Final = {"found": "evidence found", "none": "nothing found", "not_assessable": "not assessable"}
POSTING_COLOR: Final = {"inspected": "#2e7d32", "restricted use": "#f9a825", "unsafe": "#c62828"}

CSS: Final = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1150px;
color:#1d1d1f;line-height:1.4;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:2px solid #444;padding-bottom:.2em;margin-top:2em}
h3{margin-top:1.4em}table{border-collapse:collapse;width:100%;margin:.6em 0;font-size:.92em}
th,td{border:1px solid #bbb;padding:.3em .5em;text-align:left;vertical-align:top}th{background:#eee}
.advisory{background:#fff3cd;border:1px solid #e0c36b;padding:.6em 1em;margin:1em 0}
.posting{display:inline-block;color:#fff;font-weight:bold;padding:.3em .9em;border-radius:4px;
text-transform:uppercase;letter-spacing:.05em}
.found{color:#b71c1c;font-weight:bold}.none{color:#1b5e20}.not_assessable{color:#6d4c41;font-style:italic}
.failed{background:#fdecea;border:1px solid #e57373;padding:.6em 1em}
.nm{color:#6d4c41;font-style:italic}img{max-width:100%;border:1px solid #ccc}
.small{font-size:.85em;color:#555}code{font-size:.9em}
@media print{body{margin:0;max-width:none}h2{page-break-before:always}h2.first{page-break-before:avoid}
img{page-break-inside:avoid}}
"""


def _v(value: Any, fmt: str = "", unit: str = "") -> str:
    if value is None:
        return f'<span class="nm">{NOT_MEASURED}</span>'
    text = format(value, fmt) if fmt else str(value)
    return escape(text + unit)


def _where(where: list[dict[str, Any]]) -> str:
    parts = []
    for w in where:
        rec = w.get("recording")
        inst = f" #{w['instance']}" if w.get("instance") is not None else ""
        place = f"<code>{escape(w['entity'])}{inst}</code> at {escape(w['timeline'])} {w['position']}"
        parts.append(place + (f" in <code>{escape(rec)}</code>" if rec else " (no recording saved)"))
    return "<br>".join(parts) or "-"


def _table(header: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _posting(p: dict[str, Any] | None) -> str:
    if p is None:
        return ""
    color = POSTING_COLOR.get(p["suggested"], "#555")
    reasons = "; ".join(escape(r) for r in p["reasons"])
    return (
        f'<p>Suggested posting (advisory): <span class="posting" style="background:{color}">'
        f"{escape(p['suggested'])}</span></p><p>Because: {reasons}.</p>"
        f'<p class="small">Rule: {escape(p["rule"])}.</p>'
    )


def _storeys(storeys: list[dict[str, Any]]) -> str:
    rows = []
    for s in storeys:
        drift = _v(s["drift_mm"], ".1f", " mm")
        if s["drift_mm"] is not None:
            drift += f" ± {_v(s['uncertainty_mm'], '.1f', ' mm')}" if s["uncertainty_mm"] is not None else " ± ?"
        tilt = _v(s["tilt_deg"], ".3f", "°")
        if s["tilt_deg"] is not None:
            u = s.get("tilt_uncertainty_deg")
            tilt += f" ± {_v(u, '.3f', '°')}" if u is not None else " ± ?"
        rows.append(
            [
                str(s["index"]),
                _v(s["floor_z_m"], ".2f", " m"),
                _v(s["height_m"], ".2f", " m"),
                drift,
                _v(s["drift_ratio_text"]),
                tilt,
                _v(s["flag"]),
                escape(s["reason"] or ""),
            ]
        )
    return _table(["storey", "floor z", "height", "drift", "ratio", "slab tilt", "flag", "why not measured"], rows)


def _mission(m: dict[str, Any], report: Report) -> str:
    out = [f"<h2>Mission {escape(m['name'])}</h2>"]
    if m["status"] == "failed":
        out.append(f'<div class="failed"><b>failed</b>: {escape(str(m.get("error")))}</div>')
        return "".join(out)
    if m["status"] == "interrupted":
        out.append('<div class="failed">interrupted: the results cover the part of the log that was processed</div>')
    out.append(_posting(m["posting"]))
    out.append("<h3>Evidence checklist (after the ATC-20 detailed evaluation)</h3>")
    rows = [
        [escape(i["item"]), f'<span class="{i["status"]}">{STATUS_TEXT[i["status"]]}</span>', escape(i["evidence"]),
         _where(i["where"])]
        for i in m["checklist"]
    ]  # fmt: skip
    out.append(_table(["item", "status", "evidence", "where in the recording"], rows))
    out.append("<h3>Storey drift and tilt</h3>")
    dm = m["drift_measured"]
    out.append(f'<p class="small">Measured on <code>{escape(dm["from"])}</code>; up: {escape(dm["up_text"])}.</p>')
    out.append(_storeys(m["storeys"]))
    out.append("<h3>Plan views</h3>")
    for s in m["storeys"]:
        png = report.plans.get((m["name"], s["index"]))
        if png is not None:
            b64 = base64.b64encode(png).decode("ascii")
            alt = escape(f"plan of storey {s['index']} of {m['name']}")
            out.append(f'<p><img src="data:image/png;base64,{b64}" alt="{alt}"></p>')
    if m["findings"]:
        out.append("<h3>Findings</h3>")
        rows = [
            [str(f["number"]), escape(f["kind"]), escape(f["text"]), str(f["storey"]), _where([f["where"]])]
            for f in m["findings"]
        ]
        out.append(_table(["#", "kind", "finding", "storey", "where in the recording"], rows))
    out.append("<h3>Structural inventory</h3>")
    keys = ("storey", "slabs", "walls", "columns", "beams")
    rows = [[*(str(i[k]) for k in keys), escape(i["source"])] for i in m["inventory"]]
    out.append(_table(["storey", "slabs", "walls", "columns", "beams", "from"], rows))
    out.append("<h3>Cracks</h3>")
    crk = m["cracks"]
    if not crk["assessed"]:
        out.append(f'<p class="nm">Not assessable: {escape(crk["reason"])}.</p>')
    for e in crk["elements"]:
        narrow = (
            f"{e['narrowest_detectable_m'] * 1000:.1f} mm"
            if e["narrowest_detectable_m"] is not None
            else escape(e["narrowest_reason"] or "")
        )
        out.append(
            f"<p><b>{escape(e['element'])}</b> (<code>{escape(e['file'])}</code>): narrowest width resolved "
            f"{narrow}; a narrower crack is not detectable here.</p>"
        )
        if e["cracks"]:
            rows = [[str(c["id"]), escape(c["element"]), _v(c["length_m"], ".3f", " m"), escape(c["width_text"]),
                     escape(c["severity"])] for c in e["cracks"]]  # fmt: skip
            out.append(_table(["crack", "element", "length", "width", "severity"], rows))
        else:
            out.append("<p>No crack found at that resolution.</p>")
    out.append("<h3>Debris</h3>")
    rows = [
        [str(d["storey"]), _v(d["volume_m3"], ".2f", " m³"), _v(d["floor_area_m2"], ".1f", " m²"),
         _v(None if d["floor_share"] is None else 100 * d["floor_share"], ".1f", " %"), escape(d.get("reason") or "")]
        for d in m["debris"]
    ]  # fmt: skip
    out.append(_table(["storey", "volume", "floor area seen", "share of floor", "why not measured"], rows))
    if m.get("notes"):
        out.append("<h3>Notes from the analysis</h3><ul>")
        out.extend(f"<li>{escape(n)}</li>" for n in m["notes"])
        out.append("</ul>")
    return "".join(out)


def render(report: Report) -> str:
    d = report.data
    site = d["site"]
    rows = []
    for m in d["missions"]:
        if m["status"] == "failed":
            rows.append([escape(m["name"]), "failed", "", "", "", "", escape(str(m.get("error"))), ""])
            continue
        sensor = m["sensor"]
        kind = " / ".join(escape(str(sensor.get(k))) for k in ("source_kind", "environment") if sensor.get(k))
        rows.append(
            [
                escape(m["name"]),
                escape(m["status"]),
                escape(m["started_utc"]) if m["started_utc"] else '<span class="nm">no clock time in the log</span>',
                _v(m["duration_s"], ".1f", " s"),
                _v(m["path_length_m"], ".1f", " m"),
                _v(m["scans"]),
                kind + "<br>" + "<br>".join(escape(w) for w in m["what_was_run"]),
                escape(m["posting"]["suggested"]) if m.get("posting") else "",
            ]
        )
    lim = d["limits"]
    src = lim["sources"]
    worst = site["suggested_posting"]
    head = (
        f"<h1>Site assessment: {escape(site['folder'])}</h1>"
        f'<p class="small">Made {escape(d["generated_utc"])} by aftershock {escape(d["aftershock"])} from '
        f"{'an export' if site['kind'] == 'export' else 'a batch'} folder: {site['missions']} mission(s), "
        f"{site['failed']} failed.</p>"
        '<div class="advisory"><b>Advisory.</b> This report collects evidence from LiDAR scans for a structural '
        "engineer to check. Its posting is a suggestion made by a fixed rule; the posting of a building is the "
        "inspecting engineer's decision (ATC-20). Values the data could not measure are shown as "
        f'"{NOT_MEASURED}" or "not assessable", never as zero.</div>'
    )
    if worst:
        color = POSTING_COLOR.get(worst, "#555")
        head += f'<p>Site, worst mission: <span class="posting" style="background:{color}">{escape(worst)}</span></p>'
    site_table = '<h2 class="first">Missions</h2>' + _table(
        ["mission", "status", "started (UTC)", "duration", "path", "scans", "sensor, what was run", "posting"], rows
    )
    limits = (
        "<h2>Limits and sources</h2><ul>"
        f"<li>Drift ratio flagged at 1/{round(1 / lim['drift_restricted_ratio'])} (restricted use) and "
        f"1/{round(1 / lim['drift_unsafe_ratio'])} (unsafe): {escape(src['drift_limits'])}.</li>"
        f"<li>Slab tilt flagged at {lim['tilt_restricted_deg']}° and {lim['tilt_unsafe_deg']}°: "
        f"{escape(src['tilt_limits'])}. Tilt uncertainty: {escape(src['tilt_uncertainty'])}.</li>"
        f"<li>Drift uncertainty ± {lim['drift_uncertainty_mm']} mm per storey (with up from the map's z, + the "
        f"storey height × tan {lim['level_uncertainty_deg']}°): {escape(src['uncertainty'])}.</li>"
        f"<li>Partial collapse when debris covers {lim['collapse_debris_share']:.0%} of a storey's floor; an exit "
        f"blocked when debris lies within {lim['exit_clearance_m']} m of a door (choices of this tool).</li>"
        f"<li>Checklist: {escape(src['checklist'])}.</li>"
        "<li>All limits are settings: <code>--set report.drift_restricted_ratio=0.004</code> and the like.</li></ul>"
    )
    body = head + site_table + "".join(_mission(m, report) for m in d["missions"]) + limits
    return (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>Site assessment: {escape(site['folder'])}</title><style>{CSS}</style></head>"
        f"<body>{body}</body></html>\n"
    )
