"""The standards' tables faceanim reads and writes, in one bottom-layer package (no faceanim
imports but :mod:`faceanim.errors`).

- :mod:`~faceanim.standards.mpeg4`: MPEG-4 FBA's 68 FAPs, FAPU, visemes and expressions, the feature points.
- :mod:`~faceanim.standards.ipa`: IPA phones -> the ARPAbet phone of the same mouth (visemes for any
  language espeak-ng speaks).
"""
