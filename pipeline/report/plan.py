"""A plan view per storey: the labelled map seen from above (ceilings left out, higher points drawn over lower
ones), the trajectory, the structural elements (the structure model's columns, beams and walls, else the
map's columns), every
finding marked with its number, and a legend of the classes drawn. Returns PNG bytes (matplotlib, Agg)."""

from __future__ import annotations

import io
from typing import Any, Final

import numpy as np

from aftershock.pipeline.classes import CLASS_COLORS, CLASS_NAMES, NUM_CLASSES, SemanticClass
from aftershock.pipeline.config import ReportConfig
from aftershock.pipeline.report.assess import storey_of
from aftershock.pipeline.report.gather import MissionData

LEFT_OUT: Final = (SemanticClass.CEILING,)  # seen from above, the ceiling would hide the storey
FINDING_COLORS: Final = {
    "crack": "#e6194b",
    "debris": "#f58231",
    "exit": "#ffe119",
    "drift": "#911eb4",
    "tilt": "#911eb4",
}
DPI: Final = 100


def _elements(m: MissionData, sel: np.ndarray) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """(kind, label, xy min, xy max) of the structural elements to draw: the structure model's columns, beams
    and walls (slabs are the plan's own ground), or the map's column objects."""
    out: list[tuple[str, str, np.ndarray, np.ndarray]] = []
    elements = (m.structure or {}).get("elements")
    if isinstance(elements, list):
        for e in elements:
            kind = str(e.get("kind", ""))
            if kind not in ("column", "beam", "wall"):
                continue
            ext = e.get("extent")
            try:
                if isinstance(ext, dict):
                    lo, hi = np.asarray(ext["min"], float), np.asarray(ext["max"], float)
                else:
                    flat = np.asarray(ext, float).reshape(-1)
                    lo, hi = flat[:3], flat[3:6]
            except (TypeError, ValueError, KeyError, IndexError):
                continue
            out.append((kind, f"{kind[0].upper()}{e.get('id', '')}", lo[:2], hi[:2]))
        return out
    cloud = m.cloud
    if cloud is None or cloud.instance_ids is None or cloud.class_ids is None:
        return out
    col = sel & (cloud.class_ids == SemanticClass.COLUMN) & (cloud.instance_ids > 0)
    ids = cloud.instance_ids[col]
    pts = cloud.points[col, :2]
    for k, i in enumerate(np.unique(ids)):  # one outline per column object
        p = pts[ids == i]
        out.append(("column", f"C{k + 1}", p.min(axis=0), p.max(axis=0)))
    return out


def draw_plan(
    m: MissionData, levels: list[dict[str, Any]], storey: int, findings: list[dict[str, Any]], cfg: ReportConfig
) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Rectangle

    fig, ax = plt.subplots(figsize=(10.5, 7.0), dpi=DPI)
    cloud = m.cloud
    drawn: list[int] = []
    sel = np.zeros(0, bool)
    if cloud is not None and len(cloud) and cloud.class_ids is not None:
        sel = storey_of(cloud.points, levels) == storey
        sel &= ~np.isin(cloud.class_ids, LEFT_OUT)
        idx = np.flatnonzero(sel)
        if len(idx) > cfg.plan_points:
            idx = idx[np.linspace(0, len(idx) - 1, cfg.plan_points).astype(np.int64)]
        idx = idx[np.argsort(cloud.points[idx, 2], kind="stable")]  # higher points over lower ones
        cls = cloud.class_ids[idx].astype(np.int64)
        known = cls < NUM_CLASSES
        colors = np.where(known[:, None], CLASS_COLORS[np.minimum(cls, NUM_CLASSES - 1)], 40) / 255.0
        ax.scatter(cloud.points[idx, 0], cloud.points[idx, 1], c=colors, s=2.0, marker="s", linewidths=0)
        drawn = sorted(set(cls[known].tolist()))
    for kind, label, lo, hi in _elements(m, sel):
        if kind == "wall":  # a wall's extent is a thin box along it: drawn as its line
            ax.plot([lo[0], hi[0]], [lo[1], hi[1]], color="black", lw=1.0, alpha=0.6)
            continue
        style = "-" if kind == "column" else "--"
        ax.add_patch(Rectangle(tuple(lo), *(hi - lo), fill=False, ec="black", lw=1.2, ls=style))
        ax.annotate(label, tuple(hi), fontsize=7, xytext=(2, 2), textcoords="offset points")
    if len(m.poses):
        xy = m.poses[:, 1:3]
        ax.plot(xy[:, 0], xy[:, 1], color="black", lw=1.6)
        ax.plot(*xy[0], marker="^", color="black", ms=9, ls="none")
        ax.plot(*xy[-1], marker="s", color="black", ms=8, ls="none")
    placed = [f for f in findings if f["storey"] == storey and f["position"] is not None]
    unplaced = [f for f in findings if f["storey"] == storey and f["position"] is None]
    for k, f in enumerate(placed):
        x, y = f["position"][0], f["position"][1]
        color = FINDING_COLORS.get(f["kind"], "#e6194b")
        ax.plot(x, y, marker="o", ms=17, mfc=color, mec="black", mew=1.2, ls="none", zorder=5)
        ax.annotate(str(f["number"]), (x, y), ha="center", va="center", fontsize=9, weight="bold", zorder=6)
        # labels fan out round the marker so that neighbouring findings do not overlap
        angle = 2 * np.pi * k / max(len(placed), 1)
        ax.annotate(
            f["text"], (x, y), xytext=(28 * np.cos(angle), 28 * np.sin(angle)), textcoords="offset points",
            fontsize=7, bbox={"boxstyle": "round", "fc": "white", "alpha": 0.85}, zorder=6,
            arrowprops={"arrowstyle": "-", "lw": 0.6},
        )  # fmt: skip
    if unplaced:
        text = "\n".join(f"{f['number']}: {f['text']}" for f in unplaced)
        ax.text(0.01, 0.99, text, transform=ax.transAxes, va="top", fontsize=8, bbox={"fc": "white", "alpha": 0.9})
    handles: list[Any] = [Patch(color=CLASS_COLORS[c] / 255.0, label=CLASS_NAMES[c]) for c in drawn]
    handles += [
        Line2D([], [], color="black", lw=1.6, marker="^", ms=7, label="trajectory (▲ start, ■ end)"),
        Line2D([], [], marker="o", ms=10, mfc="#e6194b", mec="black", ls="none", label="finding (number)"),
    ]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    level = levels[storey] if storey < len(levels) else {}
    floor = f"floor at z {level['floor_z_m']:.2f} m" if level.get("floor_z_m") is not None else "no floor slab found"
    ax.set_title(f"{m.name}: storey {storey} from above ({floor}; ceiling left out)", fontsize=10)
    ax.set_xlabel("x (m, map frame)")
    ax.set_ylabel("y (m, map frame)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3, alpha=0.5)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()
