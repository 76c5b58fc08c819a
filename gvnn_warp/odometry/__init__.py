"""Direct RGB-D odometry without torch (numpy and Warp): the aligner (:mod:`.aligner`), tracking a
sequence frame to frame or to keyframes (:mod:`.tracking`), and trajectory metrics and figures
computed with evo (:mod:`.evaluation`).
"""

from . import aligner
from .aligner import *  # noqa: F403

__all__ = list(aligner.__all__)
