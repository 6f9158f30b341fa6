"""The findings page: each claim of the paper's tables, the paper's numbers, ours, and whether it holds.

Every line compares two rows of one of our tables on one metric and one column (a trajectory or
the Average over trajectories), the way the paper's table and prose claim it ("ReconDreamer >
Street Gaussians on NTA-IoU at Lane Shift @ 6m"). Evidence, from the metric files only:

- ``k/n``: the segments where the claimed order holds (per-segment values; for FID and KID the
  per-segment diagnostics of the metrics files);
- a paired 95 % bootstrap interval over segments of the claimed improvement (better minus worse,
  signed so that positive supports the claim): segments are resampled with replacement, the
  same resamples for both rows. For NTA-IoU, NTL-IoU, PSNR and SSIM the statistic is the mean over
  the resampled segments; for FID and KID it is the pooled value recomputed on the resampled
  segments' features, exactly as the tables compute it;
- the verdict: *holds* when the whole interval supports the claim, *does not hold* when the whole
  interval contradicts it, *not significant* otherwise (and with fewer than 3 segments).

Table 3's claims (win rate above 50 %) resample segments of the judge's decisions; win rates
from people (no per-segment decisions) use an exact binomial interval over the answers.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from recondreamer.report import paper_values
from recondreamer.report.layout import RESTORER_LABELS, UPPER_BOUND_LABEL, Method, features_file, format_stride, trajectory_label
from recondreamer.experiment_plan import ExperimentPlan
from recondreamer.report.tables import METRIC_BY_KEY, METRICS, ReportInputError, format_value, read_metrics, read_win_rates

AVERAGE = paper_values.AVERAGE
BOOTSTRAP_SEGMENT_MEANS = 10000  # resamples for per-segment metrics (cheap)
BOOTSTRAP_POOLED = 200  # resamples for pooled FID/KID (each one recomputes FID and KID of every run)
POOLED_KID_SUBSETS = 20  # KID subsets inside each pooled resample
MIN_SEGMENTS = 3
CONFIDENCE = 0.95
PAPER_METRICS = ("nta_iou", "ntl_iou", "fid")
VALIDITY_METRICS = ("nta_iou", "ntl_iou", "fid", "kid", "psnr", "ssim")


@dataclass(frozen=True)
class Claim:
    table: int | str  # paper table number, or "validity"
    better: Method
    worse: Method | None  # None: a win-rate claim against 50 %
    metric: str  # METRICS key, or "win_rate"
    column: str  # trajectory name or AVERAGE
    better_label: str
    worse_label: str
    paper_table: int | None = None  # where the paper's numbers come from

    @property
    def text(self) -> str:
        where = "on average over the trajectories" if self.column == AVERAGE else f"at {trajectory_label(self.column)}"
        if self.metric == "win_rate":
            return f"{self.better_label} wins > 50 % against {self.worse_label} {where}"
        return f"{self.better_label} > {self.worse_label} on {METRIC_BY_KEY[self.metric].label} {where}"


@dataclass
class Evidence:
    claim: Claim
    paper: str
    ours: str
    improvement: float  # positive = the claimed order
    holds_in: int
    segments: int
    low: float
    high: float

    @property
    def verdict(self) -> str:
        if self.segments < MIN_SEGMENTS:
            return f"not significant (fewer than {MIN_SEGMENTS} segments)"
        if self.low > 0:
            return "holds"
        if self.high < 0:
            return "does not hold"
        return "not significant"


# ---------------------------------------------------------------------------- the claims


def paper_claims(plan: ExperimentPlan, with_win_rates: bool) -> list[Claim]:
    """The claims of the paper's tables, as rows of this plan."""
    columns = [*plan.trajectories, AVERAGE]
    widest = _widest_shift(plan)
    claims: list[Claim] = []
    ours = plan.recondreamer(plan.ablation_backbone)
    base = plan.baseline(plan.ablation_backbone)

    def add(table, better, worse, metrics, cols, better_label=None, worse_label=None, paper_table=None):
        for column in cols:
            for metric in metrics:
                claims.append(Claim(table, better, worse, metric, column, better_label or better.label, worse_label or worse.label, paper_table or (table if isinstance(table, int) else None)))

    # Table 1: ReconDreamer beats its baseline everywhere; that baseline is the strongest one.
    add(1, ours, base, PAPER_METRICS, columns)
    for backbone in plan.backbones:
        if backbone != plan.ablation_backbone:
            add(1, base, plan.baseline(backbone), PAPER_METRICS, [AVERAGE])
    # Table 2: ReconDreamer beats DriveDreamer4D, DriveDreamer4D beats its baseline.
    for backbone in plan.dd4d_backbones:
        add(2, plan.recondreamer(backbone), plan.dd4d(backbone), PAPER_METRICS, [c for c in (widest, AVERAGE) if c])
        add(2, plan.dd4d(backbone), plan.baseline(backbone), PAPER_METRICS, [AVERAGE])
    # Table 3: ReconDreamer's win rates.
    if with_win_rates:
        for versus in plan.preference_versus:
            opponent = Method.from_run_id(versus)
            add(3, plan.preference_method(), opponent, ["win_rate"], columns, better_label=plan.preference_method().label)
    # Table 4: DriveDreamer-2+Mask is the best backbone; DriveDreamer-2 beats SD and SVD.
    restorer_pairs = [("dd2_mask", other) for other in plan.restorers if other != "dd2_mask"]
    restorer_pairs += [("dd2", other) for other in ("sd", "svd") if other in plan.restorers]
    for better, worse in restorer_pairs:
        if better in plan.restorers:
            add(4, plan.recondreamer(plan.ablation_backbone, restorer=better), plan.recondreamer(plan.ablation_backbone, restorer=worse), PAPER_METRICS, [AVERAGE],
                better_label=RESTORER_LABELS.get(better, better), worse_label=RESTORER_LABELS.get(worse, worse))
    # Table 5: the main stride beats every other stride (6 m = no PDUS).
    for stride in plan.strides:
        if abs(stride - plan.main_stride) > 1e-9:
            add(5, plan.recondreamer(plan.ablation_backbone), plan.recondreamer(plan.ablation_backbone, stride=stride), PAPER_METRICS, [AVERAGE],
                better_label=f"stride {format_stride(plan.main_stride)} m", worse_label=f"stride {format_stride(stride)} m")
    return [claim for claim in claims if _paper_shows(claim)]


def _paper_shows(claim: Claim) -> bool:
    """False where the paper's own numbers show the opposite order (then the paper does not claim
    it: e.g. its table 2 has DriveDreamer4D ahead of ReconDreamer on S3Gaussian's average NTL-IoU)."""
    if claim.metric not in PAPER_METRICS or claim.paper_table is None:
        return True
    better = paper_values.paper_value(claim.paper_table, claim.better.run_id, claim.column, claim.metric)
    worse = paper_values.paper_value(claim.paper_table, claim.worse.run_id, claim.column, claim.metric)
    if better is None or worse is None:
        return True
    return better < worse if claim.metric == "fid" else better > worse


def validity_claims(plan: ExperimentPlan, metrics: Sequence[str]) -> list[Claim]:
    """The upper bound must beat the baseline at the widest shift on every metric, or the metric cannot rank."""
    widest = _widest_shift(plan)
    if not plan.oracle or widest is None:
        return []
    base = plan.baseline(plan.ablation_backbone)
    return [Claim("validity", plan.upper_bound(), base, metric, widest, UPPER_BOUND_LABEL, base.label) for metric in metrics]


def _widest_shift(plan: ExperimentPlan) -> str | None:
    from recondreamer.report.layout import trajectory_shift

    shifts = [(abs(trajectory_shift(t)), t) for t in plan.trajectories if trajectory_shift(t) is not None]
    return max(shifts)[1] if shifts else None


# ---------------------------------------------------------------------------- the evidence


class MetricData:
    """Per-segment values and pooled FID/KID (with segment resamples) of the runs the claims need."""

    def __init__(self, plan: ExperimentPlan, results_dir: str | Path, methods: Sequence[Method], seed: int = 0):
        self.plan = plan
        self.segments = list(plan.segments)
        # Every metric file once: per-segment values, FID and KID as the segments' diagnostics (for k/n).
        long = read_metrics(results_dir, self.segments, methods, plan.trajectories, METRICS)
        self.values = {(r.run, r.trajectory, r.metric, r.segment): r.value for r in long.itertuples()}
        self.features = self._read_features(results_dir, methods)
        rng = np.random.default_rng(seed)
        n = len(self.segments)
        self.mean_resamples = rng.integers(0, n, size=(BOOTSTRAP_SEGMENT_MEANS, n))
        self.pooled_resamples = rng.integers(0, n, size=(BOOTSTRAP_POOLED, n))
        self._pooled_cache: dict[tuple[str, str, str], np.ndarray] = {}
        self._basis_cache: dict[tuple[bytes, int], tuple[np.ndarray, np.ndarray]] = {}

    def _read_features(self, results_dir, methods) -> dict:
        from recondreamer.evaluation.evaluate import read_feature_file

        features = {}
        for method in methods:
            for segment in self.segments:
                path = features_file(results_dir, segment, method.run_id)
                if not path.is_file():
                    raise ReportInputError(f"{path}: FID feature file missing (written by the workflow's evaluate rule)")
                features[(method.run_id, segment)] = read_feature_file(path)
        return features

    def segment_values(self, run_id: str, metric: str, column: str) -> np.ndarray:  # (n,) NaN where undefined
        trajectories = self.plan.trajectories if column == AVERAGE else [column]
        rows = []
        for segment in self.segments:
            per = [self.values.get((run_id, t, metric, segment)) for t in trajectories]
            per = [math.nan if v is None else float(v) for v in per]
            rows.append(float(np.nanmean(per)) if not all(math.isnan(v) for v in per) else math.nan)
        return np.array(rows)

    def _pooled_trajectory(self, run_id: str, metric: str, trajectory: str, indices) -> float:
        from recondreamer.evaluation import frechet

        chosen = range(len(self.segments)) if indices is None else indices
        renders = np.concatenate([self.features[(run_id, self.segments[i])].renders[trajectory] for i in chosen])
        reference = np.concatenate([self.features[(run_id, self.segments[i])].reference for i in chosen])
        if metric == "fid":
            # Every run of a segment shares its reference features, so a resample's principal
            # basis serves all runs and trajectories: computed once (its eigh was 3/4 of the time).
            dim = frechet.fid_dimension(min(len(renders), len(reference)), reference.shape[1])
            key = (hashlib.sha1(reference.tobytes()).digest(), dim)
            if key not in self._basis_cache:
                self._basis_cache[key] = frechet.reference_basis(reference, dim)
            return frechet.pooled_fid_from_features(renders, reference, dim, basis=self._basis_cache[key])["fid"]
        subsets = frechet.KID_SUBSETS if indices is None else POOLED_KID_SUBSETS
        return 1000.0 * frechet.kid_from_features(renders, reference, num_subsets=subsets)["kid"]

    def pooled(self, run_id: str, metric: str, column: str) -> float:
        """The table's pooled FID or KID x1000 of ``run_id`` (Average: mean over the trajectories)."""
        trajectories = self.plan.trajectories if column == AVERAGE else [column]
        return float(np.mean([self._pooled_trajectory(run_id, metric, t, None) for t in trajectories]))

    def pooled_resampled(self, run_id: str, metric: str, column: str) -> np.ndarray:  # (B,)
        """The pooled value on each segment resample (the same resamples for every run)."""
        if column == AVERAGE:
            return np.mean([self.pooled_resampled(run_id, metric, t) for t in self.plan.trajectories], axis=0)
        key = (run_id, metric, column)
        if key not in self._pooled_cache:
            self._pooled_cache[key] = np.array([self._pooled_trajectory(run_id, metric, column, idx) for idx in self.pooled_resamples])
        return self._pooled_cache[key]


def _interval(samples: np.ndarray) -> tuple[float, float]:
    tail = 100 * (1 - CONFIDENCE) / 2
    low, high = np.nanpercentile(samples, [tail, 100 - tail])
    return float(low), float(high)


def _fmt(value: float | None, metric: str) -> str:
    return format_value(value, 1 if metric == "win_rate" else METRIC_BY_KEY[metric].decimals)


def metric_evidence(claim: Claim, data: MetricData) -> Evidence:
    spec = METRIC_BY_KEY[claim.metric]
    sign = 1.0 if spec.higher_is_better else -1.0
    a_seg = data.segment_values(claim.better.run_id, claim.metric, claim.column)
    b_seg = data.segment_values(claim.worse.run_id, claim.metric, claim.column)
    both = ~(np.isnan(a_seg) | np.isnan(b_seg))
    per_segment = sign * (a_seg - b_seg)
    holds_in = int(np.sum(per_segment[both] > 0))
    if spec.pooled:
        a, b = data.pooled(claim.better.run_id, claim.metric, claim.column), data.pooled(claim.worse.run_id, claim.metric, claim.column)
        samples = sign * (data.pooled_resampled(claim.better.run_id, claim.metric, claim.column) - data.pooled_resampled(claim.worse.run_id, claim.metric, claim.column))
        improvement = sign * (a - b)
    else:
        a, b = float(np.nanmean(a_seg)), float(np.nanmean(b_seg))
        improvement = float(np.nanmean(per_segment[both])) if both.any() else math.nan
        masked = np.where(both, per_segment, np.nan)
        with np.errstate(all="ignore"):
            samples = np.nanmean(masked[data.mean_resamples], axis=1)
    low, high = _interval(samples) if np.isfinite(samples).any() else (math.nan, math.nan)
    paper = "—"
    if claim.paper_table is not None and claim.metric in PAPER_METRICS:
        pa = paper_values.paper_value(claim.paper_table, claim.better.run_id, claim.column, claim.metric)
        pb = paper_values.paper_value(claim.paper_table, claim.worse.run_id, claim.column, claim.metric)
        if pa is not None and pb is not None:
            paper = f"{format_value(pa, spec.decimals)} vs {format_value(pb, spec.decimals)}"
    return Evidence(claim, paper, f"{_fmt(a, claim.metric)} vs {_fmt(b, claim.metric)}", improvement, holds_in, int(both.sum()), low, high)


def win_rate_evidence(claim: Claim, document: dict, segments: Sequence[str], seed: int = 0) -> Evidence:
    ours, versus = claim.better.run_id, claim.worse.run_id
    trajectories = None if claim.column == AVERAGE else {claim.column}
    paper_rate = paper_values.paper_win_rate(versus, claim.column)
    paper = "—" if paper_rate is None else f"{paper_rate:.1f} %"
    decisions = [d for d in document.get("decisions", []) if ours in d and versus in d and (trajectories is None or d["trajectory"] in trajectories)]
    if decisions:
        by_segment: dict[str, list[float]] = {}
        for d in decisions:
            by_segment.setdefault(d["scene"], []).append(1.0 if d["winner"] == ours else 0.5 if d["winner"] is None else 0.0)
        names = [s for s in segments if s in by_segment] or sorted(by_segment)
        rates = np.array([np.mean(by_segment[s]) for s in names]) - 0.5
        rng = np.random.default_rng(seed)
        samples = rates[rng.integers(0, len(rates), size=(BOOTSTRAP_SEGMENT_MEANS, len(rates)))].mean(axis=1)
        low, high = _interval(samples)
        overall = float(np.mean([x for s in names for x in by_segment[s]]))
        return Evidence(claim, paper, f"{100 * overall:.1f} %", overall - 0.5, int(np.sum(rates > 0)), len(names), low, high)
    # People's answers: counts only (no segment of each answer); exact binomial interval, ties left out.
    from scipy.stats import binomtest

    pair = next((p for p in document.get("pairs", []) if p["method"] == ours and p["versus"] == versus), None)
    if pair is None:
        raise ReportInputError(f"win rates: no {ours} vs {versus} comparisons")
    cells = [v for t, v in pair["per_trajectory"].items() if trajectories is None or t in trajectories]
    wins, losses = sum(c["wins"] for c in cells), sum(c["losses"] for c in cells)
    rate = float(np.mean([c["win_rate"] for c in cells]))
    if wins + losses == 0:
        return Evidence(claim, paper, f"{100 * rate:.1f} %", rate - 0.5, 0, 0, math.nan, math.nan)
    interval = binomtest(wins, wins + losses).proportion_ci(CONFIDENCE)
    return Evidence(claim, paper, f"{100 * rate:.1f} %", rate - 0.5, wins, wins + losses, interval.low - 0.5, interval.high - 0.5)


# ---------------------------------------------------------------------------- the page


SECTIONS = {
    1: "Table 1: reconstruction baselines and ReconDreamer",
    2: "Table 2: DriveDreamer4D",
    3: "Table 3: preference win rates",
    4: "Table 4: DriveRestorer backbones",
    5: "Table 5: PDUS strides",
    "validity": "Metric validity: the upper bound (true novel views in the loop) must beat the baseline",
}


def build_findings(plan: ExperimentPlan, results_dir: str | Path, win_rates_file: str | Path | None = None, seed: int = 0) -> list[Evidence]:
    """Evidence for every claim of the paper's tables that this plan's runs can test."""
    win_document = None if win_rates_file is None else read_win_rates(Path(win_rates_file))
    claims = paper_claims(plan, win_document is not None) + validity_claims(plan, VALIDITY_METRICS)
    methods = {c.better.run_id: c.better for c in claims if c.metric != "win_rate"}
    methods.update({c.worse.run_id: c.worse for c in claims if c.metric != "win_rate" and c.worse is not None})
    data = MetricData(plan, results_dir, list(methods.values()), seed)
    # PSNR and SSIM exist only against true novel views (synthetic segments).
    has_truth = all(v is not None and not math.isnan(v) for (_, _, metric, _), v in data.values.items() if metric == "psnr")
    claims = [c for c in claims if has_truth or c.metric not in ("psnr", "ssim")]
    evidence = []
    for claim in claims:
        if claim.metric == "win_rate":
            evidence.append(win_rate_evidence(claim, win_document, plan.segments, seed))
        else:
            evidence.append(metric_evidence(claim, data))
    return evidence


def findings_frame(evidence: Sequence[Evidence]) -> pd.DataFrame:
    return pd.DataFrame.from_records([
        {
            "section": str(e.claim.table),
            "claim": e.claim.text,
            "paper": e.paper,
            "ours": e.ours,
            "segments": f"{e.holds_in}/{e.segments}",
            "improvement": e.improvement,
            "ci_low": e.low,
            "ci_high": e.high,
            "verdict": e.verdict,
        }
        for e in evidence
    ])


def _interval_text(e: Evidence) -> str:
    if math.isnan(e.low):
        return "n/a"
    scale = 100.0 if e.claim.metric == "win_rate" else 1.0
    unit = " pp" if e.claim.metric == "win_rate" else ""
    return f"[{scale * e.low:+.3g}, {scale * e.high:+.3g}]{unit}"


def to_markdown(evidence: Sequence[Evidence], plan: ExperimentPlan, notes: Sequence[str] = ()) -> str:
    counts = pd.Series([e.verdict.split(" (")[0] for e in evidence]).value_counts()
    lines = [
        "# Findings: the paper's claims on this run",
        "",
        f"Segments: {len(plan.segments)} ({', '.join(plan.segments)}). Each line: the paper's numbers (where its tables have the row), "
        "ours (the tables' values), the segments where the claimed order holds, a paired 95 % bootstrap interval over segments of the "
        "improvement in the claimed direction (positive supports the claim; "
        f"{BOOTSTRAP_SEGMENT_MEANS} resamples, {BOOTSTRAP_POOLED} for the pooled FID/KID), and the verdict: holds (the whole interval is positive), "
        "does not hold (the whole interval is negative), not significant (otherwise).",
        "",
        "Summary: " + ", ".join(f"{counts.get(v, 0)} {v}" for v in ("holds", "not significant", "does not hold")) + f" of {len(evidence)} claims.",
    ]
    if notes:
        lines += ["", *[f"- {n}" for n in notes]]
    for section, title in SECTIONS.items():
        rows = [e for e in evidence if e.claim.table == section]
        if not rows:
            continue
        lines += ["", f"## {title}", "", "| claim | paper | ours | segments | 95 % interval | verdict |", "|---|---|---|---|---|---|"]
        lines += [f"| {e.claim.text} | {e.paper} | {e.ours} | {e.holds_in}/{e.segments} | {_interval_text(e)} | **{e.verdict}** |" for e in rows]
    return "\n".join(lines) + "\n"


def to_html(markdown_text: str, evidence: Sequence[Evidence]) -> str:
    """A standalone HTML page of the findings (tables as HTML tables) for the Snakemake report."""
    import html

    head = [line for line in markdown_text.splitlines() if line and not line.startswith(("|", "##"))]
    parts = ["<!DOCTYPE html>", "<html><head><meta charset='utf-8'><title>Findings</title>",
             "<style>body{font-family:sans-serif;max-width:1200px} table{border-collapse:collapse} td,th{padding:2px 8px;border-bottom:1px solid #ddd;text-align:left}"
             " .holds{color:#060} .does{color:#a00} .not{color:#666}</style></head><body>"]
    for line in head:
        if line.startswith("# "):
            parts.append(f"<h1>{html.escape(line[2:])}</h1>")
        elif line.startswith("- "):
            parts.append(f"<p>{html.escape(line[2:])}</p>")
        else:
            parts.append(f"<p>{html.escape(line)}</p>")
    for section, title in SECTIONS.items():
        rows = [e for e in evidence if e.claim.table == section]
        if not rows:
            continue
        parts += [f"<h2>{html.escape(title)}</h2>", "<table><tr><th>claim</th><th>paper</th><th>ours</th><th>segments</th><th>95 % interval</th><th>verdict</th></tr>"]
        for e in rows:
            css = e.verdict.split()[0]
            parts.append(
                f"<tr><td>{html.escape(e.claim.text)}</td><td>{html.escape(e.paper)}</td><td>{html.escape(e.ours)}</td>"
                f"<td>{e.holds_in}/{e.segments}</td><td>{html.escape(_interval_text(e))}</td><td class='{css}'><b>{html.escape(e.verdict)}</b></td></tr>"
            )
        parts.append("</table>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def write_findings(evidence: Sequence[Evidence], plan: ExperimentPlan, out_md: str | Path, notes: Sequence[str] = ()) -> list[Path]:
    """Write findings.md, findings.html and findings.csv (same stem) atomically."""
    from recondreamer.io import write_text_atomic

    out_md = Path(out_md)
    text = to_markdown(evidence, plan, notes)
    outputs = {
        out_md: text,
        out_md.with_suffix(".html"): to_html(text, evidence),
        out_md.with_suffix(".csv"): findings_frame(evidence).to_csv(index=False, float_format="%.6g"),
    }
    for path, content in outputs.items():
        write_text_atomic(path, content)
    return list(outputs)
