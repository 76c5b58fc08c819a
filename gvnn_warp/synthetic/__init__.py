"""Synthetic RGB-D data: a textured room of boxes, camera trajectories in it, and a Warp ray caster.

Data generation lives here, apart from the layers: nothing in ``gvnn_warp.kernels`` or the torch
front imports it. Never imports torch (numpy and Warp only).

- :mod:`.scene`: the room layout (``ROOM_MIN``, ``ROOM_MAX``, ``CAMERA_REGION_MIN/MAX``,
  ``BOX_CLEARANCE``), :class:`RoomScene`, :func:`make_room_scene`, :func:`surface_distance`;
- :mod:`.trajectories`: :func:`default_intrinsics`, :func:`rotation_trajectory`,
  :func:`smooth_se3_trajectory`, :func:`relative_pose`, :func:`pose_error`, :func:`euler_to_rotation`,
  :func:`rotation_angle_deg`;
- :mod:`.render`: :func:`render_rgbd` (colour and depth of a scene from camera poses, on the CPU);
- :mod:`.sequence`: :func:`~.sequence.render_sequence`, a rendered sequence written as a TUM RGB-D
  folder (what ``gvnn-warp render`` does).

Example::

    from gvnn_warp.synthetic import default_intrinsics, make_room_scene, render_rgbd, smooth_se3_trajectory

    K = default_intrinsics(64, 48)
    image, depth = render_rgbd(make_room_scene(seed=0), smooth_se3_trajectory(10, seed=0), K, 64, 48)
"""

from .._exports import lazy_exports

# the names of the modules below (their __all__), loaded on first use: the renderer defines its
# kernels at import, which `gvnn-warp --help` should not wait for
__getattr__, __dir__ = lazy_exports(__name__, ("render", "scene", "trajectories"))
