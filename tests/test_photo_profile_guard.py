"""The profile guard of faceanim.build.photo (profile_outliers, Reconstruction.refused) and what it
does for fit_identity, against a real ICT identity as the oracle.

A morphable head of known identity weights (ICT FaceKit's modes, as the generic head ships them)
is rendered from the front and in true profile; its profile's points are then spoiled the way a
misdetection spoils them: the chin and the menton found on the neck (0.5 IOD below), or every point
0.5 IOD off. The guard must leave those points out (or set the whole profile aside), and the
identity fitted with the guard must lie closer to the true head than the one fitted without it
(the guard switched off by an infinite threshold). Errors: mean distance of the face's skin
vertices from the true head's (same topology, after a similarity), in inter-ocular distances.
"""

from __future__ import annotations

import numpy as np
import pytest

from faceanim.build import photo as P
from faceanim.face.frame import similarity

from conftest import rendered_identity

SEED = 1000  # an identity of the tuning set (ICT seeds 1000-1009), not of the held-out one
CHIN = (175, 152)  # the chin and the menton
OFF = 0.5  # how far a spoiled point is moved, inter-ocular distances


@pytest.fixture(scope="module")
def person():
    """(head, true identity vertices, front + profile views) of one ICT identity."""
    head, truth, views = rendered_identity(SEED)
    assert views[1].profile
    return head, truth, views


def face_vertices(head) -> np.ndarray:
    """Skin vertices within 0.1 IOD of the face's 468 surface landmarks (the face, no skull)."""
    from scipy.spatial import cKDTree

    lm = head.landmarks()
    iod = np.linalg.norm(lm[33] - lm[263])
    skin = head.parts["skin"]
    d, _ = cKDTree(lm[:468]).query(head.mesh.vertices[skin])
    return skin[d < 0.1 * iod]


def error(head, w, truth) -> float:
    idx = face_vertices(head)
    got = head.identity(w)[idx]
    want = truth[idx]
    s, r, t = similarity(got, want)
    iod = np.linalg.norm(head.landmarks(truth)[33] - head.landmarks(truth)[263])
    return float(np.linalg.norm(s * got @ r.T + t - want, axis=1).mean() / iod)


def spoiled(views, moved: dict) -> list:
    """A copy of the views whose profile has the points ``moved`` (index -> pixel offset)."""
    import copy

    out = copy.deepcopy(views)
    for i, d in moved.items():
        out[1].points[i] = out[1].points[i] + d
    return out


def fit(head, views, guard: bool, monkeypatch):
    if not guard:
        monkeypatch.setattr(P, "PROFILE_OUTLIER", np.inf)
    try:
        rec = P.reconstruct(views, *P.prior_points(head))
        return rec, P.fit_identity(head, views, rec)
    finally:
        monkeypatch.undo()


def iod_pixels(head, views) -> float:
    rec = P.reconstruct(views[:1], *P.prior_points(head))
    return rec.cameras[0].scale * rec.iod


def test_a_good_profile_passes_the_guard_and_helps(person, monkeypatch):
    """Nothing of a clean profile is left out, and it brings the fit nearer the truth than the
    front view alone (the guard would be pointless if the profile did not count)."""
    head, truth, views = person
    rec, w = fit(head, views, True, monkeypatch)
    assert not any(rec.refused)
    rows, _ = P._observations(views[1], {n: 478 + k for k, n in enumerate(P.EXTRA_POINTS)})
    assert set(rows) == set(rec.observed[1])
    front_only = P.fit_identity(head, views[:1], P.reconstruct(views[:1], *P.prior_points(head)))
    assert error(head, w, truth) < error(head, front_only, truth)


def test_a_chin_found_on_the_neck_is_left_out(person, monkeypatch):
    head, truth, views = person
    down = np.array([0.0, OFF * iod_pixels(head, views)])  # pixels, y down
    bad = spoiled(views, {i: down for i in CHIN if i in views[1].points})
    guarded, w_guard = fit(head, bad, True, monkeypatch)
    unguarded, w_free = fit(head, bad, False, monkeypatch)
    # the guard drops exactly the moved points, and the profile still steers
    assert not guarded.refused[1]
    assert not set(CHIN) & set(guarded.observed[1])
    assert set(CHIN) <= set(unguarded.observed[1])
    assert len(set(unguarded.observed[1]) - set(guarded.observed[1])) == len(CHIN)
    e_guard, e_free = error(head, w_guard, truth), error(head, w_free, truth)
    assert e_guard < e_free, (e_guard, e_free)
    # and the guarded fit is as good as on the clean profile, within 10%
    _, w_clean = fit(head, views, True, monkeypatch)
    assert e_guard < 1.1 * error(head, w_clean, truth)


def test_a_profile_whose_points_are_all_off_is_set_aside(person, monkeypatch):
    head, truth, views = person
    rng = np.random.default_rng(3)
    step = OFF * iod_pixels(head, views)
    angles = rng.uniform(0, 2 * np.pi, 478)
    moved = {i: step * np.array([np.cos(angles[i]), np.sin(angles[i])]) for i in views[1].points}
    bad = spoiled(views, moved)
    guarded, w_guard = fit(head, bad, True, monkeypatch)
    unguarded, w_free = fit(head, bad, False, monkeypatch)
    assert guarded.refused[1] and not unguarded.refused[1]
    # a profile set aside steers nothing: the fit is the front view's alone
    front_only = P.fit_identity(head, views[:1], P.reconstruct(views[:1], *P.prior_points(head)))
    e_guard, e_free = error(head, w_guard, truth), error(head, w_free, truth)
    np.testing.assert_allclose(e_guard, error(head, front_only, truth), rtol=0.05)
    assert e_guard < e_free, (e_guard, e_free)
