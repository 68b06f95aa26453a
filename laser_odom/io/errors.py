"""Errors of the writers in :mod:`laser_odom.io`, turned into one-line messages by the CLIs."""


class OutputExistsError(FileExistsError):
    """The output path exists already; writers never overwrite it unless told to."""


class BagWriteError(RuntimeError):
    """A bag could not be written; ``str(error)`` is a one-line explanation."""
