"""Direct RGB-D odometry without torch (numpy and Warp): the aligner (:mod:`.aligner`; its parts: the
arguments it takes (:mod:`.inputs`), prepared frames and their pooled pyramids (:mod:`.frame`), the
Levenberg-Marquardt state and recorded launches (:mod:`.solver`)), tracking a sequence frame to
frame or to keyframes (:mod:`.tracking`), trajectory metrics and figures computed with evo
(:mod:`.evaluation`), and a whole TUM folder tracked with its results written, as ``gvnn-warp track``
does (:mod:`.sequence`: ``make_aligner``, ``track_sequence``).
"""

from .._exports import lazy_exports

# DirectAligner and Frame, loaded on first use: the aligner defines its kernels at import, which
# `gvnn-warp --help` and the tracking loop's own module (KeyframePolicy) should not wait for
__getattr__, __dir__ = lazy_exports(__name__, ("aligner",))
