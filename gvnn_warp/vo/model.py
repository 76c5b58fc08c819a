"""The siamese pose-regression network of the paper's visual-odometry application (gvnn, section
"Application: Training on RGB-D Visual Odometry"), scaled down to train on a 2-core CPU.

As in the paper: VGG-style 3x3 convolutions, stride 2 for every downsampling and no pooling, a PReLU
after every convolution except the last three, two heads with shared weights fused early (their
feature maps are concatenated after ``n_head_layers`` convolutions), MSRA (kaiming) initialisation,
and a last layer initialised to zero so the network starts at the identity pose.

Each head sees one RGB-D frame: RGB minus 0.5 and, with ``depth_input`` (the default), the inverse
depth ``1 / depth`` (1/m) as a 4th channel -- translation shows in the images as parallax
proportional to inverse depth. Both frames of an RGB-D pair have a depth map, so the heads stay
identical (shared weights); the loss only ever uses the reference depth.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..functional.lie import se3_to_matrix
from ..functional.sampling import warp_frame_depth
from .pose import compose_pose, full_xi, invert_pose, median_depth, mirror_pose

# compose_pose, invert_pose and mirror_pose (now in .pose) stay importable from here
__all__ = ["MOTIONS", "SYMMETRIES", "CascadeVO", "SiameseVO", "compose_pose", "invert_pose", "mirror_pose", "pose_dim"]

MOTIONS = {"so3": 3, "se3": 6}

#: the exact symmetries of a pair that :meth:`CascadeVO.predict` can average over: ``"swap"`` (the
#: pair in reverse order predicts the inverse pose), ``"mirror_x"`` / ``"mirror_y"`` (both frames
#: mirrored left-right / upside-down predict the mirrored pose; exact only when the principal point
#: is the image centre along that axis and the skew is 0, else skipped)
SYMMETRIES = ("swap", "mirror_x", "mirror_y")


def pose_dim(motion: str) -> int:
    """Length of the pose vector the network predicts: 3 (``so3``: omega) or 6 (``se3``: [omega, t])."""
    if motion not in MOTIONS:
        raise ValueError(f"motion must be one of {sorted(MOTIONS)}, got {motion!r}")
    return MOTIONS[motion]


def _conv(c_in: int, c_out: int, stride: int = 2, act: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = [nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1)]
    if act:
        layers.append(nn.PReLU(c_out))
    return nn.Sequential(*layers)


class SiameseVO(nn.Module):
    """Siamese network regressing the relative pose ``T_live_ref`` of an RGB(-D) frame pair.

    Layout for ``widths = (16, 32, 64, 128)``, input 128x96 (every convolution 3x3, stride 2):

    - per head (shared weights): 4 -> 16 -> 32 channels (64x48, 32x24), PReLU after each;
    - fused: concatenation (64 channels), then 64 -> 64 -> 64 -> 128 -> 128 (16x12, 8x6, 4x3, 2x2),
      PReLU;
    - the last three layers, linear: a convolution over the whole remaining map (the paper's
      2x1 / 2x2 convolutions that absorb the input size; here it is adaptive), then two 1x1
      convolutions 128 -> 128 -> ``pose_dim``; the last one is initialised to zero.

    The output is scaled per component (``omega_scale`` radians, ``t_scale`` metres per unit) so
    the raw regression targets are of order one.

    Args:
        motion: ``"so3"`` (3 outputs, omega) or ``"se3"`` (6 outputs, [omega, t]).
        size: input (width, height); the images must have this size.
        widths: channel widths; heads use the first two, the fused trunk the rest.
        depth_input: append inverse depth as a 4th input channel of each head.
        n_head_layers: convolutions per head before fusion.
    """

    def __init__(
        self,
        motion: str,
        size: tuple[int, int] = (128, 96),
        widths: tuple[int, ...] = (16, 32, 64, 128),
        depth_input: bool = True,
        n_head_layers: int = 2,
        omega_scale: float = 0.1,
        t_scale: float = 0.05,
        depth_normalised_t: bool = True,
    ):
        super().__init__()
        self.motion = motion
        self.out_dim = pose_dim(motion)
        self.size = tuple(size)
        self.depth_input = bool(depth_input)
        self.depth_normalised_t = bool(depth_normalised_t)
        c_in = 4 if depth_input else 3
        widths = tuple(widths)
        if len(widths) <= n_head_layers:
            raise ValueError("need more widths than head layers")

        head: list[nn.Module] = []
        c = c_in
        for w in widths[:n_head_layers]:
            head.append(_conv(c, w))
            c = w
        self.head = nn.Sequential(*head)

        trunk: list[nn.Module] = []
        c = 2 * c
        trunk_widths = [2 * widths[n_head_layers - 1], *widths[n_head_layers:], widths[-1]]
        for w in trunk_widths:
            trunk.append(_conv(c, w))
            c = w
        self.trunk = nn.Sequential(*trunk)

        # spatial size after all the stride-2 convolutions (kernel 3, padding 1)
        W, H = self.size
        for _ in range(n_head_layers + len(trunk_widths)):
            W, H = (W + 1) // 2, (H + 1) // 2
        self.feature_hw = (H, W)
        self.tail = nn.Sequential(
            nn.Conv2d(c, c, (H, W)),  # linear from here on: the last three convolutions
            nn.Conv2d(c, c, 1),
            nn.Conv2d(c, self.out_dim, 1),
        )
        scale = [omega_scale] * 3 + [t_scale] * (self.out_dim - 3)
        self.register_buffer("out_scale", torch.tensor(scale, dtype=torch.float32), persistent=False)
        self.reset_parameters()
        # float32 whatever torch's default dtype (the data are float32); channels-last: the faster
        # layout of the convolutions (forward + backward) on this CPU
        self.to(dtype=torch.float32, memory_format=torch.channels_last)

    def reset_parameters(self) -> None:
        """MSRA init for every convolution (PReLU slope 0.25), zero for the last layer."""
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, a=0.25, mode="fan_in", nonlinearity="leaky_relu")
                nn.init.zeros_(m.bias)
        last = self.tail[-1]
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)

    def encode(self, image: Tensor, depth: Tensor | None) -> Tensor:
        """One head's input: (B, 3|4, H, W), RGB - 0.5 and inverse depth."""
        x = image - 0.5
        if self.depth_input:
            if depth is None:
                raise ValueError("this network takes depth as input")
            inv = torch.where(depth > 1e-3, 1.0 / depth.clamp_min(1e-3), torch.zeros_like(depth))
            x = torch.cat([x, inv], dim=1)
        return x

    def forward(
        self, ref: Tensor, live: Tensor, ref_depth: Tensor | None = None, live_depth: Tensor | None = None
    ) -> Tensor:
        """Pose vectors (B, 3) omega or (B, 6) [omega, t] of ``T_live_ref``.

        Args:
            ref, live: (B, 3, H, W) images in [0, 1] at the network's ``size``.
            ref_depth, live_depth: (B, 1, H, W) depths (m), needed with ``depth_input``.
        """
        B, _, H, W = ref.shape
        if (W, H) != self.size:
            raise ValueError(f"network built for {self.size[0]}x{self.size[1]} inputs, got {W}x{H}")
        both = torch.cat([self.encode(ref, ref_depth), self.encode(live, live_depth)], dim=0)
        both = both.contiguous(memory_format=torch.channels_last)
        f = self.head(both)  # shared weights: both heads in one batch
        f = torch.cat([f[:B], f[B:]], dim=1)
        out = self.tail(self.trunk(f)).flatten(1) * self.out_scale
        if self.out_dim == 6 and self.depth_normalised_t:
            if ref_depth is None:
                raise ValueError("depth_normalised_t needs the reference depth")
            out = torch.cat([out[:, :3], out[:, 3:] * median_depth(ref_depth)[:, None]], dim=1)
        return out


class CascadeVO(nn.Module):
    """:class:`SiameseVO` networks refining one pose coarse to fine (iterative alignment through the
    3D spatial transformer).

    Stage 1 sees the (reference, live) pair, downsampled by ``scales[0]``. Every later stage sees
    the reference frame and the live image warped into it with the pose so far
    (``warp_frame_depth`` with the reference depth; pixels with no source are mid-grey), so its
    input is what is *left* to explain - after a good rotation estimate, mostly the
    depth-dependent parallax of the translation - and it predicts a correction ``d`` composed as
    ``T(xi) T(d)`` (:func:`compose_pose`): the warped image samples the live one at ``T(xi) X``,
    so warping it again by ``T(d)`` samples at ``T(xi) T(d) X`` (up to the reference depth being
    read at the moved pixel), i.e. ``d`` is the pose still between the pair it sees. The warp that
    builds the next stage's input is not differentiated (the pose it used reaches the output
    through the composition). Every stage starts at the identity (zero last layer), so the cascade
    does too. Training scores every stage's estimate (:func:`gvnn_warp.vo.train.train`).

    Args:
        motion: ``"so3"`` or ``"se3"``.
        scales: one entry per stage, its input downsampling factor (2x2 means for a factor 2, ...):
            ``(2, 1)`` is a coarse network at half resolution refined by one at full resolution;
            ``(1,)`` a plain :class:`SiameseVO`.
        size: full input (width, height).
        **kwargs: passed to every :class:`SiameseVO`.
    """

    def __init__(self, motion: str, scales: tuple[int, ...] = (1,), size: tuple[int, int] = (128, 96), **kwargs):
        super().__init__()
        scales = tuple(int(s) for s in scales)
        W, H = size
        if not scales or any(s < 1 or W % s or H % s for s in scales):
            raise ValueError(f"CascadeVO: scales must be positive divisors of the size {W}x{H}, got {scales!r}")
        self.scales = scales
        self.stages = nn.ModuleList(SiameseVO(motion, size=(W // s, H // s), **kwargs) for s in scales)
        self.motion = motion
        self.out_dim = self.stages[0].out_dim
        self.size = (W, H)

    def forward(
        self,
        ref: Tensor,
        live: Tensor,
        ref_depth: Tensor | None = None,
        live_depth: Tensor | None = None,
        K: Tensor | None = None,
        all_stages: bool = False,
        refine: int = 0,
    ) -> Tensor | list[Tensor]:
        """Pose vectors of ``T_live_ref`` ((B, 3) or (B, 6)); with ``all_stages`` the list of every
        stage's estimate (the last is the output). ``K`` ((3, 3) or (B, 3, 3)) and ``ref_depth`` are
        needed from the second stage on.

        ``refine``: apply the last stage this many more times, each time to the live image warped
        with the estimate so far (test-time iterative refinement: the last network was trained to
        correct an estimate from the pair it leaves; training itself uses ``refine=0``).
        """
        if refine < 0 or (refine and len(self.stages) < 2):
            raise ValueError(f"CascadeVO: refine must be >= 0 and needs at least 2 stages, got {refine!r}")
        xi = self._stage(0, ref, live, ref_depth, live_depth)
        out = [xi]
        for k in [*range(1, len(self.stages)), *([len(self.stages) - 1] * int(refine))]:
            if K is None or ref_depth is None:
                raise ValueError("CascadeVO: stages after the first need K and ref_depth")
            with torch.no_grad():
                pose = se3_to_matrix(full_xi(xi.detach()))
                warped, valid = warp_frame_depth(live, ref_depth, pose, K)
                warped = torch.where(valid, warped, torch.full_like(warped, 0.5))
            xi = compose_pose(xi, self._stage(k, ref, warped, ref_depth, ref_depth))
            out.append(xi)
        return out if all_stages else xi

    def predict(
        self,
        ref: Tensor,
        live: Tensor,
        ref_depth: Tensor | None = None,
        live_depth: Tensor | None = None,
        K: Tensor | None = None,
        refine: int = 0,
        symmetries: tuple[str, ...] = (),
    ) -> Tensor:
        """:meth:`forward`'s pose, averaged over the pair's exact symmetries (:data:`SYMMETRIES`,
        test-time augmentation): with ``("swap", "mirror_y")`` the network sees the pair, the pair
        in reverse order, and both mirrored upside down, and the four poses, brought back to the
        pair's, are averaged (pose vectors; the estimates differ by a few degrees at most). A mirror
        whose axis the intrinsics are not symmetric about (principal point off the image centre
        by more than 1e-4 px, or skew) is skipped. Needs depth for both frames with ``"swap"``."""
        unknown = [n for n in symmetries if n not in SYMMETRIES]
        if unknown:
            raise ValueError(f"CascadeVO.predict: unknown symmetries {unknown}, expected some of {SYMMETRIES}")
        W, H = self.size
        Kc = None if K is None else (K if K.dim() == 2 else K[0])
        axes = [0]
        for axis, name in ((1, "mirror_x"), (2, "mirror_y")):
            if name in symmetries and Kc is not None and float(Kc[0, 1]) == 0.0 and abs(
                float(Kc[axis - 1, 2]) - ((W if axis == 1 else H) - 1) / 2
            ) < 1e-4:
                axes += [a | axis for a in axes]  # every combination of the mirrors
        orders = (False, True) if "swap" in symmetries else (False,)
        total = 0
        for swap in orders:
            a, b, ad, bd = (live, ref, live_depth, ref_depth) if swap else (ref, live, ref_depth, live_depth)
            for m in axes:
                dims = [d for d, bit in ((-1, 1), (-2, 2)) if m & bit]
                xs = [None if x is None else (x.flip(dims) if dims else x) for x in (a, b, ad, bd)]
                xi = self(*xs, K, refine=refine)
                for axis, bit in ((0, 1), (1, 2)):
                    if m & bit:
                        xi = mirror_pose(xi, axis)
                total = total + (invert_pose(xi) if swap else xi)
        return total / (len(orders) * len(axes))

    def _stage(self, k: int, ref: Tensor, live: Tensor, ref_depth: Tensor | None, live_depth: Tensor | None) -> Tensor:
        s = self.scales[k]
        if s > 1:
            ref, live = F.avg_pool2d(ref, s), F.avg_pool2d(live, s)
            ref_depth = None if ref_depth is None else F.avg_pool2d(ref_depth, s)
            live_depth = None if live_depth is None else F.avg_pool2d(live_depth, s)
        return self.stages[k](ref, live, ref_depth, live_depth)
