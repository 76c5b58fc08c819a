"""Sample arguments for every registered ``gvnn_warp::*`` op (flattened, as the ops take them),
and :data:`OPS`, the registry, with every registration module of ``gvnn_warp.ops`` loaded.

One entry per op: ``tests/ops/test_registry.py`` fails, with a list, for an op that has none.
Used by the opcheck tests (tiny sizes) and by ``tests/ops/test_scopes.py`` (sizes large enough to cut
every launch into many pieces).
"""

import torch
from gvnn_warp.kernels.geometry import lens
from gvnn_warp.kernels.photometric.residual import KINDS as PHOTOMETRIC_CODES
from gvnn_warp.kernels.robust import KINDS as ROBUST_CODES
from refs import intrinsics

import gvnn_warp as G
from gvnn_warp.ops import geometry, perpixel, photometric, reprojection, sampling  # noqa: F401  (their registrations fill OPS)
from gvnn_warp.ops.registry import OPS  # noqa: F401  (every registered op, for the tests)


def op_samples(B=2, C=2, H=5, W=6, seed=0):
    """name -> args, float64, for batch B, C channels, H x W images."""
    g = torch.Generator().manual_seed(seed)
    f64 = torch.float64

    def r(*s):  # uniform in [0, 1)
        return torch.rand(*s, generator=g, dtype=f64)

    def u(*s, scale=1.0):  # uniform in [-scale, scale)
        return (r(*s) * 2 - 1) * scale

    n = B * 3  # batch of small ops
    P = 4  # points per batch item
    K = intrinsics(W, H).expand(B, 3, 3).contiguous()
    pose = G.se3_to_matrix(r(B, 6) * 0.1).contiguous()
    img = r(B, C, H, W)
    hw = H * W
    # radial-tangential (TUM freiburg1's coefficients) for batch item 0, fisheye-sized for item 1
    tum = [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]
    dist = torch.stack([torch.as_tensor(lens.pack_dist(lens.RADTAN, [c / (1 + b) for c in tum])) for b in range(B)])
    fish = [0.02, -0.005, 0.001, -0.0002]
    fdist = torch.stack([torch.as_tensor(lens.pack_dist(lens.FISHEYE, [c * (1 + b) for c in fish])) for b in range(B)])
    cam_px = torch.stack([r(B * P) * (W - 1), r(B * P) * (H - 1)], dim=-1)
    # distorted cameras (TUM freiburg1's radtan coefficients; a fisheye), packed as the kernels take them
    radtan = torch.from_numpy(lens.pack_dist(lens.RADTAN, [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]))
    fisheye = torch.from_numpy(lens.pack_dist(lens.FISHEYE, [0.08, -0.02, 0.004, -0.001]))
    radtan, fisheye = (d.expand(B, 8).contiguous() for d in (radtan, fisheye))
    rays = sampling.pixel_rays(K[:1].contiguous(), radtan[:1].contiguous(), H, W, lens.RADTAN)  # shared by the batch
    return {
        # gvnn_warp.ops.geometry
        "so3_exp": (r(n, 3),),
        "so3_log": (G.so3_exp(r(n, 3)),),
        "quaternion_to_matrix": (r(n, 4),),
        "euler_to_matrix": (r(n, 3), 2, 1, 0),
        "se3_to_matrix": (r(n, 3), r(n, 3)),
        "sim3_to_matrix": (r(n, 3), r(n, 3), r(n)),
        "se3_exp": (r(n, 3), r(n, 3)),
        "se3_log": (G.se3_exp(r(n, 6)).contiguous(),),
        "depth_to_points": (r(B * hw) + 1, K, H, W),
        "transform_points": (pose, r(B * P, 3), P),
        "project_points": (r(B * P, 3) + 1, K, P, 1e-3),
        "project_points_camera": (u(B * P, 3, scale=0.3) + torch.tensor([0, 0, 1.5], dtype=f64), K, dist, P,
                                  1e-3, lens.RADTAN),
        "depth_to_points_camera": (r(B * hw) + 1, K, fdist, H, W, lens.FISHEYE),
        "unproject_points": (cam_px, r(B * P) + 1, K, dist, P, lens.RADTAN),
        "distort_points": (cam_px, K, fdist, P, lens.FISHEYE),
        "undistort_points": (cam_px, K, dist, P, lens.RADTAN),
        # gvnn_warp.ops.sampling
        "bilinear_sample": (img, r(B * 12, 2) * 2 - 1, C, H, W, 12, 0, 0),
        "bilinear_sample_lanes": (img, r(B * 16, 2) * 2 - 1, C, H, W, 16, 1, 1),
        "warp_frame_depth": (img, r(B, 1, H, W) + 1, pose, K, C, H, W, 1e-3, 0),
        "warp_frame_depth_lanes": (r(B, C, H, 16), r(B, 1, H, 16) + 1, pose,  # (rows of two 8-pixel blocks)
                                   intrinsics(16, H).expand(B, 3, 3).contiguous(), C, H, 16, 1e-3, 1),
        "pixel_rays": (K, fisheye, H, W, lens.FISHEYE),
        "warp_frame_depth_lens": (img, r(B, 1, H, W) + 1, pose, K, radtan, rays, C, H, W, 1e-3, 0, lens.RADTAN, 0),
        # gvnn_warp.ops.perpixel
        "flow_warp": (img, u(B, 2, H, W, scale=2), C, H, W, 0),
        "disparity_warp": (img, u(B, 1, H, W, scale=2), C, H, W, 1),
        "affine_flow_warp": (img, u(B, 6, H, W), C, H, W, 0),
        "affine_flow": (u(B, 6, H, W), H, W),
        "se2_flow": (u(B, 3, H, W), H, W),
        "homography_flow": (u(B, 9, H, W) * 0.1 + torch.eye(3, dtype=f64).reshape(1, 9, 1, 1), H, W),
        "plane_disparity": (u(B, 3, H, W), H, W),
        "pointwise_se3": (u(B, H, W, 3), u(B, 6, H, W), hw),
        "pointwise_sim3": (u(B, H, W, 3), u(B, 7, H, W), hw),
        "pointwise_transform10": (u(B, H, W, 3), u(B, 10, H, W), hw),
        "affine_grid": (u(B, 2, 3), H, W, 0),
        "robust_rho": (u(n, scale=3), ROBUST_CODES["cauchy"], 0.5),
        "robust_psi": (u(n, scale=3), ROBUST_CODES["tukey"], 2.0),
        "smoothness": (u(B, 3, H, W), H, W, ROBUST_CODES["huber"], 0.3, 0.01, 0.02),
        # gvnn_warp.ops.photometric (reference and live images, depth, pose, K; penalty cauchy)
        "photometric_rows": (img, r(B, 1, H, W) + 1, r(B, C, H, W), pose, K, C, H, W,
                             PHOTOMETRIC_CODES["cauchy"], 0.5, 1e-3),
        "photometric_rows_lens": (img, r(B, 1, H, W) + 1, r(B, C, H, W), pose, K, radtan, rays, C, H, W,
                                  PHOTOMETRIC_CODES["huber"], 0.5, 1e-3, lens.RADTAN, 0),
        "photometric_mean": (r(B * H), torch.randint(0, W + 1, (B * H,), generator=g).to(f64), H, C),
        # (every gradient computed in the forward pass: needs = 31)
        "photometric_error": (img, r(B, 1, H, W) + 1, r(B, C, H, W), pose, K, PHOTOMETRIC_CODES["cauchy"], 0.5,
                              1e-3, 31),
        # gvnn_warp.ops.geometry: a lens camera's domain bound (TUM freiburg1's radtan, and one scaled down)
        "lens_domain_limit": (torch.tensor([tum, [c / 2 for c in tum]], dtype=f64), lens.RADTAN),
        "photometric_normal_equations": (img, r(B, 1, H, W) + 1, r(B, C, H, W), r(B, 1, H, W) + 1, pose, K,
                                         PHOTOMETRIC_CODES["tukey"], 0.4, 1e-3, 2.0),
        "photometric_normal_equations_lens": (img, r(B, 1, H, W) + 1, r(B, C, H, W), r(B, 1, H, W) + 1, pose, K,
                                              radtan, rays, PHOTOMETRIC_CODES["huber"], 0.4, 1e-3, 2.0, lens.RADTAN,
                                              0),
        # gvnn_warp.ops.reprojection (S = 2 sources; choice: -1 excluded, s reprojection, S + s identity)
        "reprojection_choice": (img, r(B, 2, C, H, W), r(B, 2, C, H, W), (r(B, 2, H, W) > 0.2).to(f64),
                                r(B, H, W) + 1 - 1.2 * (r(B, H, W) > 0.9), G.se3_to_matrix(r(2 * B, 6) * 0.1),
                                K.repeat_interleave(2, 0), 2, C, H, W, 0.85, 1, 1e-3, 0),
        "reprojection_error": (img, r(B, 2, C, H, W), r(B, 2, C, H, W),
                               torch.randint(-1, 4, (B, H, W), generator=g).to(torch.int32), r(B, H, W), 2, C, H, W,
                               0.85),
        "reprojection_error_copy": (img, r(B, 2, C, H, W), r(B, 2, C, H, W),
                                    torch.randint(-1, 4, (B, H, W), generator=g).to(torch.int32), r(B, H, W), 2, C,
                                    H, W, 0.85),
        "per_item_mean": (r(B, hw), (r(B, hw) > 0.3).to(f64), hw),
        "disparity_mean": (r(B, 1, H, W) + 0.1, hw),
        "smoothness_rows": (r(B, 1, H, W), img, r(B) + 0.5, C, H, W),
        "rows_total": (r(B, H), H),
    }
