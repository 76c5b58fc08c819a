"""Geometry as ``@wp.func`` libraries and the thin kernels over them:

- :mod:`.lie`: so3, SE3 and Sim3 exponential and logarithm maps, quaternions, Euler angles, poses;
- :mod:`.camera`: the pinhole camera (unproject, project, the rays of a pixel row);
- :mod:`.lens`: the camera models (pinhole, radial-tangential, fisheye) with their contract, and
  :mod:`.lens_rays`: pixel rays moved and projected through a lens, for fused kernels;
- :mod:`.lie_kernels`, :mod:`.camera_kernels`, :mod:`.lens_kernels`: one thin kernel per op.
"""
