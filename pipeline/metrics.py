"""Segmentation metrics over points, as in the study (METHODS.md), shared by every method that is evaluated.

- Semantic: overall accuracy, mean class accuracy, per-class IoU and their mean. Points whose true class
  is UNLABELLED are left out; an unlabelled prediction counts as wrong. Means are over the classes that
  occur in the ground truth.
- Clustering: NMI, AMI, ARI of the instance ids over all points (scikit-learn).
- Instances: a prediction matches a true instance when their IoU exceeds the threshold (0.5); matching is
  one-to-one (Hungarian assignment on IoU, not the original's greedy pass). Precision = matched predictions
  / predictions, recall = matched truths / truths, mIoU = mean over true instances of their best IoU.
  Instance id 0 ("no object") is neither a true nor a predicted instance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from scipy.optimize import linear_sum_assignment
from sklearn.metrics import adjusted_mutual_info_score, adjusted_rand_score, normalized_mutual_info_score

from aftershock.pipeline.classes import CLASS_NAMES, NUM_CLASSES

IOU_THRESHOLD: Final = 0.5


@dataclass(slots=True)
class SemanticScores:
    overall_accuracy: float
    mean_accuracy: float
    mean_iou: float
    per_class_iou: dict[str, float]
    per_class_accuracy: dict[str, float]
    points: int
    # where each true class's points went: {true class: {predicted class or "unlabelled": points}}, non-zero only
    confusion: dict[str, dict[str, int]]


@dataclass(slots=True)
class ClusterScores:
    nmi: float
    ami: float
    ari: float


@dataclass(slots=True)
class InstanceScores:
    precision: float
    recall: float
    mean_iou: float
    true_instances: int
    predicted_instances: int
    matched: int


def confusion_matrix(true: np.ndarray, pred: np.ndarray, num_classes: int = NUM_CLASSES) -> np.ndarray:
    """(C, C + 1) counts, rows = truth, columns = prediction; the last column collects predictions outside
    0..C-1 (unlabelled). Points whose truth is outside 0..C-1 are left out."""
    t = np.asarray(true, dtype=np.int64).ravel()
    p = np.asarray(pred, dtype=np.int64).ravel()
    known = (t >= 0) & (t < num_classes)
    t, p = t[known], p[known]
    p = np.where((p >= 0) & (p < num_classes), p, num_classes)
    return np.bincount(t * (num_classes + 1) + p, minlength=num_classes * (num_classes + 1)).reshape(
        num_classes, num_classes + 1
    )


def semantic_scores(
    true: np.ndarray, pred: np.ndarray, num_classes: int = NUM_CLASSES, names: tuple[str, ...] = CLASS_NAMES
) -> SemanticScores:
    cm = confusion_matrix(true, pred, num_classes)
    total = int(cm.sum())
    tp = np.diag(cm[:, :num_classes]).astype(np.float64)
    in_truth = cm.sum(axis=1).astype(np.float64)
    in_pred = cm[:, :num_classes].sum(axis=0).astype(np.float64)
    present = in_truth > 0
    union = in_truth + in_pred - tp
    iou = np.divide(tp, union, out=np.zeros_like(tp), where=union > 0)
    acc = np.divide(tp, in_truth, out=np.zeros_like(tp), where=present)
    return SemanticScores(
        overall_accuracy=float(tp.sum() / total) if total else 0.0,
        mean_accuracy=float(acc[present].mean()) if present.any() else 0.0,
        mean_iou=float(iou[present].mean()) if present.any() else 0.0,
        per_class_iou={names[c]: float(iou[c]) for c in np.flatnonzero(present)},
        per_class_accuracy={names[c]: float(acc[c]) for c in np.flatnonzero(present)},
        points=total,
        confusion={
            names[t]: {(names[p] if p < num_classes else "unlabelled"): int(cm[t, p]) for p in np.flatnonzero(cm[t])}
            for t in np.flatnonzero(present)
        },
    )


def cluster_scores(true_ids: np.ndarray, pred_ids: np.ndarray) -> ClusterScores:
    t = np.asarray(true_ids).ravel()
    p = np.asarray(pred_ids).ravel()
    if len(t) == 0:
        return ClusterScores(0.0, 0.0, 0.0)
    return ClusterScores(
        nmi=float(normalized_mutual_info_score(t, p)),
        ami=float(adjusted_mutual_info_score(t, p)),
        ari=float(adjusted_rand_score(t, p)),
    )


def instance_iou_pairs(true_ids: np.ndarray, pred_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every (true id, predicted id) pair that shares points (ids > 0 only) and its IoU."""
    t = np.asarray(true_ids, dtype=np.int64).ravel()
    p = np.asarray(pred_ids, dtype=np.int64).ravel()
    t_ids, t_size = np.unique(t[t > 0], return_counts=True)
    p_ids, p_size = np.unique(p[p > 0], return_counts=True)
    both = (t > 0) & (p > 0)
    pairs, inter = np.unique(np.stack([t[both], p[both]], axis=1), axis=0, return_counts=True)
    if not len(pairs):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    ts = t_size[np.searchsorted(t_ids, pairs[:, 0])]
    ps = p_size[np.searchsorted(p_ids, pairs[:, 1])]
    return pairs[:, 0], pairs[:, 1], inter / (ts + ps - inter)


def instance_scores(true_ids: np.ndarray, pred_ids: np.ndarray, threshold: float = IOU_THRESHOLD) -> InstanceScores:
    t = np.asarray(true_ids).ravel()
    p = np.asarray(pred_ids).ravel()
    n_true = len(np.unique(t[t > 0]))
    n_pred = len(np.unique(p[p > 0]))
    ti, pi, iou = instance_iou_pairs(t, p)
    matched = 0
    cand = iou > threshold
    if cand.any():
        # Hungarian assignment over the instances that have a candidate match; sparse everywhere else.
        rows, r_inv = np.unique(ti[cand], return_inverse=True)
        cols, c_inv = np.unique(pi[cand], return_inverse=True)
        m = np.zeros((len(rows), len(cols)))
        m[r_inv, c_inv] = iou[cand]
        r, c = linear_sum_assignment(m, maximize=True)
        matched = int((m[r, c] > threshold).sum())
    best = np.zeros(n_true)
    if len(ti):
        t_ids = np.unique(t[t > 0])
        np.maximum.at(best, np.searchsorted(t_ids, ti), iou)
    return InstanceScores(
        precision=matched / n_pred if n_pred else 0.0,
        recall=matched / n_true if n_true else 0.0,
        mean_iou=float(best.mean()) if n_true else 0.0,
        true_instances=n_true,
        predicted_instances=n_pred,
        matched=matched,
    )
