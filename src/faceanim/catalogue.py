"""faceanim's catalogue of controls: the sets a face's rig is made of, by name (no imports: read by
the command line's help without loading anything heavy).

:func:`faceanim.autorig.auto_rig` makes them on a face; :func:`faceanim.autorig.full_rig` is the
same as one :class:`~faceanim.rig.rig.Rig`. ``faceanim rig --set``, ``photo --rig``, the viewer's
groups and batch jobs all read this one list.
"""

RIG_SETS = ("arkit", "visemes", "rpm", "au", "emotions", "fap")
SET_LABELS = {"arkit": "ARKit", "visemes": "Visemes", "rpm": "Ready Player Me", "au": "Action units (FACS)",
              "emotions": "Emotions", "fap": "MPEG-4 FAPs"}
EMOTIONS = ("joy", "sadness", "surprise", "fear", "anger", "disgust")
