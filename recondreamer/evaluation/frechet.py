"""Exact Frechet distance between Gaussian fits of two feature sets (the core of FID).

FID = |mu1 - mu2|^2 + tr(S1) + tr(S2) - 2 tr((S1 S2)^(1/2)).

The trace of the matrix square root is computed through a symmetric route: with
A = S1^(1/2) (symmetric, from an eigen-decomposition of the PSD matrix S1),
S1 S2 is similar to A S2 A, which is symmetric positive semi-definite, so
tr((S1 S2)^(1/2)) = sum_i sqrt(lambda_i(A S2 A)). This needs no non-symmetric square
root (scipy.linalg.sqrtm's complex round-off and "singular product" retries) and is exact
up to floating-point error for rank-deficient covariances too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GaussianStats:
    """Mean and covariance of a feature set, with how many samples produced them."""

    mean: np.ndarray  # (D,) float64
    cov: np.ndarray  # (D,D) float64
    num_samples: int

    @property
    def dim(self) -> int:
        return int(self.mean.shape[0])

    @property
    def full_rank(self) -> bool:
        """Whether the sample covariance can be full rank (needs more samples than dimensions)."""
        return self.num_samples > self.dim


def gaussian_stats(features: np.ndarray) -> GaussianStats:  # features (N,D)
    """Sample mean and unbiased covariance (ddof=1), as pytorch-fid computes them.

    At least two samples are needed for a covariance; fewer raise ValueError rather than
    returning a made-up number.
    """
    features = np.asarray(features, dtype=np.float64)
    if features.ndim != 2:
        raise ValueError(f"features must be (N, D), got shape {features.shape}")
    if features.shape[0] < 2:
        raise ValueError(f"a covariance needs at least 2 samples, got {features.shape[0]}")
    if not np.all(np.isfinite(features)):
        raise ValueError("features contain NaN or infinite values")
    return GaussianStats(
        mean=features.mean(axis=0),
        cov=np.atleast_2d(np.cov(features, rowvar=False, ddof=1)),
        num_samples=int(features.shape[0]),
    )


def _psd_sqrt(matrix: np.ndarray) -> np.ndarray:  # (D,D) -> (D,D)
    """Square root of a symmetric PSD matrix; tiny negative eigenvalues from round-off clip to 0."""
    sym = (matrix + matrix.T) / 2.0
    eigvals, eigvecs = np.linalg.eigh(sym)
    return (eigvecs * np.sqrt(np.clip(eigvals, 0.0, None))) @ eigvecs.T


def trace_sqrt_product(cov1: np.ndarray, cov2: np.ndarray) -> float:
    """tr((cov1 cov2)^(1/2)) for symmetric PSD covariances."""
    root1 = _psd_sqrt(np.asarray(cov1, dtype=np.float64))
    middle = root1 @ np.asarray(cov2, dtype=np.float64) @ root1
    eigvals = np.linalg.eigvalsh((middle + middle.T) / 2.0)
    return float(np.sqrt(np.clip(eigvals, 0.0, None)).sum())


def frechet_distance(mean1: np.ndarray, cov1: np.ndarray, mean2: np.ndarray, cov2: np.ndarray) -> float:
    """Frechet (2-Wasserstein) distance between N(mean1, cov1) and N(mean2, cov2)."""
    mean1, mean2 = np.asarray(mean1, np.float64), np.asarray(mean2, np.float64)
    cov1, cov2 = np.atleast_2d(np.asarray(cov1, np.float64)), np.atleast_2d(np.asarray(cov2, np.float64))
    if mean1.shape != mean2.shape or cov1.shape != cov2.shape or cov1.shape != (mean1.size, mean1.size):
        raise ValueError(
            f"shape mismatch: means {mean1.shape} / {mean2.shape}, covariances {cov1.shape} / {cov2.shape}"
        )
    diff = mean1 - mean2
    value = float(diff @ diff + np.trace(cov1) + np.trace(cov2) - 2.0 * trace_sqrt_product(cov1, cov2))
    # The exact value is >= 0; only round-off can push it below.
    return max(value, 0.0)


def fid_from_features(features1: np.ndarray, features2: np.ndarray) -> dict:  # (N1,D), (N2,D)
    """FID between two feature sets plus the sample facts a reader needs to judge it.

    With fewer samples than feature dimensions the covariances are rank deficient: the
    Frechet distance of the two Gaussian fits is still computed exactly, but as an estimate
    of the population FID it is biased upwards; the returned dict says so.
    """
    stats1, stats2 = gaussian_stats(features1), gaussian_stats(features2)
    if stats1.dim != stats2.dim:
        raise ValueError(f"feature dimensions differ: {stats1.dim} vs {stats2.dim}")
    return {
        "fid": frechet_distance(stats1.mean, stats1.cov, stats2.mean, stats2.cov),
        "num_samples": [stats1.num_samples, stats2.num_samples],
        "feature_dim": stats1.dim,
        "covariance_full_rank": bool(stats1.full_rank and stats2.full_rank),
    }
