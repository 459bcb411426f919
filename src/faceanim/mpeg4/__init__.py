"""MPEG-4 face animation: the FAP table, FAP streams and .fap files, feature points and FAPU."""

from .fapfile import format_fap, parse_fap, read_fap, write_fap
from .faps import EXPRESSIONS, N_FAPS, VISEMES, Fap, FapError, FapStream, fap, faps
from .fdp import FeaturePoints, feature_points

__all__ = [
           "EXPRESSIONS",
           "N_FAPS",
           "VISEMES",
           "Fap",
           "FapError",
           "FapStream",
           "FeaturePoints",
           "fap",
           "faps",
           "feature_points",
           "format_fap",
           "parse_fap",
           "read_fap",
           "write_fap",
]
