"""faceanim's version (one place: the package and `faceanim --version` read it)."""

__version__ = "0.1.0"
