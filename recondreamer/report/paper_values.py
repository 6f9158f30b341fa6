"""The numbers of the paper's tables 1-5 (ReconDreamer, CVPR 2025), for the findings page.

Keyed by table, then by this project's run id (``recondreamer.report.layout.Method.run_id``)
of the row, then by (trajectory, metric); "Average" is the paper's average column. Metrics:
nta_iou (fraction), ntl_iou (percent), fid. Table 3 holds win rates in percent, keyed by the
opponent's run id. These are the published values, quoted beside ours; no table of this
project is computed from them.
"""

from __future__ import annotations

AVERAGE = "Average"
_COLUMNS = ("shift@3", "shift@6", "lane_change", AVERAGE)
_METRICS = ("nta_iou", "ntl_iou", "fid")


def _row(*values: float) -> dict[tuple[str, str], float]:
    """12 numbers in the paper's column order: per trajectory (and Average) NTA-IoU, NTL-IoU, FID."""
    assert len(values) == 12
    return {(trajectory, metric): values[3 * i + j] for i, trajectory in enumerate(_COLUMNS) for j, metric in enumerate(_METRICS)}


_BASELINES = {
    "baseline-pvg": _row(0.242, 49.99, 134.74, 0.118, 48.32, 212.19, 0.256, 50.70, 105.29, 0.205, 49.67, 150.74),
    "baseline-s3": _row(0.059, 48.24, 234.54, 0.014, 47.69, 311.59, 0.175, 49.05, 124.90, 0.083, 48.33, 223.68),
    "baseline-deformable": _row(0.142, 50.63, 161.20, 0.069, 48.86, 260.83, 0.240, 51.62, 92.34, 0.150, 50.37, 171.46),
    "baseline-street": _row(0.498, 53.19, 130.75, 0.374, 49.27, 213.04, 0.496, 56.03, 86.46, 0.456, 52.83, 143.42),
}

PAPER: dict[int, dict[str, dict]] = {
    1: {
        **_BASELINES,
        "recondreamer-street-dd2_mask-stride1.5": _row(0.539, 54.58, 93.56, 0.467, 52.58, 149.19, 0.554, 56.63, 73.91, 0.517, 54.60, 105.55),
    },
    2: {
        **_BASELINES,
        "dd4d-pvg": _row(0.340, 51.32, 129.05, 0.121, 49.28, 210.37, 0.438, 53.06, 71.52, 0.300, 51.22, 136.98),
        "recondreamer-pvg-dd2_mask-stride1.5": _row(0.474, 52.06, 124.12, 0.358, 50.14, 177.58, 0.464, 53.21, 74.32, 0.432, 51.80, 125.34),
        "dd4d-s3": _row(0.263, 51.07, 173.49, 0.031, 48.04, 303.95, 0.495, 53.42, 66.93, 0.263, 50.84, 181.46),
        "recondreamer-s3-dd2_mask-stride1.5": _row(0.267, 50.26, 110.41, 0.177, 50.54, 152.89, 0.413, 51.62, 123.61, 0.286, 50.80, 128.97),
        "dd4d-deformable": _row(0.181, 50.72, 169.79, 0.078, 48.90, 259.19, 0.335, 52.93, 77.32, 0.198, 50.85, 168.77),
        "recondreamer-deformable-dd2_mask-stride1.5": _row(0.416, 52.26, 106.99, 0.294, 50.54, 143.88, 0.443, 53.78, 76.24, 0.384, 52.19, 109.04),
    },
    3: {  # ReconDreamer (Street Gaussians) win rate in percent against the run id
        "baseline-street": {"shift@3": 97.92, "shift@6": 100.00, "lane_change": 93.75, AVERAGE: 97.22},
        "dd4d-pvg": {"shift@3": 96.88, "shift@6": 100.00, "lane_change": 93.75, AVERAGE: 96.88},
    },
    4: {
        "recondreamer-street-sd-stride1.5": _row(0.504, 54.51, 112.25, 0.389, 52.13, 178.16, 0.509, 56.42, 80.90, 0.467, 54.35, 123.77),
        "recondreamer-street-svd-stride1.5": _row(0.500, 53.33, 120.46, 0.435, 49.67, 199.40, 0.527, 56.05, 89.89, 0.487, 53.02, 136.58),
        "recondreamer-street-dd2-stride1.5": _row(0.525, 54.42, 100.32, 0.456, 52.17, 152.23, 0.551, 56.67, 92.30, 0.511, 54.42, 114.95),
        "recondreamer-street-dd2_mask-stride1.5": _row(0.539, 54.52, 93.56, 0.467, 52.56, 149.19, 0.544, 56.67, 73.91, 0.517, 54.58, 105.55),
    },
    5: {
        "recondreamer-street-dd2_mask-stride0.5": _row(0.533, 54.10, 120.23, 0.452, 51.82, 162.34, 0.521, 56.78, 77.34, 0.502, 54.23, 119.97),
        "recondreamer-street-dd2_mask-stride1.0": _row(0.536, 54.13, 114.23, 0.459, 51.93, 162.46, 0.523, 56.89, 79.27, 0.506, 54.32, 118.65),
        "recondreamer-street-dd2_mask-stride1.5": _row(0.539, 54.52, 93.56, 0.467, 52.56, 149.19, 0.554, 56.67, 73.91, 0.517, 54.58, 105.55),
        "recondreamer-street-dd2_mask-stride3.0": _row(0.521, 54.26, 97.54, 0.451, 52.16, 150.43, 0.523, 57.10, 72.09, 0.498, 54.51, 106.69),
        "recondreamer-street-dd2_mask-stride6.0": _row(0.518, 54.55, 104.72, 0.447, 52.24, 168.22, 0.513, 56.40, 84.34, 0.493, 54.40, 119.09),
    },
}


def paper_value(table: int, run_id: str, trajectory: str, metric: str) -> float | None:
    """The paper's number, or None where the paper has no such row, column or metric."""
    return PAPER.get(table, {}).get(run_id, {}).get((trajectory, metric))


def paper_win_rate(versus: str, trajectory: str) -> float | None:
    return PAPER[3].get(versus, {}).get(trajectory)
