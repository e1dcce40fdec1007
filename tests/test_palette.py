"""The class palette: every two classes clearly apart (CIE76 ΔE), and apart from the viewer's background, the
unlabelled grey and the magenta of uncertain voxels; the smallest distances are printed."""

from __future__ import annotations

import itertools

import numpy as np

from aftershock.pipeline.classes import CLASS_COLORS, CLASS_NAMES, UNCERTAIN_COLOR, UNLABELLED_COLOR, cie_lab

MIN_DELTA_E = 25.0  # ΔE76 above ~10 reads as a different colour at a glance; 25 leaves room for shading
BACKGROUND = np.array([18, 18, 22])  # sinks/rerun_blueprint.py: the 3D view's background


def test_cie_lab_reference_values() -> None:
    assert np.allclose(cie_lab(np.array([255, 255, 255])), [100, 0, 0], atol=0.01)
    assert np.allclose(cie_lab(np.array([255, 0, 0])), [53.24, 80.09, 67.20], atol=0.05)  # sRGB red


def test_every_two_classes_are_clearly_distinct() -> None:
    lab = cie_lab(CLASS_COLORS)
    pairs = sorted(
        (float(np.linalg.norm(lab[i] - lab[j])), CLASS_NAMES[i], CLASS_NAMES[j])
        for i, j in itertools.combinations(range(len(CLASS_NAMES)), 2)
    )
    for d, a, b in pairs[:3]:
        print(f"ΔE76 {d:.1f}: {a} / {b}")
    assert pairs[0][0] >= MIN_DELTA_E, pairs[0]
    against = {"background": BACKGROUND, "unlabelled": UNLABELLED_COLOR, "uncertain": UNCERTAIN_COLOR}
    for what, color in against.items():
        d = np.linalg.norm(lab - cie_lab(color), axis=1)
        print(f"ΔE76 {d.min():.1f}: {CLASS_NAMES[int(d.argmin())]} / {what}")
        assert d.min() >= MIN_DELTA_E, what
