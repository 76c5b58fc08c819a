"""Bad input gets a ValueError / TypeError naming the function, the argument and what was expected."""

import pytest
import torch

import gvnn_warp as G

f64 = torch.float64
IMG = torch.rand(2, 3, 6, 8, dtype=f64)
DEPTH = torch.rand(2, 1, 6, 8, dtype=f64) + 1
POSE = torch.eye(3, 4, dtype=f64).expand(2, 3, 4)
K = torch.tensor([[8.0, 0, 3.5], [0, 8, 2.5], [0, 0, 1]], dtype=f64)

CASES = [
    # (call, exception, regex the message must match)
    (lambda: G.so3_exp(torch.zeros(4, 2)), ValueError, r"so3_exp: argument 'omega' must have shape \(\.\.\., 3\)"),
    (lambda: G.so3_exp(torch.zeros(4, 3, dtype=torch.int64)), TypeError, r"so3_exp: argument 'omega' must be float"),
    (lambda: G.so3_exp([0.0, 0.0, 0.0]), TypeError, r"so3_exp: argument 'omega' must be a torch.Tensor"),
    (lambda: G.so3_log(torch.zeros(3, 4)), ValueError, r"so3_log: argument 'R'"),
    (lambda: G.quaternion_to_matrix(torch.zeros(3)), ValueError, r"quaternion_to_matrix: argument 'q'"),
    (lambda: G.euler_to_matrix(torch.zeros(3), "XXY"), ValueError, r"euler_to_matrix: argument 'convention' must be one of"),
    (lambda: G.euler_to_matrix(torch.zeros(3), "xyz"), ValueError, r"'convention'.*'XYZ'"),
    (lambda: G.se3_to_matrix(torch.zeros(2, 7)), ValueError, r"se3_to_matrix: argument 'xi'"),
    (lambda: G.sim3_to_matrix(torch.zeros(2, 6)), ValueError, r"sim3_to_matrix: argument 'xi'"),
    (lambda: G.se3_log(torch.zeros(2, 3, 3)), ValueError, r"se3_log: argument 'T' must have shape \(\.\.\., 3\|4, 4\)"),
    (lambda: G.depth_to_points(DEPTH[:, 0], K), ValueError, r"depth_to_points: argument 'depth' must have shape \(B, 1, H, W\)"),
    (lambda: G.depth_to_points(DEPTH, K.expand(3, 3, 3)), ValueError, r"argument 'K' has B=3 .* 'depth' has B=2"),
    (lambda: G.depth_to_points(DEPTH, K.float()), TypeError, r"'K' has dtype torch.float32 but 'depth' has torch.float64"),
    (lambda: G.transform_points(POSE, torch.zeros(3, 5, 3, dtype=f64)), ValueError, r"transform_points: argument 'points' has B=3"),
    (lambda: G.project_points(torch.zeros(2, 5, 3, dtype=f64), K, min_depth=0.0), ValueError, r"project_points: argument 'min_depth' must be a positive"),
    (lambda: G.bilinear_sample(IMG, torch.zeros(2, 4, 4, 3, dtype=f64)), ValueError, r"bilinear_sample: argument 'grid'"),
    (lambda: G.bilinear_sample(IMG, torch.zeros(2, 4, 4, 2, dtype=f64), padding_mode="reflection"), ValueError, r"'padding_mode' must be one of \['zeros', 'border'\], got 'reflection'"),
    (lambda: G.warp_frame_depth(IMG, DEPTH.expand(2, 3, 6, 8), POSE, K), ValueError, r"warp_frame_depth: argument 'depth' must have shape \(B, 1, H, W\)"),
    (lambda: G.warp_frame_depth(IMG, DEPTH[:, :, :5], POSE, K), ValueError, r"argument 'depth' has H=5 .* 'image' has H=6"),
    (lambda: G.warp_frame_depth(IMG, DEPTH[:1], POSE, K), ValueError, r"argument 'depth' has B=1 .* 'image' has B=2"),
    # a channel-last image (as image libraries load them): the error says so, whichever argument it is about
    (lambda: G.warp_frame_depth(IMG.permute(0, 2, 3, 1), DEPTH, POSE, K), ValueError,
     r"argument 'depth' has H=6 .* 'image' has H=8 \(argument 'image' has shape \(2, 6, 8, 3\), which looks "
     r"channel-last \(B, H, W, C\): images are \(B, C, H, W\); use .permute\(0, 3, 1, 2\)\)$"),
    (lambda: G.reprojection_loss(IMG.permute(0, 2, 3, 1), IMG[:, None], DEPTH, POSE[:, None], K), ValueError,
     r"reprojection_loss: .*'target' has shape \(2, 6, 8, 3\), which looks channel-last"),
    (lambda: G.warp_frame_depth(IMG, DEPTH, POSE[:, :2], K), ValueError, r"warp_frame_depth: argument 'pose' must have shape \(B, 3\|4, 4\)"),
    (lambda: G.warp_frame_depth(IMG, DEPTH, POSE, K[:2]), ValueError, r"warp_frame_depth: argument 'K' must have shape \(3, 3\), got \(2, 3\)"),
    (lambda: G.warp_frame_depth(IMG, DEPTH, POSE, K[None, None]), ValueError, r"'K' must have shape \(3, 3\) or \(B, 3, 3\), got \(1, 1, 3, 3\)"),
    (lambda: G.warp_frame_depth(IMG.float(), DEPTH, POSE, K), TypeError, r"'depth' has dtype torch.float64 but 'image' has torch.float32"),
    (lambda: G.warp_frame_depth(IMG.half(), DEPTH.half(), POSE.half(), K.half()), TypeError, r"'image' must be float32 or float64, got torch.float16"),
    (lambda: G.warp_frame_depth(IMG, DEPTH, POSE, K, min_depth=-1), ValueError, r"'min_depth' must be a positive"),
    (lambda: G.warp_frame_depth(IMG, DEPTH, POSE, K, padding_mode="bogus"), ValueError, r"warp_frame_depth: argument 'padding_mode'"),
    (lambda: G.so3_exp(torch.zeros(1, 3).expand(2**31 // 3 + 1, 3)), ValueError, r"so3_exp: argument 'omega' has \d+ elements; kernels index with int32"),
    (lambda: G.bilinear_sample(IMG[:, :, :0], torch.zeros(2, 4, 4, 2, dtype=f64)), ValueError, r"bilinear_sample: argument 'image' has no pixels to sample from \(shape \(2, 3, 0, 8\)\)"),
    # small inputs, an output of 2**31 elements (1 x 1024 channels x 2048 x 1024): refused before allocating
    (lambda: G.bilinear_sample(torch.zeros(1, 1024, 2, 2), torch.zeros(1, 2048, 1024, 2)), ValueError, r"gvnn_warp\.bilinear_sample(_lanes)?: the output would have shape .* \(2147483648 elements\); kernels index with int32"),
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_bad_input_message(case):
    call, exc, pattern = CASES[case]
    with pytest.raises(exc, match=r"gvnn_warp\.[a-z0-9_]+: " if "gvnn_warp" not in pattern else pattern) as info:
        call()
    assert info.match(pattern)


@pytest.mark.parametrize(
    "fn, make",
    [
        (G.so3_exp, lambda: torch.rand(4, 3, dtype=f64)),
        (lambda g: G.bilinear_sample(IMG, g), lambda: torch.rand(2, 3, 3, 2, dtype=f64) - 0.5),
    ],
)
def test_second_order_gradients_refused_clearly(fn, make):
    # create_graph=True gives a first-order gradient; differentiating it again names the function
    x = make().requires_grad_()
    (g,) = torch.autograd.grad(fn(x).pow(2).sum(), x, create_graph=True)
    with pytest.raises(NotImplementedError, match=r"gvnn_warp\.[a-z0-9_]+: second-order gradients are not supported"):
        g.pow(2).sum().backward()
