"""Sampling images: the bilinear sampler (:mod:`.sampler`: one position at a time, :mod:`.scalar`, or
8, :mod:`.lanes`), the sampling kernels and the fused 3D spatial transformer, pinhole and through a
lens model (:mod:`.kernels`; a block of 8 pixels of the pinhole variant's 8-lane kernel, with its
adjoint: :mod:`.pinhole_block`; of the lens variant: :mod:`.lens_block`), and host functions
on ``wp.array`` s that ``wp.Tape`` can record (:mod:`.pipeline`).
"""
