"""Errors raised for user mistakes.

Every message is one line and names the file (if any), the field and what was expected, so
the CLI can print it verbatim and exit non-zero without a traceback.
"""

from __future__ import annotations


class FacesimError(Exception):
    """A user-facing error: bad input, bad file, impossible request."""


class ModelFileError(FacesimError):
    """A model file that cannot be read: missing, wrong format, unknown version, missing field."""

    def __init__(self, path, message: str):
        self.path = str(path)
        super().__init__(f"{self.path}: {message}")
