"""Build, cache and dispatch of the C++ CPU rasterizer."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from recondreamer.splat import cpu_kernel, rasterize


def small_scene():
    g = torch.Generator().manual_seed(0)
    means = torch.randn(50, 3, generator=g) + torch.tensor([0.0, 0.0, 5.0])
    quats = torch.randn(50, 4, generator=g)
    scales = torch.rand(50, 3, generator=g) * 0.3 + 0.02
    opacities = torch.rand(50, generator=g)
    colors = torch.rand(50, 3, generator=g)
    K = torch.tensor([[30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]])
    return means, quats, scales, opacities, colors, torch.eye(4), K


def test_auto_backend_is_the_cpu_kernel_for_cpu_tensors():
    scene = small_scene()
    auto = rasterize(*scene, 32, 24, backend="auto")
    cpu = rasterize(*scene, 32, 24, backend="cpu")
    for name in ("rgb", "depth", "alpha", "means2d", "radii", "visible"):
        assert torch.equal(auto[name], cpu[name]), name


def test_gsplat_backend_rejects_cpu_tensors():
    with pytest.raises(ValueError, match="CUDA"):
        rasterize(*small_scene(), 32, 24, backend="gsplat")


def test_missing_compiler_gives_a_clear_error(monkeypatch):
    monkeypatch.setattr(cpu_kernel, "_extension", None)
    monkeypatch.setenv("CXX", "no-such-compiler-for-recondreamer")
    with pytest.raises(cpu_kernel.KernelBuildError, match="C\\+\\+ compiler"):
        cpu_kernel.load_extension()


def test_cache_name_follows_source_and_flags(tmp_path, monkeypatch):
    flags = cpu_kernel.compiler_flags()
    name = cpu_kernel.extension_name(flags)
    assert name != cpu_kernel.extension_name(flags + ("-DEXTRA",))
    edited = tmp_path / "rasterize_cpu.cpp"
    edited.write_text(cpu_kernel.SOURCES[0].read_text() + "\n// edited\n")
    monkeypatch.setattr(cpu_kernel, "SOURCES", (edited,))
    assert cpu_kernel.extension_name(flags) != name


def test_cache_name_differs_between_checkouts(tmp_path, monkeypatch):
    """The same sources in another folder (a second checkout) build into their own cache folder."""
    flags = cpu_kernel.compiler_flags()
    name = cpu_kernel.extension_name(flags)
    copies = []
    for path in cpu_kernel.SOURCES + cpu_kernel.HEADERS:
        copy = tmp_path / path.name
        copy.write_bytes(path.read_bytes())
        copies.append(copy)
    monkeypatch.setattr(cpu_kernel, "SOURCES", tuple(copies[: len(cpu_kernel.SOURCES)]))
    monkeypatch.setattr(cpu_kernel, "HEADERS", tuple(copies[len(cpu_kernel.SOURCES) :]))
    assert cpu_kernel.extension_name(flags) != name


def test_built_extension_is_reused_by_a_new_process():
    cpu_kernel.load_extension()
    build_dir = cpu_kernel.cache_root() / cpu_kernel.extension_name(cpu_kernel.compiler_flags())
    libraries = sorted(build_dir.glob("*.so"))
    assert libraries, f"no built library in {build_dir}"
    stamps = [path.stat().st_mtime_ns for path in libraries]
    code = "from recondreamer.splat.cpu_kernel import load_extension; load_extension()"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)
    assert [path.stat().st_mtime_ns for path in libraries] == stamps  # loaded, not rebuilt
