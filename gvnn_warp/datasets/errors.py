"""The one error of the dataset readers."""

__all__ = ["DatasetError"]


class DatasetError(ValueError):
    """A sequence folder or trajectory file that cannot be read; the message names the file."""
