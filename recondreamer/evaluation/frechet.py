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


def checked_features(features: np.ndarray) -> np.ndarray:  # (N,D) -> (N,D) float64
    """A feature set as float64, refused (ValueError) unless it is (N, D), N >= 2, all finite.

    At least two samples are needed for a covariance; fewer raise rather than giving a made-up
    number.
    """
    features = np.asarray(features, dtype=np.float64)
    if features.ndim != 2:
        raise ValueError(f"features must be (N, D), got shape {features.shape}")
    if features.shape[0] < 2:
        raise ValueError(f"a covariance needs at least 2 samples, got {features.shape[0]}")
    if not np.all(np.isfinite(features)):
        raise ValueError("features contain NaN or infinite values")
    return features


def gaussian_stats(features: np.ndarray) -> GaussianStats:  # features (N,D)
    """Sample mean and unbiased covariance (ddof=1), as pytorch-fid computes them."""
    features = checked_features(features)
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


def frechet_distance_from_samples(features1: np.ndarray, features2: np.ndarray) -> float:  # (N1,D), (N2,D)
    """``frechet_distance`` of the two sets' Gaussian fits without forming a D x D matrix.

    With a = centred features1 / sqrt(N1-1) (N1,D) and b likewise, S1 = a^T a and S2 = b^T b,
    and tr((S1 S2)^(1/2)) is the sum of the singular values of a b^T (N1,N2): O(N1 N2 D)
    instead of the reference's O(D^3). The fast path of a per-scene FID (24-72 frames against
    D = 512 features): ``fid_from_features`` takes it whenever a set has fewer samples than
    dimensions; ``frechet_distance`` is its reference twin.
    """
    means, centred = [], []
    for features in (features1, features2):
        features = np.asarray(features, dtype=np.float64)
        means.append(features.mean(axis=0))
        centred.append((features - means[-1]) / np.sqrt(features.shape[0] - 1))
    a, b = centred
    diff = means[0] - means[1]
    trace_sqrt = float(np.linalg.svd(a @ b.T, compute_uv=False).sum())
    return max(float(diff @ diff + (a * a).sum() + (b * b).sum() - 2.0 * trace_sqrt), 0.0)


def fid_from_features(features1: np.ndarray, features2: np.ndarray) -> dict:  # (N1,D), (N2,D)
    """FID between two feature sets plus the sample facts a reader needs to judge it.

    With fewer samples than feature dimensions the covariances are rank deficient: the
    Frechet distance of the two Gaussian fits is still computed exactly, but as an estimate
    of the population FID it is biased upwards; the returned dict says so.
    """
    features1, features2 = checked_features(features1), checked_features(features2)
    (num1, dim), (num2, dim2) = features1.shape, features2.shape
    if dim != dim2:
        raise ValueError(f"feature dimensions differ: {dim} vs {dim2}")
    if min(num1, num2) < dim:  # the covariances are never formed on this path
        fid = frechet_distance_from_samples(features1, features2)
    else:
        stats1, stats2 = gaussian_stats(features1), gaussian_stats(features2)
        fid = frechet_distance(stats1.mean, stats1.cov, stats2.mean, stats2.cov)
    return {
        "fid": fid,
        "num_samples": [num1, num2],
        "feature_dim": dim,
        "covariance_full_rank": bool(num1 > dim and num2 > dim),
    }


# ---------------------------------------------------------------------------- pooled FID

# The pooled FID keeps at most one feature dimension per this many samples of the smaller set:
# a Gaussian fit of n samples in d dimensions is only trustworthy when n is several times d.
MIN_SAMPLES_PER_DIMENSION = 4


def reference_basis(reference: np.ndarray, dim: int) -> tuple[np.ndarray, np.ndarray]:  # (N,D) -> mean (D,), basis (D,dim)
    """Mean and the ``dim`` leading principal directions of the reference features.

    Fitted on the reference set only, so every method compared against that reference is
    projected onto the same axes.
    """
    reference = np.asarray(reference, dtype=np.float64)
    mean = reference.mean(axis=0)
    centred = reference - mean
    eigvals, eigvecs = np.linalg.eigh(centred.T @ centred)  # ascending
    order = np.argsort(eigvals)[::-1][:dim]
    return mean, eigvecs[:, order]


def fid_dimension(num_samples: int, feature_dim: int) -> int:
    """Feature dimensions the pooled FID keeps for ``num_samples`` samples (the smaller set)."""
    return int(max(1, min(feature_dim, num_samples // MIN_SAMPLES_PER_DIMENSION)))


def pooled_fid_from_features(
    features: np.ndarray,  # (N1,D)
    reference: np.ndarray,  # (N2,D)
    dim: int | None = None,
    basis: tuple[np.ndarray, np.ndarray] | None = None,  # reference_basis(reference, dim): (D,), (D,dim)
) -> dict:
    """FID of ``features`` against ``reference`` in the reference's leading principal subspace.

    ``dim`` defaults to :func:`fid_dimension` of the smaller set; with ``dim`` equal to the
    feature dimension the projection is a rotation and the value equals
    :func:`fid_from_features` (FID is rotation invariant). ``basis``, when given, must be
    :func:`reference_basis` of this ``reference`` and ``dim``: callers that score many feature
    sets against one reference (the findings' bootstrap) compute its eigen-decomposition once.
    """
    features, reference = np.asarray(features, np.float64), np.asarray(reference, np.float64)
    if features.ndim != 2 or reference.ndim != 2 or features.shape[1] != reference.shape[1]:
        raise ValueError(f"features must be (N, D) with the same D, got {features.shape} and {reference.shape}")
    feature_dim = features.shape[1]
    if dim is None:
        dim = fid_dimension(min(len(features), len(reference)), feature_dim)
    if not 1 <= dim <= feature_dim:
        raise ValueError(f"FID dimension must lie in 1..{feature_dim}, got {dim}")
    if basis is None:
        basis = reference_basis(reference, dim)
    mean, basis = basis
    if mean.shape != (feature_dim,) or basis.shape != (feature_dim, dim):
        raise ValueError(f"basis must be a mean ({feature_dim},) and directions ({feature_dim}, {dim}), got {mean.shape} and {basis.shape}")
    result = fid_from_features((features - mean) @ basis, (reference - mean) @ basis)
    return {**result, "feature_dim": feature_dim, "fid_dim": int(dim), "projection": "leading principal directions of the reference features"}


# ---------------------------------------------------------------------------- KID

KID_SUBSETS = 100
KID_MAX_SUBSET = 1000


def polynomial_kernel(x: np.ndarray, y: np.ndarray) -> np.ndarray:  # (..., n, D), (..., m, D) -> (..., n, m)
    """KID's kernel k(x, y) = (x . y / D + 1)^3."""
    return (x @ np.swapaxes(y, -1, -2) / x.shape[-1] + 1.0) ** 3


def mmd2_unbiased(x: np.ndarray, y: np.ndarray) -> np.ndarray:  # (..., m, D), (..., m, D) -> (...)
    """Unbiased estimate of the squared MMD with :func:`polynomial_kernel` (equal set sizes)."""
    m = x.shape[-2]
    kxx, kyy, kxy = polynomial_kernel(x, x), polynomial_kernel(y, y), polynomial_kernel(x, y)
    diagonal = np.trace(kxx, axis1=-2, axis2=-1) + np.trace(kyy, axis1=-2, axis2=-1)
    within = (kxx.sum(axis=(-2, -1)) + kyy.sum(axis=(-2, -1)) - diagonal) / (m * (m - 1))
    return within - 2.0 * kxy.sum(axis=(-2, -1)) / (m * m)


def kid_subset_size(num_samples: int) -> int:
    """Subset size for KID: half the smaller set (so that subsets differ), at least 2, at most 1000."""
    return int(min(KID_MAX_SUBSET, max(2, num_samples // 2)))


def kid_from_features(features1: np.ndarray, features2: np.ndarray, subset_size: int | None = None, num_subsets: int = KID_SUBSETS, seed: int = 0) -> dict:
    """Kernel Inception Distance (Binkowski et al. 2018) between two feature sets.

    The unbiased squared MMD with the cubic polynomial kernel, averaged over ``num_subsets``
    random subsets of ``subset_size`` samples drawn without replacement from each set; its
    standard deviation over the subsets is reported beside it. Unbiased: two sets drawn from
    one distribution give 0 in expectation (single estimates may be negative).
    """
    x, y = np.asarray(features1, np.float64), np.asarray(features2, np.float64)
    if x.ndim != 2 or y.ndim != 2 or x.shape[1] != y.shape[1]:
        raise ValueError(f"features must be (N, D) with the same D, got {x.shape} and {y.shape}")
    smaller = min(len(x), len(y))
    if smaller < 2:
        raise ValueError(f"KID needs at least 2 samples per set, got {len(x)} and {len(y)}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("features contain NaN or infinite values")
    size = kid_subset_size(smaller) if subset_size is None else int(subset_size)
    if not 2 <= size <= smaller:
        raise ValueError(f"KID subset size must lie in 2..{smaller}, got {size}")
    if num_subsets < 1:
        raise ValueError(f"KID needs at least one subset, got {num_subsets}")
    rng = np.random.default_rng(seed)
    # One subset at a time: S kernel matrices of m x m at once would need S times the memory.
    values = np.array([mmd2_unbiased(x[rng.choice(len(x), size, replace=False)], y[rng.choice(len(y), size, replace=False)]) for _ in range(num_subsets)])
    return {
        "kid": float(values.mean()),
        "kid_std": float(values.std(ddof=1)) if num_subsets > 1 else 0.0,
        "subset_size": size,
        "num_subsets": int(num_subsets),
        "num_samples": [int(len(x)), int(len(y))],
        "feature_dim": int(x.shape[1]),
    }
