"""The face: a mesh and its landmarks, with the geometry every method derives from them.

``from faceanim.face import Face`` - see :mod:`faceanim.face.face`. Modules: ``mesh`` (Mesh),
``landmarks`` (schemes, MediaPipe index tables, detection), ``frame`` (face frame, rigid
alignment), ``regions`` (skin, slits, face and free regions), ``fdp`` (MPEG-4 feature points and
FAPU), ``faps`` (the 68 FAPs and FAP streams), ``default`` (the embedded default face).
"""


def __getattr__(name):  # lazy, so that face.mesh can be imported by io without a cycle
    if name == "Face":
        from faceanim.face.face import Face

        return Face
    raise AttributeError(f"module 'faceanim.face' has no attribute '{name}'")
