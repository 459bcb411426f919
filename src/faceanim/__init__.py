"""faceanim: 3D facial animation from the papers, as working software."""

from faceanim.version import __version__

__all__ = ["__version__"]
