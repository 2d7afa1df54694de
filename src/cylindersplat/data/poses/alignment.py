"""How far estimated camera poses are from reference ones, up to the similarity SfM cannot know.

:func:`align_similarity` finds ``(s, R, t)`` with ``s R c_est + t ≈ c_ref`` for the camera centres and
``R R_est ≈ R_ref`` for the rotations. The rotation comes from the cameras' rotations (the chordal mean of
``R_ref R_est^T``), not from the centres: centres on one line (a panorama walk) leave a rotation about that line
undetermined. Scale and translation are then the least-squares fit of the centres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...geometry.rotations import nearest_rotation

__all__ = ["Similarity", "PoseErrors", "align_similarity", "pose_errors"]


@dataclass
class Similarity:
    scale: float
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)

    def apply_c2w(self, c2w: np.ndarray) -> np.ndarray:
        """A c2w ``(4, 4)`` of the estimated frame in the reference frame."""
        out = np.eye(4)
        out[:3, :3] = self.rotation @ c2w[:3, :3]
        out[:3, 3] = self.scale * self.rotation @ c2w[:3, 3] + self.translation
        return out


@dataclass
class PoseErrors:
    """Per camera: ``rotation_deg`` and ``centre`` (reference units) after alignment; ``baseline`` the largest
    distance between reference centres."""

    rotation_deg: list[float]
    centre: list[float]
    baseline: float
    similarity: Similarity

    @property
    def centre_over_baseline(self) -> float:
        return max(self.centre) / self.baseline


def align_similarity(estimated: np.ndarray, reference: np.ndarray) -> Similarity:
    """``estimated``, ``reference``: c2w ``(N, 4, 4)`` of the same cameras (N >= 2, distinct reference centres)."""
    est, ref = np.asarray(estimated, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    rotation = nearest_rotation(sum(r[:3, :3] @ e[:3, :3].T for e, r in zip(est, ref)))
    ce = est[:, :3, 3] @ rotation.T
    cr = ref[:, :3, 3]
    de, dr = ce - ce.mean(0), cr - cr.mean(0)
    scale = float((de * dr).sum() / (de * de).sum())
    return Similarity(scale, rotation, cr.mean(0) - scale * ce.mean(0))


def pose_errors(estimated: np.ndarray, reference: np.ndarray) -> PoseErrors:
    sim = align_similarity(estimated, reference)
    rot, centre = [], []
    for e, r in zip(np.asarray(estimated, dtype=np.float64), np.asarray(reference, dtype=np.float64)):
        aligned = sim.apply_c2w(e)
        cos = (np.trace(aligned[:3, :3].T @ r[:3, :3]) - 1.0) / 2.0
        rot.append(math.degrees(math.acos(max(-1.0, min(1.0, cos)))))
        centre.append(float(np.linalg.norm(aligned[:3, 3] - r[:3, 3])))
    ref = np.asarray(reference)[:, :3, 3]
    baseline = float(max(np.linalg.norm(a - b) for a in ref for b in ref))
    return PoseErrors(rot, centre, baseline, sim)
