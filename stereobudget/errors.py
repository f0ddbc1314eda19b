"""Error classes of stereobudget, each with the exit code the CLI uses for it.

Every error a user can cause with bad input is a subclass of :class:`StereoBudgetError`.
The CLI prints ``sb-xxx: error: <path>: <message>`` on one line and exits with
``exit_code``; it never shows a traceback for these.  ``docs/errors.md`` lists them.
"""

from __future__ import annotations


class StereoBudgetError(Exception):
    """Base class: a problem with the user's input, options or environment."""

    exit_code = 1

    def __init__(self, message: str, *, path: str | None = None):
        super().__init__(message)
        self.message = message
        self.path = path

    def __str__(self) -> str:
        return f"{self.path}: {self.message}" if self.path else self.message


# --- sample-file (.sbs) errors: one class per validation step ----------------------

class SampleFileError(StereoBudgetError):
    """Base class of every problem found while reading a sample file."""

    exit_code = 4


class NotASampleFileError(SampleFileError):
    """The bytes do not start with the .sbs signature (or were mangled in text-mode transfer)."""

    exit_code = 4


class TruncatedFileError(SampleFileError):
    """The file ends before the header or the payload it declares is complete."""

    exit_code = 5


class UnsupportedVersionError(SampleFileError):
    """The major version, or the payload codec (1.1), is one this reader cannot decode."""

    exit_code = 6


class CorruptHeaderError(SampleFileError):
    """Header CRC mismatch, or a field with an impossible value (dimensions, dtype, pattern...)."""

    exit_code = 7


class CorruptPayloadError(SampleFileError):
    """Payload length differs from what the header implies, the payload CRC does not match, or a coded payload does not decode."""

    exit_code = 8


# --- images, options, resources -------------------------------------------------------

class ImageReadError(StereoBudgetError):
    """An input image cannot be read or has an unsupported layout (empty, 0x0, float, NaN...)."""

    exit_code = 9


class MismatchError(StereoBudgetError):
    """Left image and sample file disagree (size, channels, bit depth)."""

    exit_code = 10


class OptionError(StereoBudgetError):
    """An option value is invalid for this input (disparity range, stride, offset...)."""

    exit_code = 2


class MemoryLimitError(StereoBudgetError):
    """The job would need more memory than allowed (see ``--max-memory``)."""

    exit_code = 11


class OutputError(StereoBudgetError):
    """An output cannot be written: exists without ``--overwrite``, equals an input, unwritable."""

    exit_code = 12


class CalibrationError(StereoBudgetError):
    """A calibration file cannot be used: unreadable, malformed, inconsistent, or for another camera pair or image size."""

    exit_code = 13


EXIT_OK = 0
EXIT_FAILURES = 1          # batch finished but at least one file failed; or an unexpected error
EXIT_INTERRUPTED = 130     # SIGINT / SIGTERM
