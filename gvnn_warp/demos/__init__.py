"""Small end-to-end demonstrations of the layers on data made at run time (torch and matplotlib).

- :mod:`.align`: the relative pose of two rendered RGB-D views recovered by gradient descent through
  ``warp_frame_depth`` (``gvnn-warp align``);
- :mod:`.flow`: a per-pixel affine optic flow fitted between two synthetic frames with an
  M-estimator and a smoothness term (``gvnn-warp flow``).

Each demo is one function (:func:`.align.align_demo`, :func:`.flow.flow_demo`) that prints its
progress, writes its figure into a folder and returns its figures of merit; the command line
(``gvnn_warp.cli``) only parses arguments and calls it. The submodules import torch: import them
by name (this package imports none of them).
"""
