"""Geometry as ``@wp.func`` libraries and the thin kernels over them:

- :mod:`.lie`: so3, SE3 and Sim3 exponential and logarithm maps, quaternions, Euler angles, poses;
- :mod:`.camera`: the pinhole camera (unproject, project, the rays of a pixel row);
- :mod:`.lens`: the camera models (pinhole, radial-tangential, fisheye) with their contract (one
  module per model, the float64 dispatch on the model id, the typed fronts), and :mod:`.lens.rays`:
  pixel rays moved and projected through a lens, for fused kernels (8 at a time: :mod:`.lens.lanes`);
- :mod:`.kernels`: one thin kernel per op, pinhole and through a lens model (``<name>_lens()``).
"""
