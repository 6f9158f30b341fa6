"""Optimiser with one parameter group per Gaussian attribute, and adaptive density control.

Density control (3DGS): screen-space gradients of the projected means are accumulated per
Gaussian while it is visible; every ``every`` steps Gaussians whose mean gradient exceeds the
threshold are cloned (small ones) or split in two smaller ones sampled from themselves (large
ones), and nearly transparent or oversized Gaussians are pruned. Opacities are reset now and
then so that useless Gaussians can fade out and be pruned. Growth stops at ``max_gaussians``:
the largest gradients win the remaining budget. Every edit keeps the Adam moments of surviving
rows and starts new rows with zero moments.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from recondreamer.recon.base import GaussianSceneModel
from recondreamer.recon.config import DensifyConfig, OptimConfig
from recondreamer.recon.gaussians import inverse_sigmoid
from recondreamer.splat.projection import quats_to_rotmats

CORE_LEARNING_RATES = {
    "means": "means",
    "quats": "quats",
    "log_scales": "scales",
    "logit_opacities": "opacities",
    "sh_dc": "sh_dc",
    "sh_rest": "sh_rest",
}
SPLIT_CHILDREN = 2
SPLIT_SCALE_DIVISOR = 1.6  # children are 1/(0.8 N) the size of their parent (3DGS)
RESET_OPACITY = 0.01


def build_optimizer(model: GaussianSceneModel, config: OptimConfig) -> torch.optim.Adam:
    """Adam: one named group per Gaussian attribute, plus "field", "grid" and "sky" groups.

    Position learning rates are multiplied by the scene extent (3DGS's spatial LR scale);
    backbone-specific per-Gaussian attributes (PVG's velocity, peak time, lifespan) use the
    "dynamics" rate.
    """
    groups = []
    for name, param in model.gaussians.params.items():
        rate_name = CORE_LEARNING_RATES.get(name, "dynamics")
        lr = getattr(config, rate_name) * (model.extent if name == "means" else 1.0)
        groups.append({"params": [param], "lr": lr, "name": name})
    if model.field_parameters():
        groups.append(
            {"params": model.field_parameters(), "lr": config.field, "name": "field"}
        )
    if model.grid_parameters():
        groups.append(
            {"params": model.grid_parameters(), "lr": config.grid, "name": "grid"}
        )
    groups.append(
        {"params": list(model.sky.parameters()), "lr": config.sky, "name": "sky"}
    )
    # fused: one kernel per parameter group instead of a dozen tensor ops per parameter.
    return torch.optim.Adam(groups, eps=1e-15, fused=True)


def exponential_lr(step: int, total: int, start: float, end: float) -> float:
    """Log-linear decay from ``start`` at step 0 to ``end`` at ``total``."""
    fraction = min(max(step / max(total, 1), 0.0), 1.0)
    return math.exp((1 - fraction) * math.log(start) + fraction * math.log(end))


def update_learning_rates(
    optimizer: torch.optim.Optimizer,
    model: GaussianSceneModel,
    config: OptimConfig,
    step: int,
    total: int,
) -> None:
    """Exponential decay of the position, deformation-field and feature-grid rates."""
    for group in optimizer.param_groups:
        if group["name"] == "means":
            group["lr"] = (
                exponential_lr(step, total, config.means, config.means_final)
                * model.extent
            )
        elif group["name"] == "field":
            group["lr"] = exponential_lr(step, total, config.field, config.field_final)
        elif group["name"] == "grid":
            group["lr"] = exponential_lr(step, total, config.grid, config.grid_final)


def _group_of(optimizer: torch.optim.Optimizer, name: str) -> dict:
    for group in optimizer.param_groups:
        if group["name"] == name:
            return group
    raise KeyError(name)


def edit_rows(
    model: GaussianSceneModel,
    optimizer: torch.optim.Optimizer,
    keep: torch.Tensor,  # (N,) bool
    new_rows: dict[str, torch.Tensor] | None = None,  # name -> (M, ...)
) -> None:
    """Keep the rows ``keep`` of every per-Gaussian tensor and append ``new_rows``.

    Adam moments follow their rows; appended rows start with zero moments.
    """
    gaussians = model.gaussians
    new_rows = new_rows or {}
    for name in gaussians.row_names:
        old = gaussians.params[name]
        added = new_rows.get(name, old.data[:0])
        param = nn.Parameter(torch.cat((old.data[keep], added.to(old.dtype))))
        group = _group_of(optimizer, name)
        state = optimizer.state.pop(old, None)
        if state:
            for key in ("exp_avg", "exp_avg_sq"):
                state[key] = torch.cat((state[key][keep], torch.zeros_like(added)))
            optimizer.state[param] = state
        group["params"][0] = param
        gaussians.params[name] = param
    for name, value in gaussians.buffer_rows().items():
        setattr(
            gaussians,
            name,
            torch.cat((value[keep], new_rows.get(name, value[:0]).to(value.dtype))),
        )


class DensityController:
    """Accumulates screen-space gradient statistics and edits the Gaussians on schedule."""

    def __init__(
        self,
        config: DensifyConfig,
        iterations: int,
        num_gaussians: int,
        device: torch.device | str = "cpu",
    ) -> None:
        self.config = config
        self.stop = int(config.stop_fraction * iterations)
        self.device = torch.device(device)
        self.reset_stats(num_gaussians)

    def reset_stats(self, num: int) -> None:
        self.grad_sum = torch.zeros(
            num, device=self.device
        )  # (N,) sum of NDC gradient norms while visible
        self.visible_count = torch.zeros(num, device=self.device)  # (N,)
        self.max_radius = torch.zeros(num, device=self.device)  # (N,) pixels

    def accumulate(
        self, means2d_grad: torch.Tensor, radii: torch.Tensor, width: int, height: int
    ) -> None:
        """Add one view's screen-space mean gradients (N,2) in pixels; converted to NDC units."""
        visible = radii > 0
        scale = torch.tensor([width / 2.0, height / 2.0], device=means2d_grad.device)
        norms = (means2d_grad * scale).norm(dim=-1)
        self.grad_sum += torch.where(visible, norms, torch.zeros_like(norms))
        self.visible_count += visible.float()
        self.max_radius = torch.maximum(self.max_radius, radii.float())

    def step(
        self,
        step: int,
        model: GaussianSceneModel,
        optimizer: torch.optim.Optimizer,
        generator: torch.Generator,
    ) -> dict[str, int] | None:
        """Densify/prune/reset when ``step`` (1-based, after the optimiser step) is scheduled."""
        cfg = self.config
        if step > self.stop:
            return None
        report = None
        if step >= cfg.start and step % cfg.every == 0:
            report = self.densify_and_prune(model, optimizer, generator)
        if (
            cfg.reset_opacity_every
            and step % cfg.reset_opacity_every == 0
            and step < self.stop
        ):
            self.reset_opacities(model, optimizer)
        return report

    def densify_and_prune(
        self,
        model: GaussianSceneModel,
        optimizer: torch.optim.Optimizer,
        generator: torch.Generator,
    ) -> dict[str, int]:
        cfg = self.config
        gaussians = model.gaussians
        num = len(gaussians)
        mean_grad = self.grad_sum / self.visible_count.clamp_min(1.0)
        scales = gaussians.scales().detach()
        max_scale = scales.max(dim=1).values
        candidates = mean_grad >= cfg.grad_threshold
        budget = max(cfg.max_gaussians - num, 0)
        if int(candidates.sum()) > budget:
            # Each clone or split adds one Gaussian: the largest gradients win the budget.
            order = torch.argsort(
                torch.where(candidates, mean_grad, torch.full_like(mean_grad, -1.0)),
                descending=True,
            )
            candidates = torch.zeros_like(candidates)
            candidates[order[:budget]] = True
        small = max_scale <= cfg.percent_dense * model.extent
        clone = candidates & small
        split = candidates & ~small

        params = {name: p.data for name, p in gaussians.params.items()}
        buffers = gaussians.buffer_rows()
        new_rows = {name: value[clone] for name, value in {**params, **buffers}.items()}
        # Split: children sampled from the parent Gaussian, scaled down; the parent is removed.
        split_idx = torch.nonzero(split).squeeze(1).repeat(SPLIT_CHILDREN)
        if len(split_idx):
            std = scales[split_idx]
            # Drawn on the CPU generator: the same draws on any device, saved in checkpoints.
            offsets = torch.randn(std.shape, generator=generator).to(std.device) * std
            rotations = quats_to_rotmats(params["quats"][split_idx])
            children = {
                name: value[split_idx] for name, value in {**params, **buffers}.items()
            }
            children["means"] = (
                params["means"][split_idx] + (rotations @ offsets[:, :, None])[:, :, 0]
            )
            children["log_scales"] = torch.log(std / (0.8 * SPLIT_CHILDREN))
            new_rows = {
                name: torch.cat((new_rows[name], children[name])) for name in new_rows
            }

        opacities = gaussians.opacities().detach()
        distance = (self._world_means(model) - model.center).norm(dim=1)
        too_big = max_scale > cfg.max_world_scale * torch.clamp_min(
            distance, model.extent
        )
        prune = (opacities < cfg.min_opacity) | too_big
        if cfg.max_screen_radius > 0:
            prune |= self.max_radius > cfg.max_screen_radius
        keep = ~(prune | split)
        edit_rows(model, optimizer, keep, new_rows)
        self.reset_stats(len(gaussians))
        return {
            "cloned": int(clone.sum()),
            "split": int(split.sum()),
            "pruned": int((prune & ~split).sum()),
            "total": len(gaussians),
        }

    @staticmethod
    def _world_means(
        model: GaussianSceneModel,
    ) -> torch.Tensor:  # (N,3) at mid-segment, statically
        with torch.no_grad():
            return model.gaussians_at(0.5, static=True)["means"]

    def reset_opacities(
        self, model: GaussianSceneModel, optimizer: torch.optim.Optimizer
    ) -> None:
        param = model.gaussians.params["logit_opacities"]
        with torch.no_grad():
            param.clamp_(max=float(inverse_sigmoid(torch.tensor(RESET_OPACITY))))
        state = optimizer.state.get(param)
        if state:
            state["exp_avg"].zero_()
            state["exp_avg_sq"].zero_()

    def state_dict(self) -> dict:
        return {
            "grad_sum": self.grad_sum,
            "visible_count": self.visible_count,
            "max_radius": self.max_radius,
        }

    def load_state_dict(self, state: dict) -> None:
        self.grad_sum = state["grad_sum"].to(self.device).clone()
        self.visible_count = state["visible_count"].to(self.device).clone()
        self.max_radius = state["max_radius"].to(self.device).clone()
