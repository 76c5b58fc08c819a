"""The error of input files: a file or folder given to gvnn_warp that cannot be used.

:class:`InputError` is the base of ``gvnn_warp.datasets.DatasetError`` (a sequence folder, list,
image or trajectory file) and ``gvnn_warp.vo.checkpoint.CheckpointError`` (a checkpoint of another
format or version). Its message is one line naming the file; the command line prints it as such
(status 1), without the usage text that belongs to mistakes in the arguments.
"""

__all__ = ["InputError"]


class InputError(ValueError):
    """A file or folder that cannot be used (missing, unreadable, of another format); the message is
    one line naming it."""
