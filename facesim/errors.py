"""Errors: user mistakes (:class:`FacesimError`) and numerical failures (:class:`SolverError`).

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


class SolverError(Exception):
    """A numerical failure: a linear solve that did not converge, an equilibrium that could not be
    found, a non-finite state. Not a user mistake: a sequence catches it as a failed frame (flagged
    in every output) and goes on; anywhere else it is reported as a solver failure, not as bad input."""
