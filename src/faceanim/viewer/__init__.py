"""``faceanim view``: a local browser viewer and editor for faceanim's glTF (and VRM) files.

:mod:`.server` serves one model, its sound and photos with the page in ``static/`` (three.js and
three-vrm installed there with npm, from ``static/package.json``, no CDN); :mod:`.groups` sorts
the model's morph targets into slider panels; :mod:`.points` checks picked points with the readers
of the commands that take them.
"""
