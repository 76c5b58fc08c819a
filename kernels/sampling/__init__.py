"""Sampling images: the bilinear sampler (:mod:`.sampler`), the sampling kernels and the fused 3D
spatial transformer (:mod:`.kernels`, through a lens model: :mod:`.lens_kernels`), and host
functions on ``wp.array`` s that ``wp.Tape`` can record (:mod:`.pipeline`).
"""
