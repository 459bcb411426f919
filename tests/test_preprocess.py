import numpy as np
import pytest

from faceanim.build.preprocess import (
    CHIN,
    EYE_OUTER_L,
    EYE_OUTER_R,
    NOSE_TIP,
    apply_transform,
    build_average_face,
    default_average_face,
    normalising_transform,
    preprocess,
    resample_to_grid,
)
from faceanim.errors import LandmarkError
from faceanim.face.face import landmarks_478
from faceanim.face.frame import face_frame
from faceanim.face.landmarks import BASIC22


@pytest.fixture(scope="module")
def lm(face, face_landmarks):
    return landmarks_478(face, face_landmarks)


def test_grid_lies_on_the_surface_and_keeps_landmarks(face, lm):
    grid = resample_to_grid(face, lm, 60)
    iod = face_frame(lm).iod
    _, dist, _ = face.closest_points(grid.mesh.vertices)
    # linear interpolation of a smooth, finely tessellated surface: on it, except where the grid
    # bridges the mouth opening (the default face's mouth is a recessed cavity)
    assert np.median(dist) < 0.001 * iod and np.percentile(dist, 90) < 0.01 * iod
    assert grid.mesh.n_vertices > 0.5 * 60 * 60
    # the thesis' landmarks sit on their nearest grid vertex, within a grid step or two (the inner
    # lips lie in the mouth opening the grid bridges); seen from the front, where the grid samples,
    # every one of them
    step = np.ptp(grid.mesh.vertices[:, 0]) / 59
    frame = face_frame(lm)
    idx = [i for _, i in BASIC22 if i not in (13, 14)]
    front = frame.to_local(grid.landmarks[idx])[:, :2] - frame.to_local(lm[idx])[:, :2]
    assert np.linalg.norm(front, axis=1).max() < 2.5 * step
    # in 3D too, but for the chin: on the head it lies on the face oval where the surface turns
    # under the jaw (its depth falls 2.5 mm per mm of height there), so the grid, inside the oval,
    # ends 1.7 steps above it and 9 mm in front of it
    idx = [i for i in idx if i != 152]
    assert np.linalg.norm(grid.landmarks[idx] - lm[idx], axis=1).max() < 2.5 * step
    assert grid.mesh.uv is not None and grid.mesh.texture is not None  # the scan's texture still maps


def test_normalising_transform_maps_the_four_landmarks(face, lm, rng):
    ref = lm * 1.3 + rng.normal(scale=0.001, size=lm.shape)
    ref = ref - ref[NOSE_TIP]
    t = normalising_transform(lm, ref)
    moved = apply_transform(t, lm)
    idx = [NOSE_TIP, EYE_OUTER_R, EYE_OUTER_L, CHIN]
    assert np.allclose(moved[idx], ref[idx], atol=1e-12)
    flat = lm.copy()
    flat[[EYE_OUTER_R, EYE_OUTER_L, CHIN], 2] = flat[NOSE_TIP, 2]
    flat[[EYE_OUTER_R, EYE_OUTER_L, CHIN], 1] = flat[NOSE_TIP, 1]
    with pytest.raises(LandmarkError, match="plane"):
        normalising_transform(flat, ref)


def test_preprocess_normalises_onto_the_average_face(face, lm):
    afm = default_average_face()
    grid = preprocess(face, lm, afm, 50)
    idx = [EYE_OUTER_R, EYE_OUTER_L, CHIN]
    # landmarks snapped to grid vertices, then mapped: close to the AFM's
    assert np.abs(grid.landmarks[NOSE_TIP]).max() < 0.05
    assert np.linalg.norm(grid.landmarks[idx] - afm.landmarks[idx], axis=1).max() < 0.1


def test_average_of_one_face_is_that_face(face, lm):
    afm = build_average_face([("default", face, lm)], 40)
    frame = face_frame(lm)
    m = afm.mesh()
    surface = face.with_vertices(frame.to_local(face.vertices) / frame.iod)
    _, dist, _ = surface.closest_points(m.vertices)
    assert np.median(dist) < 0.01 and np.isfinite(afm.depth).sum() > 0.5 * 40 * 40
