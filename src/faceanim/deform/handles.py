"""Handle files: the JSON that ``faceanim deform MESH --handles H.json`` reads.

Two methods::

    {"method": "rbf", "handles": [[x, y, z], ...], "offsets": [[dx, dy, dz], ...],
     "kernel": "multiquadric", "smoothing": 0.01, "stiffness": null, "degree": null}

    {"method": "gde", "elements": [
        {"control": [x, y, z] | "pick": [u, v], "offset": [dx, dy, dz], "extent": 4,
         "metric": "edges", "kernel": "multiquadric", "smoothing": 0.01, "stiffness": null,
         "max_anchors": 20, "name": "chin"}, ...]}

``method`` defaults to ``rbf``; a ``comment`` key (any value) is allowed anywhere a key is.
:func:`load_handles` checks everything before it solves anything: unknown keys are named, text,
true/false or null where a number belongs, lists nested too deep or of mixed lengths, NaN and
infinity, coordinates beyond ``MAX_SCALE`` times the mesh's size, ``max_anchors`` outside
1..1000, negative or absurd extents, negative or NaN smoothing, too many handles. The solve's
result is checked for finiteness too. Every failure is a :class:`DeformError` (or a
:class:`LandmarkError` for a 2D pick that misses the face, an :class:`InputFileError` for a file
that is missing or not JSON) whose message names the file and the element.
"""

from __future__ import annotations

import os

import numpy as np

from faceanim.deform.base import LinearDeformer
from faceanim.deform.gde import GeometryDeformationElement, _show_key, bind_gdes
from faceanim.deform.rbf import (
    DEFAULT_SMOOTHING,
    MAX_WEIGHTS,
    _describe,
    bind_rbf,
    check_number,
    check_points,
)
from faceanim.errors import DeformError, FaceAnimError, InputFileError, LandmarkError
from faceanim.io.files import read_json

METHODS = ("rbf", "gde")
RBF_KEYS = ("method", "handles", "offsets", "kernel", "smoothing", "stiffness", "degree", "comment")
GDE_KEYS = ("method", "elements", "comment")
ELEMENT_KEYS = ("control", "pick", "offset", "extent", "metric", "kernel", "smoothing", "stiffness",
                "max_anchors", "name", "comment")
MAX_HANDLES = 2000  # RBF handles: one dense (N x N) solve and a (vertices x N) weight matrix
MAX_ELEMENTS = 1000  # GDEs in one file
MAX_SCALE = 1e6  # coordinates, offsets and lengths beyond this many times the mesh's size are refused
MAX_SMOOTHING = 1e6


def load_handles(path_or_spec, mesh, forward: str = "+z", up: str = "+y") -> tuple[LinearDeformer, np.ndarray]:
    """Read a handle file (a path) or an already parsed spec (a dict) and bind it to ``mesh``.

    Returns ``(deformer, offsets)``: ``deformer.apply(offsets)`` is the deformed mesh's vertices.
    ``forward`` and ``up`` are the view of 2D picks (``"pick": [u, v]`` in the detection view).
    """
    if isinstance(path_or_spec, (str, os.PathLike)):
        label = f"handle file '{path_or_spec}'"
        spec = read_json(path_or_spec, "handle file")
    else:
        label = "handles"
        spec = path_or_spec
    try:
        return _load(spec, mesh, label, forward, up)
    except (DeformError, LandmarkError, InputFileError) as exc:
        raise type(exc)(f"{label}: {exc}") from None
    except FaceAnimError:
        raise
    except (MemoryError, OverflowError, FloatingPointError):
        raise DeformError(f"{label}: the handles are too large or too many to solve; check their units "
                          "and count") from None


def _mesh_scale(mesh) -> tuple[float, float]:
    """(size of the mesh, largest coordinate magnitude allowed)."""
    v = mesh.vertices
    diag = float(mesh.bounding_box_diagonal)
    size = diag if np.isfinite(diag) and diag > 0 else max(float(np.abs(v).max()), 1.0)
    far = float(np.abs(v).max()) + size
    return size, MAX_SCALE * far


def _check_keys(d: dict, allowed, where: str) -> None:
    unknown = [k for k in d if k not in allowed]
    if unknown:
        shown = ", ".join(_show_key(k) for k in unknown[:5])
        raise DeformError(f"{where} has unknown key(s) {shown}{' ...' if len(unknown) > 5 else ''}; "
                          f"the keys are: {', '.join(k for k in allowed if k != 'comment')}")


def _check_magnitude(points: np.ndarray, limit: float, name: str, what: str) -> None:
    big = np.abs(points) > limit
    if big.any():
        i = int(np.flatnonzero(big.any(axis=-1) if points.ndim > 1 else big)[0])
        raise DeformError(f"{name} {i} is absurdly far ({what} beyond {limit:.3g}, {MAX_SCALE:g} times the mesh's "
                          "size); check the units")


def _load(spec, mesh, label: str, forward: str, up: str) -> tuple[LinearDeformer, np.ndarray]:
    if not isinstance(spec, dict):
        raise InputFileError(f"must hold a JSON object with a 'method' ('rbf' or 'gde'), got {_describe(spec)}")
    method = spec.get("method", "rbf")
    if not isinstance(method, str) or method not in METHODS:
        raise DeformError(f"unknown method {_show_key(method)} (use 'rbf' or 'gde')")
    size, far = _mesh_scale(mesh)
    if method == "rbf":
        deformer, offsets = _load_rbf(spec, mesh, size, far)
    else:
        deformer, offsets = _load_gde(spec, mesh, size, far, forward, up)
    with np.errstate(over="ignore", invalid="ignore"):
        result = deformer.apply(offsets)
    if not np.all(np.isfinite(result)):
        raise DeformError("the deformation gives NaN or infinite positions (offsets too large for the solve); "
                          "check the offsets' units")
    return deformer, offsets


def _load_rbf(spec: dict, mesh, size: float, far: float) -> tuple[LinearDeformer, np.ndarray]:
    _check_keys(spec, RBF_KEYS, "method 'rbf'")
    for key in ("handles", "offsets"):
        if key not in spec:
            raise InputFileError(f"method 'rbf' needs '{key}'")
        if not isinstance(spec[key], list):
            raise DeformError(f"'{key}' must be a list of [x, y, z] points, got {_describe(spec[key])}")
        if len(spec[key]) > MAX_HANDLES:
            raise DeformError(f"'{key}' has {len(spec[key])} points; at most {MAX_HANDLES} RBF handles are "
                              "supported (use GDEs for many local edits)")
    handles = check_points(spec["handles"], "handles")
    offsets = check_points(spec["offsets"], "offsets")
    if offsets.shape != handles.shape:
        raise InputFileError(f"{len(handles)} handles but {len(offsets)} offsets")
    _check_magnitude(handles, far, "handle", "a coordinate")
    _check_magnitude(offsets, MAX_SCALE * size, "offset", "a component")
    if mesh.n_vertices * len(handles) > MAX_WEIGHTS:
        raise DeformError(f"{len(handles)} handles on {mesh.n_vertices} vertices are too many for one RBF "
                          "system; use fewer handles or GDEs")
    kernel = spec.get("kernel", "multiquadric")
    smoothing = check_number(spec.get("smoothing", DEFAULT_SMOOTHING), "smoothing", 0.0, MAX_SMOOTHING)
    stiffness = spec.get("stiffness")
    if stiffness is not None:
        stiffness = check_number(stiffness, "stiffness", 0.0, MAX_SCALE * size, low_inclusive=False)
    degree = spec.get("degree")
    if degree is not None:
        degree = check_number(degree, "degree", -1, 1, integer=True)
    deformer = bind_rbf(mesh.vertices, handles, kernel=kernel, smoothing=smoothing, stiffness=stiffness,
                        degree=degree)
    return deformer, offsets


def _load_gde(spec: dict, mesh, size: float, far: float, forward: str,
              up: str) -> tuple[LinearDeformer, np.ndarray]:
    _check_keys(spec, GDE_KEYS, "method 'gde'")
    elements = spec.get("elements")
    if not isinstance(elements, list) or not elements:
        raise InputFileError("method 'gde' needs a non-empty 'elements' list")
    if len(elements) > MAX_ELEMENTS:
        raise DeformError(f"{len(elements)} elements; at most {MAX_ELEMENTS} are supported")
    gdes, offsets = [], []
    for k, e in enumerate(elements):
        if not isinstance(e, dict):
            raise DeformError(f"element {k} must be an object with 'control' (or 'pick') and 'offset', "
                              f"got {_describe(e)}")
        _check_keys(e, ELEMENT_KEYS, f"element {k}")
        if "offset" not in e:
            raise InputFileError(f"element {k} needs an 'offset' [dx, dy, dz]")
        offset = check_points(e["offset"], f"element {k} offset")
        if len(offset) != 1:
            raise DeformError(f"element {k} offset must be one [dx, dy, dz], got {len(offset)} points")
        _check_magnitude(offset[0], MAX_SCALE * size, f"element {k} offset component", "a value")
        e = {key: value for key, value in e.items() if key != "comment"}
        if "pick" in e and "control" in e:
            raise DeformError(f"element {k} has both 'control' and 'pick'; give one")
        if "pick" in e:
            e["control"] = _pick_to_control(mesh, e.pop("pick"), k, forward, up)
        elif "control" not in e:
            raise DeformError(f"element {k} needs a 'control' point [x, y, z] or a 2D 'pick' [u, v]")
        element = GeometryDeformationElement.from_dict(e, k)
        _check_magnitude(np.asarray(element.control), far, f"element {k} control coordinate", "a value")
        if element.metric == "euclidean" and element.extent > MAX_SCALE * size:
            raise DeformError(f"element {k} extent {element.extent:g} is absurd ({MAX_SCALE:g} times the mesh's "
                              "size); give it in mesh units")
        gdes.append(element)
        offsets.append(offset[0])
    return bind_gdes(mesh, gdes), np.array(offsets)


def _pick_to_control(mesh, pick, k: int, forward: str, up: str) -> list[float]:
    from faceanim.face.landmarks import pick_surface_points

    if not isinstance(pick, list) or len(pick) != 2:
        raise DeformError(f"element {k} pick must be [u, v] (two numbers in the detection view, 0..1), "
                          f"got {_describe(pick) if not isinstance(pick, list) else f'{len(pick)} values'}")
    uv = [check_number(x, f"element {k} pick coordinate") for x in pick]
    pos, _ = pick_surface_points(mesh, [uv], forward, up, what=f"element {k}: GDE pick")
    return pos[0].tolist()
