"""The one error of the dataset readers."""

from ..errors import InputError

__all__ = ["DatasetError"]


class DatasetError(InputError):
    """A sequence folder or trajectory file that cannot be read; the message names the file."""
