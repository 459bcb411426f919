"""Exceptions faceanim raises for bad input.

Every error a user can cause derives from :class:`FaceAnimError`; its message says what is
wrong and what to do. The CLI prints it as one line on stderr and exits non-zero.
"""


class FaceAnimError(Exception):
    """Base class for all user-facing faceanim errors."""


class MeshError(FaceAnimError):
    """A mesh file is missing, unreadable, empty or has invalid coordinates."""


class DeformError(FaceAnimError):
    """Handles or deformation parameters are invalid (NaN, coincident, too few, unknown kernel)."""


class LandmarkError(FaceAnimError):
    """Landmarks could not be found or read (no face in the image, bad JSON)."""


class InputFileError(FaceAnimError):
    """A JSON or other input file is missing or malformed."""
