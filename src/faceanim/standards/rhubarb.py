"""Rhubarb Lip Sync's mouth shapes (Daniel Wolf's tool; the Hanna-Barbera set used in 2D animation).

Six basic shapes and three extended ones, as Rhubarb's documentation defines them: A closed (p, b,
m), B slightly open with the teeth together (most consonants, the "ee" of bee), C open (e of men, a
of bat), D wide open (a of father), E slightly rounded (o of off, ir of bird), F puckered (you,
show, way), G the upper teeth on the lower lip (f, v), H the tongue raised (a long l), X the mouth
at rest (pauses). :data:`PHONE_SHAPES` gives each ARPAbet phone its shape (a diphthong two, one
after the other).
"""

from __future__ import annotations

SHAPES: dict[str, str] = {
    "A": "closed, lips pressed (p, b, m)",
    "B": "slightly open, teeth together (most consonants, ee)",
    "C": "open (e of men, a of bat)",
    "D": "wide open (a of father)",
    "E": "slightly rounded (o of off, ir of bird)",
    "F": "puckered (oo of you, ow of show, w)",
    "G": "upper teeth on the lower lip (f, v)",
    "H": "tongue raised behind the teeth (l)",
    "X": "at rest (pauses)",
}

# ARPAbet -> shape; a diphthong's two shapes share its time (its first part the longer)
PHONE_SHAPES: dict[str, str] = {
    "P": "A", "B": "A", "M": "A",
    "F": "G", "V": "G", "L": "H",
    "AA": "D", "AE": "C", "AH": "C", "EH": "C",
    "AO": "E", "ER": "E", "R": "E", "UH": "E",
    "UW": "F", "W": "F",
    "IY": "B", "IH": "B", "Y": "B", "T": "B", "D": "B", "K": "B", "G": "B", "N": "B", "NG": "B", "S": "B",
    "Z": "B", "SH": "B", "ZH": "B", "CH": "B", "JH": "B", "TH": "B", "DH": "B", "HH": "B",
    "AY": "DB", "AW": "DF", "OY": "EB", "EY": "CB", "OW": "EF",
    "SIL": "X",
}
CUE_SUFFIXES = (".tsv", ".json")  # the files Rhubarb Lip Sync writes that faceanim writes too
FIRST_PART = 0.6  # share of a diphthong's time its first shape takes
