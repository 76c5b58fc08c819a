"""Sampling images: the bilinear sampler (:mod:`.sampler`: one position at a time, :mod:`.scalar`, or
8, :mod:`.lanes`, with the channels' part of an adjoint on the lanes, :mod:`.lanes_grad`), the
sampling kernels and the fused 3D spatial transformer, pinhole and through a lens model
(:mod:`.kernels`; a block of 8 locations of the sampler's 8-lane kernel, with its adjoint:
:mod:`.bilinear_block`; of 8 pixels of the pinhole variant's: :mod:`.pinhole_block`; of the lens
variant: :mod:`.lens_block`), and host functions on ``wp.array`` s that ``wp.Tape`` can record
(:mod:`.pipeline`).
"""
