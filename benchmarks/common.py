"""Shared pieces of the benchmarks: scenes, interleaved timing, machine description."""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
import warp

import gvnn_warp as G


@dataclass
class Case:
    """One timed callable: ``setup()`` runs untimed before every call of ``run()``."""

    name: str
    run: Callable[[], object]
    setup: Callable[[], object] = lambda: None
    times: list[float] = field(default_factory=list)

    @property
    def median_ms(self) -> float:
        return 1e3 * statistics.median(self.times)


def interleaved(cases: list[Case], repeats: int, warmup: int = 1) -> dict[str, float]:
    """Median wall-clock milliseconds of each case, measured round-robin (the order rotates every
    round) so that all cases see the same machine load. Returns {name: median ms}."""
    for c in cases:
        for _ in range(warmup):
            c.setup()
            c.run()
        c.times.clear()
    for r in range(repeats):
        for k in range(len(cases)):
            c = cases[(k + r) % len(cases)]
            c.setup()
            t0 = time.perf_counter()
            c.run()
            c.times.append(time.perf_counter() - t0)
    return {c.name: c.median_ms for c in cases}


def machine() -> dict:
    """nproc, CPU model, versions."""
    model = platform.processor() or "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        import kornia  # the peer of most benchmarks, but optional here: the machine is described without it

        kornia_version = kornia.__version__
    except ImportError:  # pragma: no cover
        kornia_version = None
    return {
        "nproc": os.cpu_count(),
        "cpu": model,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "warp": warp.__version__,
        "kornia": kornia_version,
        "platform": platform.platform(),
        "load_average": os.getloadavg() if hasattr(os, "getloadavg") else None,
    }


# ----------------------------------------------------------------------------- scenes


def intrinsics(H: int, W: int, dtype=torch.float32) -> torch.Tensor:
    f = 0.8 * W
    return torch.tensor([[f, 0.0, (W - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]], dtype=dtype)


def wfd_scene(B: int, C: int, H: int, W: int, dtype=torch.float32, seed: int = 0):
    """An image, a smooth depth map (a slanted, bumpy surface 1.5-2.5 m away), small random
    camera motions (rotations ~1.7 deg, translations ~3 cm) and shared intrinsics:
    (image, depth, pose (B, 3, 4), pose44 (B, 4, 4), K (B, 3, 3))."""
    g = torch.Generator().manual_seed(seed)
    image = torch.rand(B, C, H, W, generator=g, dtype=dtype)
    yy, xx = torch.meshgrid(
        torch.linspace(-1, 1, H, dtype=dtype), torch.linspace(-1, 1, W, dtype=dtype), indexing="ij"
    )
    base = 2.0 + 0.4 * xx + 0.2 * torch.sin(3 * yy) + 0.1 * torch.cos(5 * xx * yy)
    depth = (base + 0.05 * torch.rand(B, 1, H, W, generator=g, dtype=dtype)).contiguous()
    xi = torch.randn(B, 6, generator=g, dtype=dtype) * 0.03
    pose = G.se3_to_matrix(xi).detach()
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=dtype).expand(B, 1, 4)
    pose44 = torch.cat([pose, bottom], dim=1).contiguous()
    K = intrinsics(H, W, dtype).expand(B, 3, 3).contiguous()
    return image, depth, pose, pose44, K


def affine_grid(B: int, H: int, W: int, dtype=torch.float32, seed: int = 1) -> torch.Tensor:
    """A spatial-transformer grid: identity plus a small random affine (B, H, W, 2)."""
    g = torch.Generator().manual_seed(seed)
    theta = torch.eye(2, 3, dtype=dtype).expand(B, 2, 3) + 0.05 * torch.randn(B, 2, 3, generator=g, dtype=dtype)
    return torch.nn.functional.affine_grid(theta, (B, 1, H, W), align_corners=False).contiguous()


def projected_grid(depth: torch.Tensor, pose: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """The sample positions of ``warp_frame_depth(image, depth, pose, K)`` as a ``grid_sample`` grid
    (align_corners=True), computed in plain torch: every pixel unprojected with its depth, moved by
    the pose (B, 3, 4), projected by K (B, 3, 3). For comparing the sampling step alone at the
    same positions (the same memory access pattern)."""
    B, _, H, W = depth.shape
    with torch.no_grad():
        ys, xs = torch.meshgrid(torch.arange(H, dtype=depth.dtype), torch.arange(W, dtype=depth.dtype), indexing="ij")
        pixels = torch.stack([xs, ys, torch.ones_like(xs)]).reshape(1, 3, H * W)
        points = (torch.linalg.inv(K) @ pixels) * depth.reshape(B, 1, H * W)
        q = K @ (pose[:, :, :3] @ points + pose[:, :, 3:])
        u, v = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
        return torch.stack([2 * u / (W - 1) - 1, 2 * v / (H - 1) - 1], -1).reshape(B, H, W, 2).contiguous()


def random_grid(B: int, H: int, W: int, dtype=torch.float32, seed: int = 2) -> torch.Tensor:
    """Uniformly random sample positions in [-1.1, 1.1]^2: every sample a cache miss (worst case)."""
    g = torch.Generator().manual_seed(seed)
    return torch.rand(B, H, W, 2, generator=g, dtype=dtype) * 2.2 - 1.1


def leaves(*tensors: torch.Tensor) -> list[torch.Tensor]:
    return [t.detach().clone().requires_grad_() for t in tensors]


def clear_grads(ts) -> Callable[[], None]:
    def setup():
        for t in ts:
            t.grad = None

    return setup
