"""The damaged-region detector (issue #30, round two): a wide, rough, slightly darker band on a synthetic face is
found; an intact face with a stain, a construction joint, a cast shadow, paint and a hole is not flagged; bad input
is refused as before (one line naming the problem)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aftershock.pipeline.cli import main
from aftershock.pipeline.config import CrackConfig
from aftershock.pipeline.damage.report import find_cracks
from aftershock.pipeline.types import LabelledCloud

SPACING = 0.003


def _face(rng: np.random.Generator, size: tuple[float, float] = (0.4, 0.6)) -> tuple[np.ndarray, np.ndarray]:
    """A jittered grid (u, v) of a face at `SPACING` and its grey concrete (aggregate speckle, gentle tone)."""
    u, v = np.meshgrid(np.arange(0, size[0], SPACING), np.arange(0, size[1], SPACING), indexing="ij")
    uv = np.c_[u.ravel(), v.ravel()] + rng.uniform(-0.3, 0.3, (u.size, 2)) * SPACING
    grey = 190.0 * (1 + 0.04 * np.sin(uv[:, 0] * 9 + uv[:, 1] * 5)) + rng.normal(0, 8, len(uv))
    return uv, grey


def _cloud(
    uv: np.ndarray, grey: np.ndarray, depth: np.ndarray, rng: np.random.Generator, tint: np.ndarray | None = None
) -> LabelledCloud:
    """The face upright in space (u along x, v up), 0.5 mm scanner noise; buff concrete unless `tint` (N, 3)."""
    pts = np.c_[uv[:, 0], depth + rng.normal(0, 0.0005, len(uv)), uv[:, 1]] + [2.0, 1.0, 0.5]
    hue = np.broadcast_to(np.array([1.05, 1.0, 0.9]), (len(uv), 3)) if tint is None else tint
    rgb = np.clip(grey[:, None] * hue, 0, 255).astype(np.uint8)
    return LabelledCloud(pts, rgb)


def test_a_wide_rough_dark_band_is_found() -> None:
    """Damage as the real masks mark it: a band 7 cm wide along the face, 12 % darker, rough (2 mm spalling)."""
    rng = np.random.default_rng(5)
    uv, grey = _face(rng)
    centre = 0.2 + 0.02 * np.sin(uv[:, 1] * 6)
    band = (np.abs(uv[:, 0] - centre) <= 0.035) & (uv[:, 1] >= 0.08) & (uv[:, 1] <= 0.52)
    grey = np.where(band, grey * 0.88, grey)
    depth = np.where(band, -np.abs(rng.normal(0.0, 0.002, len(uv))), 0.0)
    result = find_cracks(_cloud(uv, grey, depth, rng), CrackConfig(detector="region"), band)
    s = result.scores
    assert s is not None and s.f1 >= 0.6, s
    assert s.precision >= 0.6, s  # the region is a little wider than the band (smoothing, hysteresis)
    assert result.detector == "region" and result.cracks


def test_an_intact_face_with_a_stain_a_joint_shade_and_paint_is_not_flagged() -> None:
    """No crack: a dark round stain, a construction joint (a straight recessed darker groove across the face), a
    cast shadow with a straight edge, a painted stripe of a hue of its own and a hole (occlusion)."""
    rng = np.random.default_rng(6)
    uv, grey = _face(rng)
    stain = np.exp(-(((uv - [0.12, 0.4]) ** 2).sum(axis=1)) / 0.04**2)
    grey = grey * (1 - 0.25 * stain)
    joint = np.abs(uv[:, 1] - 0.3) <= 0.004
    grey, depth = np.where(joint, grey * 0.8, grey), np.where(joint, -0.003, 0.0)
    grey = np.where(uv[:, 0] + 0.5 * uv[:, 1] > 0.45, grey * 0.75, grey)  # cast shadow
    tint = np.tile([1.05, 1.0, 0.9], (len(uv), 1))
    tint[np.abs(uv[:, 1] - 0.1) <= 0.015] = [1.2, 1.05, 0.5]  # a yellow painted stripe
    seen = ((uv - [0.3, 0.15]) ** 2).sum(axis=1) > 0.05**2
    cloud = _cloud(uv[seen], grey[seen], depth[seen], rng, tint[seen])
    result = find_cracks(cloud, CrackConfig(detector="region"), np.zeros(len(cloud), bool))
    assert result.mask.mean() <= 0.01, result.mask.mean()


@pytest.mark.parametrize(
    ("points", "problem"),
    [
        (np.zeros((0, 3)), "too few to look for cracks"),
        (np.zeros((1, 3)), "too few to look for cracks"),
        (np.full((500, 3), np.nan), "finite coordinates"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    points: np.ndarray, problem: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Empty, single-point or non-finite input: as for every detector, one line naming the file, exit 2."""
    path = tmp_path / "bad.ply"
    header = f"ply\nformat ascii 1.0\nelement vertex {len(points)}\n"
    header += "property float x\nproperty float y\nproperty float z\nend_header\n"
    path.write_text(header + "".join(f"{x} {y} {z}\n" for x, y, z in points))
    assert main(["cracks", str(path), "--detector", "region"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1
    assert "bad.ply" in err and problem in err


def test_non_finite_points_are_left_out_with_a_note() -> None:
    rng = np.random.default_rng(7)
    uv, grey = _face(rng, (0.2, 0.3))
    cloud = _cloud(uv, grey, np.zeros(len(uv)), rng)
    cloud.points[:5] = np.nan
    result = find_cracks(cloud, CrackConfig(detector="region"))
    assert result.notes and "non-finite" in result.notes[0]
