"""The exceptions fogd raises for an operator's mistakes, each with the exit status a command returns.

Every command catches `FogdError` at its top and prints `str(error)` as one line; anything else is a bug.
"""

import os


class FogdError(Exception):
    """An error an operator can act on; `exit_status` is what the command exits with."""

    exit_status = 1


class UsageError(FogdError):
    """A bad option or argument on the command line."""

    exit_status = 2


class InputError(FogdError):
    """A data file (CSV run, profile) that cannot be used as it is."""

    exit_status = 65  # EX_DATAERR


class NoInputError(InputError):
    """An input file (run CSV, profile) that does not exist or cannot be read."""

    exit_status = 66  # EX_NOINPUT


class ModelFileError(FogdError):
    """A model file that is corrupt, hostile or of another version."""

    exit_status = 65  # EX_DATAERR


class NoModelFileError(ModelFileError):
    """A model file that does not exist or cannot be read."""

    exit_status = 66  # EX_NOINPUT


class ConfigError(FogdError):
    """A configuration that cannot be used."""

    exit_status = 78  # EX_CONFIG


class DeviceError(FogdError):
    """A serial port or output that cannot be opened."""

    exit_status = 74  # EX_IOERR


class OutputError(DeviceError):
    """An output file that cannot be written: a missing directory, a full disk, a directory or socket named as
    the output."""


def describe_os_error(error: OSError) -> str:
    """`OSError` as 'path: reason' without Python's '[Errno N]' prefix."""
    reason = error.strerror or os.strerror(error.errno or 0) or str(error)
    return f"{error.filename}: {reason}" if error.filename else reason
