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


def shown(value, limit: int = 40, tail: bool = False) -> str:
    """A user-given name or token as it may appear in a one-line message: printable characters
    only (a terminal escape code in a file cannot reach the user's terminal), at most ``limit``
    long: its start, or with ``tail`` its end (a path's file name)."""
    s = "".join(c if c.isprintable() else "?" for c in str(value))
    if len(s) <= limit:
        return s
    return "..." + s[-(limit - 3):] if tail else s[:limit - 3] + "..."
