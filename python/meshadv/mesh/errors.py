"""Exceptions of the mesh layer."""

from __future__ import annotations


class MeshLoadError(ValueError):
    """A mesh file cannot be used: unreadable, truncated, empty, non-finite or too large.

    The message always names the file. Subclasses ``ValueError`` so callers validating user input can catch
    either.
    """


class MeshProcessingError(RuntimeError):
    """An external mesh-processing step (MeshLab through pymeshlab) failed, crashed or timed out.

    The message names the operation, the parameters and, for a crash, the signal that ended the worker.
    """
