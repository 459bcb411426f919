"""Drivers: what produces (frames x controls) curves over time - key frames, MPEG-4 actions and
their blending, speech (alignment, synthesis, visemes) and scene scripts. A driver never imports
a rig module; the curves meet a rig in :mod:`faceanim.player`."""
