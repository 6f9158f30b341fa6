"""Rasterizer speed: pure-torch reference vs the C++ CPU kernel (and gsplat on CUDA if present).

Prints forward (no grad) and forward+backward milliseconds per call on a random scene of N
Gaussians in front of the camera whose splats span about 0.5-4 px standard deviation, as a
street scene seen at 240x160 would, at each requested thread count (1 and 2 by default), and
whether the CPU kernel's gradients are bit-identical at those thread counts. Run:
``python benchmarks/rasterizer.py`` (options below); ``--stages`` adds a per-stage breakdown of
the CPU kernel's forward+backward at each thread count.
"""

from __future__ import annotations

import argparse
import math
import time

import recondreamer  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads OpenMP)
import torch

from recondreamer.splat import rasterize


def random_scene(count: int, width: int, height: int, seed: int = 0):
    """N Gaussians spread over the view frustum between 2 m and 60 m depth."""
    generator = torch.Generator().manual_seed(seed)
    focal = 0.9 * width
    K = torch.tensor([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])
    depth = torch.exp(torch.empty(count).uniform_(math.log(2.0), math.log(60.0), generator=generator))
    u = torch.empty(count).uniform_(-0.1 * width, 1.1 * width, generator=generator)
    v = torch.empty(count).uniform_(-0.1 * height, 1.1 * height, generator=generator)
    means = torch.stack([(u - width / 2) * depth / focal, (v - height / 2) * depth / focal, depth], dim=-1)
    pixel_sigma = torch.exp(torch.empty(count, 3).uniform_(math.log(0.5), math.log(4.0), generator=generator))
    scales = pixel_sigma * depth[:, None] / focal
    quats = torch.randn(count, 4, generator=generator)
    opacities = torch.empty(count).uniform_(0.05, 1.0, generator=generator)
    colors = torch.rand(count, 3, generator=generator)
    return means, quats, scales, opacities, colors, torch.eye(4), K


def time_call(fn, repeats: int) -> tuple[float, float]:
    """Median wall time and median process CPU time of ``fn`` in milliseconds, after a warm-up.

    CPU time (all threads) is reported too because wall time on a shared machine mostly
    measures the other processes."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return 1000.0 * sorted(wall)[len(wall) // 2], 1000.0 * sorted(cpu)[len(cpu) // 2]


def measure(backend: str, scene, width: int, height: int, repeats: int, device: str):
    means, quats, scales, opacities, colors, viewmat, K = (t.to(device) for t in scene)
    params = [t.clone().requires_grad_() for t in (means, quats, scales, opacities, colors)]
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)

    def forward():
        with torch.no_grad():
            rasterize(means, quats, scales, opacities, colors, viewmat, K, width, height, backend=backend)
        sync()

    def forward_backward():
        out = rasterize(*params, viewmat, K, width, height, backend=backend)
        out["means2d"].retain_grad()
        (out["rgb"].sum() + out["depth"].mean() + out["alpha"].sum()).backward()
        sync()

    return time_call(forward, repeats), time_call(forward_backward, repeats)


def cpu_gradients(scene, width: int, height: int) -> list[torch.Tensor]:
    """Gradients of the CPU kernel's forward+backward with respect to every input and to means2d."""
    means, quats, scales, opacities, colors, viewmat, K = scene
    params = [t.clone().requires_grad_() for t in (means, quats, scales, opacities, colors)]
    out = rasterize(*params, viewmat, K, width, height, backend="cpu")
    out["means2d"].retain_grad()
    (out["rgb"].sum() + out["depth"].mean() + out["alpha"].sum()).backward()
    return [param.grad for param in params] + [out["means2d"].grad]


def stage_breakdown(scene, width: int, height: int, repeats: int) -> list[tuple[str, tuple[float, float]]]:
    """The ``"cpu"`` backend's stages timed one at a time on the same inputs: (stage, (wall, CPU) ms).

    Backward stages are timed with ``torch.autograd.grad(..., retain_graph=True)`` on a graph
    built once, the projection's with the compositor's own gradients; "glue" is the full
    forward+backward minus the stages (autograd engine, background and depth normalisation,
    Python)."""
    from recondreamer.splat.cpu_kernel import composite_cpu, project_cpu
    from recondreamer.splat.validation import validate_inputs

    means, quats, scales, opacities, colors, viewmat, K = scene
    params = [t.clone().requires_grad_() for t in (means, quats, scales, opacities, colors)]
    stages = [
        (
            "validate inputs",
            time_call(
                lambda: validate_inputs(means, quats, scales, opacities, colors, viewmat, K, width, height, None, "cpu"),
                repeats,
            ),
        )
    ]
    projected, rgb = project_cpu(params[0], params[1], params[2], params[4], viewmat, K, width, height)
    with torch.no_grad():
        stages.append(
            ("projection+SH fwd", time_call(lambda: project_cpu(means, quats, scales, colors, viewmat, K, width, height), repeats))
        )
    splats = [t.detach().requires_grad_() for t in (projected.means2d, projected.conics, rgb, projected.depths)]
    inputs = (splats[0], splats[1], splats[2], opacities.clone().requires_grad_(), splats[3])
    keep = projected.in_front
    with torch.no_grad():
        stages.append(("composite fwd", time_call(lambda: composite_cpu(*inputs, width, height, keep), repeats)))
    images = composite_cpu(*inputs, width, height, keep)
    image_grads = [torch.rand_like(image) for image in images]
    stages.append(
        ("composite bwd", time_call(lambda: torch.autograd.grad(images, inputs, image_grads, retain_graph=True), repeats))
    )
    splat_outputs = (projected.means2d, projected.conics, rgb, projected.depths)
    # The compositor's own gradients: zero for the splats that no pixel depends on, which the
    # projection's backward pass skips.
    composite_grads = torch.autograd.grad(images, inputs, image_grads, retain_graph=True)
    splat_grads = [composite_grads[i] for i in (0, 1, 2, 4)]
    projection_inputs = (params[0], params[1], params[2], params[4])
    stages.append(
        (
            "projection+SH bwd",
            time_call(
                lambda: torch.autograd.grad(splat_outputs, projection_inputs, splat_grads, retain_graph=True), repeats
            ),
        )
    )

    def forward_backward():
        out = rasterize(*params, viewmat, K, width, height, backend="cpu")
        (out["rgb"].sum() + out["depth"].mean() + out["alpha"].sum()).backward()

    total = time_call(forward_backward, repeats)
    stage_sum = [sum(timing[i] for _, timing in stages) for i in (0, 1)]
    stages.append(("glue (rest)", (total[0] - stage_sum[0], total[1] - stage_sum[1])))
    stages.append(("total fwd+bwd", total))
    return stages


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--width", type=int, default=240, help="image width in pixels")
    parser.add_argument("--height", type=int, default=160, help="image height in pixels")
    parser.add_argument("--counts", type=int, nargs="+", default=[20_000, 50_000, 100_000], help="Gaussian counts")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="torch intra-op thread counts")
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per cell (median reported)")
    parser.add_argument("--reference-repeats", type=int, default=2, help="timed calls for the slow reference")
    parser.add_argument("--skip-reference", action="store_true", help="time only the fast backends")
    parser.add_argument("--stages", action="store_true", help="also print the CPU kernel's per-stage breakdown")
    args = parser.parse_args()

    backends = [("cpu", "cpu", args.repeats)]
    if not args.skip_reference:
        backends.insert(0, ("torch", "cpu", args.reference_repeats))
    if torch.cuda.is_available():
        try:
            import gsplat  # noqa: F401

            backends.append(("gsplat", "cuda", args.repeats))
        except ImportError:
            pass

    print(f"# {args.width}x{args.height}, threads {' and '.join(map(str, args.threads))}, torch {torch.__version__}")
    print("# wall ms per call (median); in brackets process CPU ms per call; speed-ups from wall time")
    header = (
        f"{'N':>8} {'threads':>7} {'backend':>8} {'fwd ms':>18} {'fwd+bwd ms':>20} "
        f"{'speed-up fwd':>13} {'speed-up fwd+bwd':>17}"
    )
    print(header)
    identical = []  # per N: whether the CPU kernel's gradients are bit-identical at every thread count
    for count in args.counts:
        scene = random_scene(count, args.width, args.height)
        gradients = []
        for threads in args.threads:
            torch.set_num_threads(threads)
            results = {}
            for backend, device, repeats in backends:
                results[backend] = measure(backend, scene, args.width, args.height, repeats, device)
            for backend, _, _ in backends:
                (fwd, fwd_cpu), (fwd_bwd, fwd_bwd_cpu) = results[backend]
                if "torch" in results and backend != "torch":
                    (ref_fwd, _), (ref_fwd_bwd, _) = results["torch"]
                    ratios = f"{ref_fwd / fwd:>12.1f}x {ref_fwd_bwd / fwd_bwd:>16.1f}x"
                else:
                    ratios = f"{'':>13} {'':>17}"
                timings = f"{fwd:>9.1f} [{fwd_cpu:>7.1f}] {fwd_bwd:>10.1f} [{fwd_bwd_cpu:>7.1f}]"
                print(f"{count:>8} {threads:>7} {backend:>8} {timings} {ratios}", flush=True)
            gradients.append(cpu_gradients(scene, args.width, args.height))
        identical.append(all(torch.equal(a, b) for other in gradients[1:] for a, b in zip(gradients[0], other)))
    verdict = "bit-identical" if all(identical) else "NOT bit-identical"
    print(f"# CPU kernel gradients at threads {', '.join(map(str, args.threads))}: {verdict} at every N")
    if args.stages:
        print("\n# CPU kernel stages (wall ms [process CPU ms], medians of separately timed calls)")
        print(f"{'N':>8} {'threads':>7} {'stage':>20} {'ms':>18}")
        for count in args.counts:
            scene = random_scene(count, args.width, args.height)
            for threads in args.threads:
                torch.set_num_threads(threads)
                for stage, (wall, cpu) in stage_breakdown(scene, args.width, args.height, args.repeats):
                    print(f"{count:>8} {threads:>7} {stage:>20} {wall:>9.1f} [{cpu:>7.1f}]", flush=True)


if __name__ == "__main__":
    main()
