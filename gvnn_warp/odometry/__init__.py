"""Direct RGB-D odometry without torch (numpy and Warp): the aligner (:mod:`.aligner`; its parts: the
arguments it takes (:mod:`.inputs`), prepared frames and their pooled pyramids (:mod:`.frame`), the
Levenberg-Marquardt state and recorded launches (:mod:`.solver`)), tracking a sequence frame to
frame or to keyframes (:mod:`.tracking`), trajectory metrics and figures computed with evo
(:mod:`.evaluation`), and a whole TUM folder tracked with its results written, as ``gvnn-warp track``
does (:mod:`.sequence`: ``make_aligner``, ``track_sequence``).
"""

from . import aligner
from .aligner import *  # noqa: F403

__all__ = list(aligner.__all__)
