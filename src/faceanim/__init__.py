"""faceanim: 3D facial animation from the papers, as working software."""

__version__ = "0.1.0"
