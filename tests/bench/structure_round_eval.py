"""Round V1 (#28, docs/decisions.md): colour-free weights files on the validation or the test missions, one
`aftershock eval --json` each (its own process, niced), and the round's rule applied to validation.

    python tests/bench/structure_round_eval.py validation OUT NAME=FILE ...   # writes OUT/NAME/G-S.json
    python tests/bench/structure_round_eval.py test OUT NAME=FILE ...
    python tests/bench/structure_round_eval.py rule OUT                       # the rule on OUT's validation figures

A missing JSON is computed, an existing one read back (a run cut short resumes).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, Final

SCANS: Final = 100
VALIDATION: Final = [("office", 800), ("disaster", 800), ("hall", 800)]
TEST: Final = [("office", 900), ("disaster", 900), ("hall", 900), ("wing", 900)]
STRUCTURAL: Final = ("floor", "wall", "column")
SHOWN: Final = ("floor", "ceiling", "wall", "column", "beam", "window", "door", "debris", "table", "clutter")


def uri(generator: str, seed: int) -> str:
    return f"sim://{generator}?seed={seed}&sensor=vlp16&scans={SCANS}&robot=wheeled&height=1&speed=1&turn=45&color=0"


def evaluate(out: Path, name: str, weights: str, missions: list[tuple[str, int]]) -> list[dict[str, Any]]:
    reps = []
    for g, s in missions:
        path = out / name / f"{g}-{s}.json"
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            cmd = ["nice", "-n", "5", sys.executable, "-m", "aftershock.pipeline", "eval", uri(g, s), "--json"]
            cmd += ["--set", f"label.weights_no_color={weights}"]
            proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "CI": "true"})
            if proc.returncode:
                raise SystemExit(f"{name} {g}-{s}: exit {proc.returncode}\n{proc.stderr[-1500:]}")
            path.write_text(proc.stdout)
        reps.append(json.loads(path.read_text()))
    return reps


def class_mean(reps: list[dict[str, Any]], cls: str) -> float | None:
    """A class's IoU, the mean over the missions that hold it (None where none does)."""
    vals = [r["per_class_iou"][cls] for r in reps if r["per_class_iou"].get(cls) is not None]
    return sum(vals) / len(vals) if vals else None


def table(out: Path, missions: list[tuple[str, int]]) -> dict[str, dict[str, Any]]:
    figures: dict[str, dict[str, Any]] = {}
    for d in sorted(p for p in out.iterdir() if p.is_dir()):
        files = [d / f"{g}-{s}.json" for g, s in missions]
        if not all(f.exists() for f in files):
            continue
        reps = [json.loads(f.read_text()) for f in files]
        row: dict[str, Any] = {k: sum(r[k] for r in reps) / len(reps) for k in ("mean_iou", "nmi", "overall_accuracy")}
        row |= {c: class_mean(reps, c) for c in SHOWN}
        row["per_mission_miou"] = {f.stem: r["mean_iou"] for f, r in zip(files, reps, strict=True)}
        figures[d.name] = row
    return figures


def show(figures: dict[str, dict[str, Any]]) -> None:
    def pct(v: float | None) -> str:
        return "—" if v is None else f"{100 * v:.1f}"

    print("| weights | OA | mIoU | NMI | " + " | ".join(SHOWN) + " |")
    print("|---" * (4 + len(SHOWN)) + "|")
    for name, row in figures.items():
        cells = [pct(row["overall_accuracy"]), pct(row["mean_iou"]), pct(row["nmi"])] + [pct(row[c]) for c in SHOWN]
        print(f"| {name} | " + " | ".join(cells) + " |")


def passes(new: dict[str, Any], ref: dict[str, Any]) -> tuple[bool, str]:
    """The round's rule: mean IoU up by at least 1 point, no one of floor, wall, column down by more than 2."""
    gain = 100 * (new["mean_iou"] - ref["mean_iou"])
    drops = {c: 100 * (ref[c] - new[c]) for c in STRUCTURAL if new[c] is not None and ref[c] is not None}
    ok = gain >= 1.0 and all(d <= 2.0 for d in drops.values())
    return ok, f"mIoU {gain:+.1f} points, drops " + ", ".join(f"{c} {d:+.1f}" for c, d in drops.items())


def main() -> None:
    what, out = sys.argv[1], Path(sys.argv[2])
    missions = VALIDATION if what in ("validation", "rule") else TEST
    for arg in sys.argv[3:]:
        name, weights = arg.split("=", 1)
        evaluate(out / what, name, weights, missions)
    figures = table(out / ("validation" if what == "rule" else what), missions)
    show(figures)
    if what == "rule":
        for ref in ("old", "shipped"):
            if "new" in figures and ref in figures:
                ok, why = passes(figures["new"], figures[ref])
                print(f"new against {ref}: {'passes' if ok else 'fails'} ({why})")
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
