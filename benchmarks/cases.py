"""The timed cases of :mod:`benchmarks.run`: ours and the torch / kornia code users would run instead,
each a :class:`~benchmarks.common.Case` (a call, and a set-up that clears the gradients)."""

from __future__ import annotations

import kornia
import torch
import torch.nn.functional as F

import gvnn_warp as G
from benchmarks.common import Case, affine_grid, clear_grads, leaves, projected_grid, random_grid, wfd_scene

__all__ = ["bilinear_cases", "lens_cases", "so3_cases", "wfd_cases"]


def wfd_cases(B, C, H, W, forward_only=False, peers=("grid_sample", "kornia"), image_grad=True) -> list[Case]:
    """Ours, grid_sample (image + grid grads) and kornia's warp_frame_depth, forward+backward.
    ``image_grad=False``: the image is data (no gradient for it, nor for grid_sample's image)."""
    image, depth, pose, pose44, K = wfd_scene(B, C, H, W)
    grid = affine_grid(B, H, W)
    if image_grad:
        ours = leaves(image, depth, pose)
        kor = leaves(image, depth, pose44)
        gs = leaves(image, grid)
    else:
        ours = [image, *leaves(depth, pose)]
        kor = [image, *leaves(depth, pose44)]
        gs = [image, *leaves(grid)]
    cases = []
    if forward_only:
        def ours_f():
            with torch.no_grad():
                G.warp_frame_depth(image, depth, pose, K)

        def kornia_f():
            with torch.no_grad():
                kornia.geometry.depth.warp_frame_depth(image, depth, pose44, K)

        def gs_f():
            with torch.no_grad():
                F.grid_sample(image, grid, align_corners=True)

        cases.append(Case("ours", ours_f))
        if "grid_sample" in peers:
            cases.append(Case("grid_sample", gs_f))
        if "kornia" in peers:
            cases.append(Case("kornia", kornia_f))
        return cases

    cases.append(Case("ours", lambda: G.warp_frame_depth(*ours, K)[0].sum().backward(), clear_grads(ours)))
    if "grid_sample" in peers:
        cases.append(
            Case("grid_sample", lambda: F.grid_sample(*gs, align_corners=True).sum().backward(), clear_grads(gs))
        )
    if "grid_sample_projected" in peers:  # the sampling step alone, at our own sample positions
        projected = projected_grid(depth, pose, K)
        same = leaves(image, projected) if image_grad else [image, *leaves(projected)]
        cases.append(Case("grid_sample_projected", lambda: F.grid_sample(*same, align_corners=True).sum().backward(),
                          clear_grads(same)))
    if "kornia" in peers:
        cases.append(
            Case(
                "kornia",
                lambda: kornia.geometry.depth.warp_frame_depth(*kor, K).sum().backward(),
                clear_grads(kor),
            )
        )
    return cases


def lens_cases(B, C, H, W) -> list[Case]:
    """warp_frame_depth fwd+bwd (grads: image, depth, pose) with the pinhole K, a radtan and a fisheye
    camera shared by the batch (their rays cached, as for any fixed camera), and a radtan camera
    whose rays are recomputed in every call (a camera that changes every call: its own cache entry
    is dropped before each call, untimed, and the other cameras' entries are left alone)."""
    # the torch front loads on first use (as G.* does): `python -m benchmarks.run --help` and the
    # report's tests (tests/project/test_benchmark_report.py) import this module without waiting for it
    from gvnn_warp.cameras import FisheyeCamera, RadTanCamera
    from gvnn_warp.cameras import fused as Fn

    image, depth, pose, _, K = wfd_scene(B, C, H, W)
    K0 = K[0].clone()
    coeffs = torch.tensor([0.2624, -0.9531, -0.0054, 0.0026, 1.1633])
    radtan = RadTanCamera(K0, coeffs)
    fisheye = FisheyeCamera(K0, torch.tensor([0.08, -0.02, 0.004, -0.001]))
    changing = RadTanCamera(K0 + torch.tensor([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), coeffs)
    ours = leaves(image, depth, pose)
    clear = clear_grads(ours)

    def run(camera):
        G.warp_frame_depth(*ours, camera)[0].sum().backward()

    changing_key = changing.K.contiguous().numpy().tobytes()  # its entries' K bytes (functional._rays)

    runs = []  # whether the changing camera has been run (its entry must then be found)

    def forget_changing():
        clear()
        keys = [k for k in Fn.RAYS_CACHE if k[4] == changing_key]
        if runs and len(keys) != 1:
            raise RuntimeError(f"lens_cases: {len(keys)} rays cache entries of the changing camera, expected 1")
        for key in keys:
            del Fn.RAYS_CACHE[key]

    def run_changing():
        runs.append(True)
        run(changing)

    return [
        Case("pinhole", lambda: run(K0), clear),
        Case("radtan", lambda: run(radtan), clear),
        Case("fisheye", lambda: run(fisheye), clear),
        Case("radtan_rays_each_call", run_changing, forget_changing),
    ]


def bilinear_cases(B, C, H, W, grid_kind="affine") -> list[Case]:
    g = torch.Generator().manual_seed(3)
    image = torch.rand(B, C, H, W, generator=g)
    grid = affine_grid(B, H, W) if grid_kind == "affine" else random_grid(B, H, W)
    ours = leaves(image, grid)
    theirs = leaves(image, grid)

    def ours_f():
        with torch.no_grad():
            G.bilinear_sample(image, grid)

    def gs_f():
        with torch.no_grad():
            F.grid_sample(image, grid, align_corners=False)

    return [
        Case("ours", lambda: G.bilinear_sample(*ours).sum().backward(), clear_grads(ours)),
        Case("grid_sample", lambda: F.grid_sample(*theirs, align_corners=False).sum().backward(), clear_grads(theirs)),
        Case("ours_forward", ours_f),
        Case("grid_sample_forward", gs_f),
    ]


def so3_cases(n) -> list[Case]:
    omega = torch.randn(n, 3, generator=torch.Generator().manual_seed(4))
    ours = leaves(omega)
    theirs = leaves(omega)
    return [
        Case("ours", lambda: G.so3_exp(*ours).sum().backward(), clear_grads(ours)),
        Case(
            "kornia",
            lambda: kornia.geometry.conversions.axis_angle_to_rotation_matrix(*theirs).sum().backward(),
            clear_grads(theirs),
        ),
    ]
