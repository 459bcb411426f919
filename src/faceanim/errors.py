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


class Interrupted(KeyboardInterrupt):
    """A stop signal (SIGINT, SIGTERM, SIGHUP) raised where the command is, so that it unwinds as on
    Ctrl-C: temporary files and folders removed, no partial output, an existing output untouched."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


# the stop signals received by this process (the ``faceanim`` command records them): a stop that a
# library swallows on its way up (an exception in a finaliser is only printed) is still seen before
# an output is put in place (faceanim.io.files.atomic_output) and when the command ends
STOPS: list[int] = []


def shown(value, limit: int = 40, tail: bool = False) -> str:
    """A user-given name or token as it may appear in a one-line message: printable characters
    only (a terminal escape code in a file cannot reach the user's terminal), at most ``limit``
    long: its start, or with ``tail`` its end (a path's file name)."""
    s = "".join(c if c.isprintable() else "?" for c in str(value))
    if len(s) <= limit:
        return s
    return "..." + s[-(limit - 3):] if tail else s[:limit - 3] + "..."
