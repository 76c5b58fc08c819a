"""The reprojection objective on ``wp.array`` s, with no torch: the same kernels as
``gvnn_warp.reprojection_loss`` (definitions: the package docstring), recordable on a ``wp.Tape``::

    tape = wp.Tape()
    with tape:
        loss = reprojection_loss(target, sources, depth, poses, K)     # (B,)
    tape.backward(grads={loss: wp.ones(B, dtype=wp.float32)})      # depth.grad, poses.grad, ...

Shapes: target (B, C, H, W), sources (B * S, C, H, W) (item b's S frames consecutive: Warp arrays
have at most four dimensions), depth (B, 1, H, W), poses (B, S) of 3x4
matrices (target-camera points -> source s's camera), K (B,) of 3x3 intrinsics; float32 or float64.
A lens model: ``model`` and ``dist`` (B,) as in :func:`..sampling.pipeline.warp_frame_depth`.
The choice of each pixel's candidate is not recorded (it has no gradient); its result is kept on
the tape's arrays.
"""

from __future__ import annotations

import warp as wp

from ..core import compat
from ..core.launch import wp_launch
from ..geometry import lens
from ..geometry.camera import MIN_DEPTH
from ..sampling import pipeline as sampling_pipeline
from . import kernels as rk

__all__ = ["reprojection_loss"]


def _expect(name: str, cond: bool, what: str, got, exc: type[Exception] = ValueError) -> None:
    sampling_pipeline._expect("reprojection_loss", name, cond, what, got, exc)


def _repeat(kernel, src: wp.array, n: int, S: int) -> wp.array:
    out = wp.zeros(src.shape[0] * S, dtype=src.dtype, device=src.device, requires_grad=src.requires_grad)
    wp_launch(kernel[compat.scalar_type(src.dtype)], dim=out.shape[0], inputs=[0, src, n, S], outputs=[out],
              device=src.device)
    return out


def reprojection_loss(target: wp.array, sources: wp.array, depth: wp.array, poses: wp.array, K: wp.array, *,
                      dist: wp.array | None = None, model="pinhole", alpha: float = 0.85, automask: bool = True,
                      min_depth: float = MIN_DEPTH, return_maps: bool = False):
    """Monodepth2's reprojection loss (B,) (with ``return_maps``, also the per-pixel error (B, 1, H,
    W) and ``choice`` (B, 1, H, W) int32: s for source s's reprojection, S + s for its identity,
    -1 where excluded). Gradients reach target, sources, depth, poses, K (and dist) on a tape."""
    fn = "reprojection_loss"
    sampling_pipeline._expect_arrays(fn, target=target, sources=sources, depth=depth, poses=poses, K=K)
    _expect("target", target.ndim == 4, "a 4-D (B, C, H, W) array", target.shape)
    B, C, H, W = target.shape
    _expect("poses", poses.ndim == 2 and poses.shape[0] == B, f"a ({B}, S) array of 3x4 matrices", poses.shape)
    S = poses.shape[1]
    _expect("sources", S >= 1, "at least one source frame per item (poses of shape (B, S), S >= 1)", S)
    _expect("sources", tuple(sources.shape) == (B * S, C, H, W), f"of shape {(B * S, C, H, W)}", sources.shape)
    _expect("target", tuple(target.shape) == (B, C, H, W), f"of shape {(B, C, H, W)}", target.shape)
    _expect("depth", tuple(depth.shape) == (B, 1, H, W), f"of shape {(B, 1, H, W)}", depth.shape)
    _expect("poses", tuple(poses.shape) == (B, S), f"a {(B, S)} array of 3x4 matrices", poses.shape)
    _expect("K", tuple(K.shape) == (B,), f"a ({B},) array of 3x3 matrices", K.shape)
    _expect("alpha", 0.0 <= alpha <= 1.0, "in [0, 1]", alpha)
    _expect("target", H >= 2 and W >= 2, "at least 2x2", (H, W))
    sampling_pipeline._expect_float(fn, "target", target)
    ft, dev = target.dtype, target.device
    for name, a in (("sources", sources), ("depth", depth)):  # (one float type: the target's)
        _expect(name, a.dtype == ft, f"of dtype {ft.__name__} like 'target'",
                sampling_pipeline._type_name(a.dtype), TypeError)
    sampling_pipeline._expect_matrices(fn, "poses", poses, (3, 4), ft)
    sampling_pipeline._expect_matrices(fn, "K", K, (3, 3), ft)
    _expect("min_depth", 0 < min_depth < float("inf"), "a positive finite number", repr(min_depth))
    if sampling_pipeline._lens_model(fn, model) != lens.PINHOLE:  # (checked here: the warps see (B S,) repeats)
        sampling_pipeline._expect_dist(fn, dist, B, ft)
    hw = H * W
    depth_s = _repeat(rk.repeat_scalar, depth.flatten(), hw, S).reshape((B * S, 1, H, W))
    K_s = _repeat(rk.repeat_mat33, K, 1, S)
    dist_s = None if dist is None else _repeat(rk.repeat_vec8, dist, 1, S)
    warped, _ = sampling_pipeline.warp_frame_depth(sources, depth_s, poses.flatten(), K_s, dist=dist_s,
                                                   model=model, padding_mode="border", min_depth=min_depth)
    pinhole = model in ("pinhole", lens.PINHOLE)  # (warp_frame_depth above has checked the name)
    if pinhole:  # the choice kernel tests the moved points' z itself
        front = wp.zeros(0, dtype=ft, device=dev)
    else:  # through a lens: the warp of a constant 1 (on copies without gradients: not recorded)
        ones = wp.full((B * S, 1, H, W), ft(1.0), dtype=ft, device=dev)
        plain = [wp.clone(a, requires_grad=False) for a in (depth_s, poses.flatten(), K_s, dist_s)]
        front, _ = sampling_pipeline.warp_frame_depth(ones, plain[0], plain[1], plain[2], dist=plain[3],
                                                      model=model, padding_mode="border", min_depth=min_depth)
        front = front.flatten()
    choice = wp.zeros(B * hw, dtype=wp.int32, device=dev)
    best = wp.zeros(B * hw, dtype=ft, device=dev)
    scratch = wp.zeros(B * hw, dtype=ft, device=dev)
    shape = [S, C, H, W, float(alpha)]
    wp_launch(rk.reprojection_choice[ft], dim=B * H,
              inputs=[0, target.flatten(), warped.flatten(), sources.flatten(), front, depth.flatten(),
                      poses.flatten(), K_s, *shape, int(automask), float(min_depth), int(not pinhole)],
              outputs=[choice, best, scratch], device=dev, record_tape=False)  # (forward only: no adjoint)
    needs = target.requires_grad or warped.requires_grad or sources.requires_grad
    pe = wp.zeros(B * hw, dtype=ft, device=dev, requires_grad=needs)
    weight = wp.zeros(B * hw, dtype=ft, device=dev)
    wp_launch(rk.reprojection_error[ft], dim=B * hw,
              inputs=[0, target.flatten(), warped.flatten(), sources.flatten(), choice, best, *shape],
              outputs=[pe, weight], device=dev)
    loss = wp.zeros(B, dtype=ft, device=dev, requires_grad=needs)
    count = wp.zeros(B, dtype=ft, device=dev)
    wp_launch(rk.per_item_mean[ft], dim=B, inputs=[0, pe, weight, hw], outputs=[loss, count], device=dev)
    if return_maps:
        return loss, pe.reshape((B, 1, H, W)), choice.reshape((B, 1, H, W))
    return loss
