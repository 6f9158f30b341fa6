"""Which runs the paper's five tables need, and which run makes which row.

``ExperimentPlan`` is built from the workflow config (``from_config``); the Snakemake rules ask
it for the runs to schedule (``runs()``) and the table builder asks it for the rows of each
table, so the DAG holds exactly the runs the tables read, runs shared between tables once.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import dataclass

from recondreamer.report.layout import (
    BACKBONE_LABELS,
    ORACLE_RESTORER,
    UPPER_BOUND_LABEL,
    RESTORER_LABELS,
    Method,
    format_stride,
)


@dataclass(frozen=True)
class ExperimentPlan:
    segments: tuple[str, ...]
    trajectories: tuple[str, ...]  # evaluated novel trajectories, in column order
    backbones: tuple[str, ...]  # table 1 baselines, in row order
    dd4d_backbones: tuple[str, ...]  # table 2 groups: baseline, DriveDreamer4D, ReconDreamer
    restorers: tuple[str, ...]  # table 4 rows (ReconDreamer with the ablation backbone)
    strides: tuple[float, ...]  # table 5 rows (ReconDreamer with the ablation backbone)
    main_restorer: str = "dd2_mask"  # the restorer of "ReconDreamer" everywhere else
    main_stride: float = 1.5  # the PDUS stride of "ReconDreamer" everywhere else
    ablation_backbone: str = "street"  # backbone of tables 3-5 and of table 1's ReconDreamer row
    preference_versus: tuple[str, ...] = ("baseline-street", "dd4d-pvg")  # table 3 columns (run ids)
    oracle: bool = False  # table 1's upper-bound row: ReconDreamer fed the true novel views (synthetic segments only)

    def __post_init__(self) -> None:
        if self.main_restorer not in self.restorers:
            raise ValueError(f"main restorer {self.main_restorer!r} is not among the restorers {self.restorers}")
        if not any(abs(s - self.main_stride) < 1e-9 for s in self.strides):
            raise ValueError(f"main stride {self.main_stride} is not among the strides {self.strides}")
        if self.ablation_backbone not in self.backbones:
            raise ValueError(f"ablation backbone {self.ablation_backbone!r} is not among the backbones {self.backbones}")
        unknown = sorted(set(self.dd4d_backbones) - set(self.backbones))
        if unknown:
            raise ValueError(f"DriveDreamer4D backbone(s) {unknown} are not among the backbones {self.backbones}")
        if not self.segments or not self.trajectories:
            raise ValueError("the plan needs at least one segment and one trajectory")

    @classmethod
    def from_config(cls, config: Mapping) -> ExperimentPlan:
        """The plan of a validated workflow config (keys as in workflow/schemas/config.schema.yaml)."""
        experiment = config["experiment"]
        return cls(
            segments=tuple(segment_names(config)),
            trajectories=tuple(experiment["trajectories"]),
            backbones=tuple(experiment["recon_backbones"]),
            dd4d_backbones=tuple(experiment["dd4d_backbones"]),
            restorers=tuple(experiment["restorer_backbones"]),
            strides=tuple(float(s) for s in experiment["strides"]),
            main_restorer=experiment["main_restorer"],
            main_stride=float(experiment["main_stride"]),
            ablation_backbone=experiment["ablation_backbone"],
            preference_versus=tuple(experiment["preference_versus"]),
            oracle=config["source"] == "synthetic",
        )

    def to_arguments(self) -> list[str]:
        """Command-line options of ``recondreamer make-tables`` / ``make-plots`` describing this plan."""
        return [
            "--segments", *self.segments,
            "--trajectories", *self.trajectories,
            "--backbones", *self.backbones,
            "--dd4d-backbones", *self.dd4d_backbones,
            "--restorers", *self.restorers,
            "--strides", *(format_stride(s) for s in self.strides),
            "--main-restorer", self.main_restorer,
            "--main-stride", format_stride(self.main_stride),
            "--ablation-backbone", self.ablation_backbone,
            "--versus", *self.preference_versus,
            *(["--oracle"] if self.oracle else []),
        ]

    # ----------------------------------------------------------------- methods

    def baseline(self, backbone: str) -> Method:
        return Method("baseline", backbone)

    def dd4d(self, backbone: str) -> Method:
        return Method("dd4d", backbone)

    def recondreamer(self, backbone: str, restorer: str | None = None, stride: float | None = None) -> Method:
        return Method("recondreamer", backbone, restorer or self.main_restorer, self.main_stride if stride is None else stride)

    def upper_bound(self) -> Method:
        """ReconDreamer on the ablation backbone with the true novel views in place of restored renders."""
        return Method("recondreamer", self.ablation_backbone, ORACLE_RESTORER, self.main_stride)

    @property
    def recondreamer_backbones(self) -> tuple[str, ...]:
        """Backbones with a ReconDreamer run at the main settings (ablation backbone + table 2's)."""
        wanted = {self.ablation_backbone, *self.dd4d_backbones}
        return tuple(b for b in self.backbones if b in wanted)

    def runs(self) -> list[Method]:
        """Every run one segment needs for all five tables, each once, in a stable order."""
        methods = [self.baseline(b) for b in self.backbones]
        methods += [self.dd4d(b) for b in self.dd4d_backbones]
        methods += [self.recondreamer(b) for b in self.recondreamer_backbones]
        methods += [self.recondreamer(self.ablation_backbone, restorer=r) for r in self.restorers]
        methods += [self.recondreamer(self.ablation_backbone, stride=s) for s in self.strides]
        if self.oracle:
            methods.append(self.upper_bound())
        unique: dict[str, Method] = {}
        for method in methods:
            unique.setdefault(method.run_id, method)
        return list(unique.values())

    def preference_method(self) -> Method:
        return self.recondreamer(self.ablation_backbone)

    # ----------------------------------------------------------------- table rows: (label, method)

    def table1_rows(self) -> list[tuple[str, Method]]:
        rows = [(BACKBONE_LABELS.get(b, b), self.baseline(b)) for b in self.backbones]
        rows += [(self.recondreamer(b).label, self.recondreamer(b)) for b in self.recondreamer_backbones]
        if self.oracle:
            rows.append((UPPER_BOUND_LABEL, self.upper_bound()))
        return rows

    def table2_rows(self) -> list[tuple[str, Method]]:
        rows = []
        for b in self.dd4d_backbones:
            rows += [(self.baseline(b).label, self.baseline(b)), (self.dd4d(b).label, self.dd4d(b)), (self.recondreamer(b).label, self.recondreamer(b))]
        return rows

    def table4_rows(self) -> list[tuple[str, Method]]:
        return [(RESTORER_LABELS.get(r, r), self.recondreamer(self.ablation_backbone, restorer=r)) for r in self.restorers]

    def table5_rows(self) -> list[tuple[str, Method]]:
        return [(f"{format_stride(s)}m", self.recondreamer(self.ablation_backbone, stride=s)) for s in self.strides]


def add_plan_arguments(parser: argparse.ArgumentParser) -> None:
    """The options ``ExperimentPlan.to_arguments`` writes (the workflow passes them to the report commands)."""
    parser.add_argument("--segments", nargs="+", required=True, help="evaluation segment names (metrics/<segment>/...)")
    parser.add_argument("--trajectories", nargs="+", default=["shift@3", "shift@6", "lane_change"], help="evaluated trajectories, in column order")
    parser.add_argument("--backbones", nargs="+", default=["pvg", "s3", "deformable", "street"], help="table 1 baseline backbones, in row order")
    parser.add_argument("--dd4d-backbones", nargs="+", default=["pvg", "s3", "deformable"], help="table 2 backbones (baseline, DriveDreamer4D, ReconDreamer)")
    parser.add_argument("--restorers", nargs="+", default=["sd", "svd", "dd2", "dd2_mask"], help="table 4 restorer backbones")
    parser.add_argument("--strides", nargs="+", type=float, default=[0.5, 1.0, 1.5, 3.0, 6.0], help="table 5 PDUS strides in metres")
    parser.add_argument("--main-restorer", default="dd2_mask", help="restorer of ReconDreamer outside table 4 (default dd2_mask)")
    parser.add_argument("--main-stride", type=float, default=1.5, help="PDUS stride of ReconDreamer outside table 5 (default 1.5)")
    parser.add_argument("--ablation-backbone", default="street", help="backbone of tables 3-5 (default street)")
    parser.add_argument("--versus", nargs="+", default=["baseline-street", "dd4d-pvg"], help="table 3 columns: run ids ReconDreamer is compared with")
    parser.add_argument("--oracle", action="store_true", help="table 1 has the upper-bound row: ReconDreamer trained on the true novel views (synthetic segments)")


def plan_from_arguments(args: argparse.Namespace) -> ExperimentPlan:
    return ExperimentPlan(
        segments=tuple(args.segments),
        trajectories=tuple(args.trajectories),
        backbones=tuple(args.backbones),
        dd4d_backbones=tuple(args.dd4d_backbones),
        restorers=tuple(args.restorers),
        strides=tuple(args.strides),
        main_restorer=args.main_restorer,
        main_stride=args.main_stride,
        ablation_backbone=args.ablation_backbone,
        preference_versus=tuple(args.versus),
        oracle=args.oracle,
    )


def segment_names(config: Mapping) -> list[str]:
    """Evaluation segment names of the configured source, in config order."""
    source = config["source"]
    if source == "synthetic":
        return list(config["synthetic"]["segments"])
    if source == "waymo":
        return list(config["waymo"]["segments"])
    raise ValueError(f"unknown source {source!r}; expected synthetic or waymo")
