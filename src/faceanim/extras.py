"""faceanim's optional parts (``pip install 'faceanim[all]'``): a command that needs
one that is not installed says which, in one line, before it starts.

- ``speech``: pocketsphinx (aligning recorded speech with its transcript, hearing phones without
  one, live lip sync); ``say TEXT`` itself needs only espeak-ng;
- ``live``: python-osc and websockets (``faceanim live``'s VMC and browser sinks), sounddevice
  (``--mic``, PortAudio; the PortAudio library itself is Debian's libportaudio2), and pocketsphinx;
- ``batch``: Dask's distributed scheduler and bokeh (``faceanim batch``);
- ``identity``: dlib and its face recognition network (``faceanim photo`` with side photos checks
  that they show the front photo's person).

``bash scripts/setup.sh`` installs them all.
"""

from __future__ import annotations

import importlib

from faceanim.errors import FaceAnimError

EXTRAS = {"pocketsphinx": "speech", "pythonosc": "live", "websockets": "live", "sounddevice": "live",
          "distributed": "batch", "dask": "batch", "dlib": "identity", "face_recognition_models": "identity"}


class MissingExtra(FaceAnimError):
    """An optional part of faceanim that a command needs is not installed."""


def require(module: str, what: str):
    """``module`` imported, or :class:`MissingExtra` saying that ``what`` needs its extra."""
    try:
        return importlib.import_module(module)
    except ImportError:
        extra = EXTRAS.get(module.split(".")[0], "all")
        raise MissingExtra(f"{what} needs faceanim's '{extra}' extra, which is not installed: "
                           f"pip install 'faceanim[{extra}]' (or bash scripts/setup.sh)") from None
