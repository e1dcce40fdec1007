"""Segmentation metrics and trajectory error on cases small enough to compute by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.metrics import cluster_scores, confusion_matrix, instance_scores, semantic_scores
from aftershock.pipeline.trajectory import trajectory_error, umeyama


def test_semantic_scores_by_hand() -> None:
    true = np.array([0, 0, 1, 1, 1, 2])
    pred = np.array([0, 1, 1, 1, 2, 2])
    s = semantic_scores(true, pred)
    # class 0: tp 1, 2 true, 1 predicted -> IoU 1/2, acc 1/2
    # class 1: tp 2, 3 true, 3 predicted -> IoU 2/4, acc 2/3
    # class 2: tp 1, 1 true, 2 predicted -> IoU 1/2, acc 1
    assert s.overall_accuracy == pytest.approx(4 / 6)
    assert s.mean_accuracy == pytest.approx((1 / 2 + 2 / 3 + 1) / 3)
    assert s.mean_iou == pytest.approx(0.5)
    assert s.per_class_iou == pytest.approx({"ceiling": 0.5, "floor": 0.5, "wall": 0.5})
    assert s.points == 6
    assert s.confusion == {"ceiling": {"ceiling": 1, "floor": 1}, "floor": {"floor": 2, "wall": 1}, "wall": {"wall": 1}}


def test_unlabelled_truth_is_left_out_and_unlabelled_prediction_is_wrong() -> None:
    true = np.array([0, 0, UNLABELLED, UNLABELLED])
    pred = np.array([0, UNLABELLED, 0, 3])
    s = semantic_scores(true, pred)
    assert s.points == 2
    assert s.overall_accuracy == pytest.approx(0.5)
    # class 0: tp 1, 2 true, 1 predicted among the evaluated points -> IoU 1 / 2
    assert s.per_class_iou == pytest.approx({"ceiling": 0.5})
    assert s.confusion == {"ceiling": {"ceiling": 1, "unlabelled": 1}}
    cm = confusion_matrix(true, pred)
    assert cm[0, 0] == 1 and cm[0, -1] == 1 and cm.sum() == 2


def test_means_are_over_classes_in_the_truth() -> None:
    s = semantic_scores(np.array([1, 1, 1, 1]), np.array([1, 1, 1, 5]))
    assert s.mean_accuracy == pytest.approx(0.75)  # only 'floor' is in the truth
    assert s.mean_iou == pytest.approx(0.75)
    assert set(s.per_class_iou) == {"floor"}


def test_cluster_scores_by_hand() -> None:
    true = np.array([0, 0, 1, 1])
    pred = np.array([7, 7, 7, 9])
    c = cluster_scores(true, pred)
    # ARI: sum C(n_ij, 2) = 1, rows 1 + 1 = 2, columns 3 + 0 = 3, C(4, 2) = 6, expected 1, max 2.5 -> 0
    assert c.ari == pytest.approx(0.0, abs=1e-12)
    h_t = math.log(2)
    h_p = -(0.75 * math.log(0.75) + 0.25 * math.log(0.25))
    mi = 0.5 * math.log(0.5 / (0.5 * 0.75)) + 0.25 * math.log(0.25 / (0.5 * 0.75)) + 0.25 * math.log(2)
    assert c.nmi == pytest.approx(mi / ((h_t + h_p) / 2))
    same = cluster_scores(np.array([1, 1, 2, 2, 3]), np.array([5, 5, 4, 4, 9]))
    assert same.nmi == pytest.approx(1) and same.ami == pytest.approx(1) and same.ari == pytest.approx(1)


def test_instance_scores_by_hand() -> None:
    true = np.array([1, 1, 1, 1, 2, 2, 0, 0])
    pred = np.array([5, 5, 5, 6, 6, 6, 7, 0])
    s = instance_scores(true, pred)
    # T1-P5: 3 / (4 + 3 - 3) = 0.75; T1-P6: 1 / 6; T2-P6: 2 / (2 + 3 - 2) = 2 / 3; P7 covers no true instance.
    assert s.matched == 2
    assert s.precision == pytest.approx(2 / 3)
    assert s.recall == pytest.approx(1.0)
    assert s.mean_iou == pytest.approx((0.75 + 2 / 3) / 2)
    assert (s.true_instances, s.predicted_instances) == (2, 3)


def test_instance_matching_is_one_to_one_not_greedy() -> None:
    # T1 has 10 points, T2 4. P5 = 6 of T1 + 3 of T2, P6 = the other 4 of T1, P7 = the last point of T2.
    true = np.array([1] * 10 + [2] * 4)
    pred = np.array([5] * 6 + [6] * 4 + [5] * 3 + [7])
    # IoU T1-P5 = 6 / 13, T1-P6 = 4 / 10, T2-P5 = 3 / 10, T2-P7 = 1 / 4. At threshold 0.29 a greedy pass
    # takes T1-P5 first and leaves T2 unmatched; the assignment matches T1-P6 and T2-P5.
    s = instance_scores(true, pred, threshold=0.29)
    assert s.matched == 2
    assert instance_scores(true, pred).matched == 0  # nothing reaches 0.5


def test_no_instances() -> None:
    s = instance_scores(np.zeros(5, int), np.zeros(5, int))
    assert (s.precision, s.recall, s.mean_iou, s.matched) == (0.0, 0.0, 0.0, 0)


def _poses(positions: np.ndarray, yaws: np.ndarray) -> np.ndarray:
    out = np.tile(np.eye(4), (len(positions), 1, 1))
    out[:, :3, :3] = Rotation.from_euler("z", yaws[:, None]).as_matrix()
    out[:, :3, 3] = positions
    return out


def test_umeyama_recovers_a_rigid_motion() -> None:
    rng = np.random.default_rng(0)
    src = rng.normal(size=(50, 3))
    r = Rotation.from_euler("xyz", [0.2, -0.4, 1.0]).as_matrix()
    dst = src @ r.T + [1.0, 2.0, -3.0]
    r_est, t_est, s = umeyama(src, dst)
    assert np.allclose(r_est, r) and np.allclose(t_est, [1, 2, -3]) and s == 1.0


def test_trajectory_error_by_hand() -> None:
    # The truth walks 1 m per frame along x; the estimate is the same path seen from another frame
    # (rotated and shifted: no error after alignment) plus 0.1 m extra at every step along y.
    n = 21
    truth = _poses(np.stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)], 1), np.zeros(n))
    assert trajectory_error(truth, truth).ate_rmse_m == pytest.approx(0, abs=1e-9)
    moved = np.eye(4)
    moved[:3, :3] = Rotation.from_euler("z", 0.7).as_matrix()
    moved[:3, 3] = [5, -2, 1]
    err = trajectory_error(moved @ truth, truth)
    assert err.ate_rmse_m == pytest.approx(0, abs=1e-9) and err.rpe_trans_m == pytest.approx(0, abs=1e-9)
    assert err.path_length_m == pytest.approx(20.0)
    drift = truth.copy()
    drift[:, 1, 3] = 0.1 * np.arange(n)
    e = trajectory_error(drift, truth, segment_m=10.0)
    assert e.rpe_trans_m == pytest.approx(0.1)  # every step is 0.1 m off sideways
    assert e.drift_percent == pytest.approx(10.0)  # 10 m segments end 1 m off sideways: 10 %
    assert e.ate_rmse_m > 0


def test_trajectory_needs_matching_lengths() -> None:
    with pytest.raises(ValueError):
        trajectory_error(np.tile(np.eye(4), (3, 1, 1)), np.tile(np.eye(4), (2, 1, 1)))
