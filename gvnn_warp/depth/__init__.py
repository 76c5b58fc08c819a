"""Learning single-image depth and ego-motion from video, without labels (Monodepth2's recipe,
Godard et al. 2019, with gvnn_warp's fused objective :func:`gvnn_warp.reprojection_loss`):

- :mod:`.model`: the depth network (encoder-decoder, disparity at four scales) and the pose network
  (a frame pair -> axis-angle and translation through ``se3_to_matrix``);
- :mod:`.data`: colour frames of TUM-format folders as triplets (t-1, t, t+1), resized, with the
  camera (lens distortion included); depth files are read only for evaluation and figures;
- :mod:`.train`: training (time-boxed, checkpointed, resumable), the poses of each triplet from the
  direct aligner through the predicted depth (the default) or from the pose network;
- :mod:`.checkpoint`: reading the checkpoints training writes (the depth network kept);
- :mod:`.evaluate`: the standard depth metrics (Eigen et al.) with per-image median scaling;
- :mod:`.predict`: a trained network's depth frame by frame, one scale per sequence, for tracking
  from colour alone (``gvnn-warp track --depth predicted``).

Command line: ``gvnn-warp depth train`` / ``gvnn-warp depth eval`` (:mod:`gvnn_warp.cli.depth`).
"""
