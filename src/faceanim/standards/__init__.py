"""The standards' tables faceanim reads and writes, in one bottom-layer package (no faceanim imports).

- :mod:`~faceanim.standards.ipa`: IPA phones -> the ARPAbet phone of the same mouth (visemes for any
  language espeak-ng speaks).
"""
