"""The self-supervised reprojection objective of Monodepth2 (Godard et al. 2019), as Warp kernels:

- :mod:`.ssim`: ``@wp.func`` library: reflection indices, SSIM from window sums, the per-pixel
  photometric error pe = alpha (1 - SSIM) / 2 + (1 - alpha) |a - b| of one candidate;
- :mod:`.kernels`: the thin kernels: the choice of each pixel's best candidate (forward only), the
  chosen candidate's error (differentiated by Warp), the per-item mean, and the edge-aware
  smoothness of a disparity map;
- :mod:`.pipeline`: the same objective on ``wp.array`` s (no torch), recordable on a ``wp.Tape``.

The definitions, stated once (the torch front ``gvnn_warp.reprojection_loss`` refers here):
for a target pixel p with a valid depth, each source s gives a *reprojection* candidate (the source
sampled where p's 3D point lands, border padding: ``warp_frame_depth``) and, with auto-masking, an
*identity* candidate (the source unwarped). Each candidate's error is

    pe = alpha * mean_c clamp((1 - SSIM_c) / 2, 0, 1) + (1 - alpha) * mean_c |target_c - cand_c|

with SSIM_c over the 3x3 window around p (reflection padding, as ``nn.ReflectionPad2d(1)``),
C1 = 0.01^2, C2 = 0.03^2, and the window statistics of ``avg_pool2d`` (sigma^2 = E[x^2] - mu^2).
The pixel's error is the minimum over its candidates, first the reprojections in source order,
then the identities; the first strict minimum wins, so on a tie a reprojection beats an identity
(Monodepth2's mask: mu = [min reprojection < min identity]) and a lower source index beats a
higher one. A reprojection candidate whose point cannot be projected (behind the source camera,
outside a lens model's domain) is not a candidate; a pixel with an invalid depth, or with no
candidate, is excluded from the mean. Gradients flow through the chosen candidate only.
"""
