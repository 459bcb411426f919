"""One registration for every face: the generic head's morphable model fitted to a Face, then
non-rigid ICP onto its surface, giving a dense correspondence both ways.

Every method that needs to know which point of a face is which point of the generic head (the
ARKit carry, the retargeting of a performance, the photo pipeline) asks the face for its
:class:`Registration` (``Face.registration``, built once per face). Three stages:

1. **Landmark fit.** A similarity ``x_face = s R x_head + t`` and the weights of the generic
   head's identity modes ``w`` (ICT FaceKit's 100 PCA modes, prior ``w ~ N(0, I)``) and of its
   expression shapes ``e`` (bounded to [0, 1], so a scan's smile is taken for a smile, not for
   its shape) fitted to the face's 468 face-mesh landmarks, with Huber weights (a contour point
   detected on an ear does not pull the head): with the rotation fixed, scale, weights and
   translation are one bounded linear least squares with the prior as extra rows
   (:func:`fit_landmarks`), then the rotation again (Umeyama), a few times.
2. **Model ICP.** The same linear fit with the closest points of a subset of the head's skin on
   the face's skin as data as well (pairs rejected by distance, by normals more than 60 degrees
   apart and on the face's boundary: holes, hair and clothes do not pull), then the similarity
   again, a few times: the head's shape is the person's, not ICT's, where the face has surface.
3. **Non-rigid ICP.** The skin of the fitted head moves onto the face's skin by a displacement
   per vertex: ``min sum_i c_i |x_i + d_i - p_i|^2 + alpha sum_edges |d_a - d_b|^2 + beta
   sum_l |B_l (x + d) - q_l|^2`` (closest points ``p_i`` with the same rejection, landmarks
   ``q_l`` on the head's surface ``B_l``), for a falling stiffness ``alpha`` (the optimal-step
   schedule of Amberg, Romdhani & Vetter 2007). Their method solves an affine map per vertex (12
   unknowns); after the morphable fit the remaining motion is small and smooth, so a
   displacement per vertex (3 unknowns, one sparse matrix for x, y and z, factorised once per
   closest-point round) does the same work a quarter as large. The off-skin parts (eyeballs, teeth, gums) keep
   the morphable fit, moved by the skin's displacement around them.

The correspondence from the face to the head (:func:`face_to_head`) projects each face vertex
onto the registered head, part by part: skin onto skin, each side of the mouth and eye slits
onto its own side, off-skin pieces (eyeballs, teeth, lashes) onto the piece they match.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.sparse as sp

from faceanim.errors import FaceAnimError, LandmarkError
from faceanim.face.frame import face_frame, similarity
from faceanim.face.generic_head import GenericHead, generic_head

# landmark fit
LANDMARK_SIGMA = 0.002  # metres on the generic head: a detected landmark's typical error
EXPRESSION_PRIOR = 25.0  # weight of |e|^2 against the identity prior |w|^2: a shape at 1 costs 5 sigma
IDENTITY_BOUND = 5.0  # no identity weight beyond 5 standard deviations
HUBER = 2.0  # landmarks further than this many median residuals count less
LANDMARK_ITERATIONS = 6
# model ICP
SURFACE_SAMPLES = 3000  # head skin vertices used as data in the model fit
SURFACE_SIGMA = 0.002  # metres on the generic head
MODEL_ITERATIONS = (0.35, 0.2, 0.12)  # rejection distance per iteration, inter-ocular distances
NORMAL_COS = 0.5  # pairs whose normals are more than 60 degrees apart are rejected
# non-rigid ICP: (stiffness alpha, landmark weight beta, rejection distance in IODs) per step
NICP_STEPS = ((50.0, 10.0, 0.12), (20.0, 5.0, 0.1), (8.0, 2.0, 0.08), (3.0, 1.0, 0.06), (1.5, 0.5, 0.05))
FACE_POINTS = np.arange(468)  # MediaPipe's face-mesh points (the 10 iris points lie on the eyeballs)
# a face's landmarks must fit the morphable head (stage 1): RMS residual in the generic head's
# inter-ocular distances, and the identity weights' root mean square. Measured on real faces: the
# default face 0.035 / 0.84, FaceWarehouse's 20 scans 0.028-0.099 / 1.03-1.56 (the open mouths
# fit worst), 12 remeshed ICT identities drawn at 1 and 2 standard deviations 0.034-0.066 /
# 0.84-1.56, VRoid's anime face 0.059 / 2.06; a torus 0.18 / 4.03
MAX_LANDMARK_ERROR = 0.15
MAX_IDENTITY_RMS = 3.0
# and it must have depth: the nose tip in front of the face oval's mean, in inter-ocular distances.
# Measured: the generic head 0.76, the default face 0.74, FaceWarehouse 0.60-0.65, VRoid's anime
# face 0.33; the generic head's landmarks squashed to a fifth of their depth 0.15, a plane's 0
MIN_FACE_DEPTH = 0.2
# and a nose: its tip in front of the cheeks (MediaPipe 205, 425), in inter-ocular distances.
# Measured: the default face 0.41, ICT's head 0.36, FaceWarehouse 0.24-0.29, VRoid's anime face
# 0.21; a face's pattern of landmarks cast onto a sphere or a capsule (a detector fooled by a
# shaded ball) 0.05, whose depth to the outline passes MIN_FACE_DEPTH
MIN_NOSE_RELIEF = 0.12
CHEEKS = (205, 425)


@dataclass(eq=False)
class Registration:
    """The generic head fitted to one face.

    Attributes
    ----------
    scale, rotation, translation : the similarity ``x_face = scale * rotation @ x_head + translation``
    identity : (K,) identity weights (standard deviations of ICT's modes)
    expression : (E,) weights of the head's expression shapes (``head.shape_names`` order)
    model : (Vh, 3) the morphable fit (identity + expression) in the face's mesh space
    vertices : (Vh, 3) the registered head in the face's mesh space: ``model`` moved onto the
        face's surface by non-rigid ICP (equal to ``model`` without it)
    landmark_error : RMS distance of the face's landmarks from the fitted head's, in the face's
        inter-ocular distances (after the landmark fit, before the surface is used)
    surface_error : RMS distance of the registered skin from the face's skin over the accepted
        pairs, in inter-ocular distances (0 for a face made from the generic head)
    coverage : share of the head's face points that found the face's surface within the last
        rejection distance
    """

    head: GenericHead
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    identity: np.ndarray
    expression: np.ndarray
    model: np.ndarray
    vertices: np.ndarray
    landmark_error: float
    surface_error: float
    coverage: float

    @property
    def identity_neutral(self) -> np.ndarray:
        """(Vh, 3) the fitted person's neutral head (no expression) in the generic head's space."""
        return self.head.identity(self.identity)

    @property
    def size_scale(self) -> float:
        """The face's size against the generic head's: the similarity's scale times the fitted
        identity's landmark spread over the generic head's. A bigger fitted head with a smaller
        scale and a smaller one with a larger scale fit the same landmarks equally well; this
        product is the same for both."""
        lm0 = self.head.landmarks()[FACE_POINTS]
        lm1 = self.head.landmarks(self.identity_neutral)[FACE_POINTS]
        spread = float(np.sqrt(np.sum((lm1 - lm1.mean(0)) ** 2) / np.sum((lm0 - lm0.mean(0)) ** 2)))
        return self.scale * spread


# faceanim's own tongueOut is no measured expression: it opens the mouth by a share of jawOpen
# (the fit would split an open mouth between the two) and puts out a tongue no landmark sees
NOT_FITTED = ("tongueOut",)


def _basis(head: GenericHead, rows: np.ndarray | None = None, matrix: sp.spmatrix | None = None):
    """The morphable model at some points: (mean (N, 3), basis (N, 3, K + E)) with identity modes
    first, then expression shapes; at vertices ``rows`` or at ``matrix @ vertices``. The shapes
    of :data:`NOT_FITTED` have zero columns (their weight stays 0)."""
    ident = head.identity_basis()  # (K, V, 3)
    names = head.shape_names

    def shape(n: str) -> np.ndarray:
        return np.zeros_like(head.mesh.vertices) if n in NOT_FITTED else head.shape(n)
    if matrix is not None:
        cols = np.unique(matrix.indices)
        m = matrix[:, cols]
        mean = m @ head.mesh.vertices[cols]
        ib = np.stack([m @ ident[k, cols].astype(np.float64) for k in range(len(ident))], axis=-1)
        eb = np.stack([m @ shape(n)[cols] for n in names], axis=-1)
    else:
        mean = head.mesh.vertices[rows]
        ib = np.moveaxis(ident[:, rows].astype(np.float64), 0, -1)
        eb = np.stack([shape(n)[rows] for n in names], axis=-1)
    return mean, np.concatenate([ib, eb], axis=-1)


@lru_cache(maxsize=2)
def _landmark_model(head: GenericHead):
    """:func:`_basis` at the head's face-mesh landmarks (computed once per head; read-only)."""
    out = _basis(head, matrix=head.landmark_matrix()[FACE_POINTS])
    for a in out:
        a.setflags(write=False)
    return out


@lru_cache(maxsize=2)
def _skin_model(head: GenericHead):
    """(rows, mean, basis): :func:`_basis` at :data:`SURFACE_SAMPLES` of the head's skin vertices,
    evenly spread (computed once per head; read-only)."""
    skin = head.parts["skin"]
    rows = skin[:: max(1, len(skin) // SURFACE_SAMPLES)]
    out = (rows, *_basis(head, rows))
    for a in out:
        a.setflags(write=False)
    return out


def _solve_weights(blocks, n_identity: int, n_expression: int) -> np.ndarray:
    """Weights (K + E,) minimising ``sum over blocks of |sqrt(c) (mean + basis x - target)|^2 /
    sigma^2 + |w|^2 + mu |e|^2``, ``w`` within +-:data:`IDENTITY_BOUND`, ``e`` in [0, 1]. Each
    block: (mean (N, 3), basis (N, 3, P), target (N, 3), weights c (N,), sigma)."""
    from scipy.linalg import cho_factor, solve_triangular
    from scipy.optimize import lsq_linear

    a_rows, b_rows = [], []
    for mean, basis, target, c, sigma in blocks:
        sw = np.sqrt(np.asarray(c, dtype=np.float64))[:, None, None] / sigma
        a_rows.append((basis * sw).reshape(-1, basis.shape[-1]))
        b_rows.append(((target - mean) * sw[..., 0]).ravel())
    # the same problem on a (P, P) triangle: the solver's work no longer grows with the number of
    # points. The normal equations' Cholesky factor (the prior keeps them well conditioned) costs
    # 0.01 s where a QR factorisation of the 10,000 x 154 rows took 0.25-0.35 s
    gram = sum(a.T @ a for a in a_rows)
    gram[np.diag_indices_from(gram)] += np.concatenate([np.ones(n_identity), np.full(n_expression, EXPRESSION_PRIOR)])
    a = np.triu(cho_factor(gram, lower=False)[0])
    b = solve_triangular(a, sum(ar.T @ br for ar, br in zip(a_rows, b_rows)), trans="T")
    lo = np.concatenate([np.full(n_identity, -IDENTITY_BOUND), np.zeros(n_expression)])
    hi = np.concatenate([np.full(n_identity, IDENTITY_BOUND), np.ones(n_expression)])
    return lsq_linear(a, b, bounds=(lo, hi), method="bvls" if a.shape[1] < 200 else "trf").x


def _huber(residual: np.ndarray) -> np.ndarray:
    k = HUBER * max(float(np.median(residual)), 1e-12)
    return np.minimum(1.0, k / np.maximum(residual, 1e-300))


class _Surface:
    """The face's skin as closest-point targets, with triangle normals and boundary flags."""

    def __init__(self, face):
        mesh = face.mesh
        skin = np.asarray(face.skin, dtype=bool)
        self.mesh = mesh
        self.triangles = np.flatnonzero(skin[mesh.faces].all(axis=1))
        if len(self.triangles) == 0:
            from faceanim.errors import shown

            raise LandmarkError(f"no face found in '{shown(mesh.name, tail=True)}': its landmarks lie on no skin surface")
        v, f = mesh.vertices, mesh.faces
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        self.normals = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        # boundary: edges used by one triangle (of the skin); a triangle touching one is rim
        ft = f[self.triangles]
        e = np.sort(np.concatenate([ft[:, [0, 1]], ft[:, [1, 2]], ft[:, [2, 0]]]), axis=1)
        uniq, count = np.unique(e, axis=0, return_counts=True)
        rim_v = np.zeros(mesh.n_vertices, bool)
        rim_v[uniq[count == 1].ravel()] = True
        self.rim = rim_v[f].any(axis=1)
        # libigl's AABB tree over the skin (trimesh's rtree search is 50x slower here)
        import igl

        self._v = np.ascontiguousarray(v, dtype=np.float64)
        self._f = np.ascontiguousarray(f[self.triangles], dtype=np.int64)
        self._tree = igl.AABB()
        self._tree.init(self._v, self._f)

    def pairs(self, points: np.ndarray, normals: np.ndarray, limit: float):
        """Closest skin points of ``points``: (positions, accepted (N,) bool, distances)."""
        d2, local, pos = self._tree.squared_distance(self._v, self._f, np.ascontiguousarray(points, dtype=np.float64))
        tri = self.triangles[np.asarray(local)]
        dist = np.sqrt(np.maximum(np.asarray(d2), 0.0))
        pos = np.asarray(pos)
        ok = (dist < limit) & ~self.rim[tri] & (np.sum(normals * self.normals[tri], axis=1) > NORMAL_COS)
        return pos, ok, dist


def _normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    from faceanim.face.mesh import vertex_normals

    return vertex_normals(vertices, faces)


def _same_topology(face, head: GenericHead) -> Registration:
    """A face made from the generic head (the default face, ``faceanim photo``): the head is the
    face vertex for vertex; the similarity and identity are fitted to all its vertices."""
    mesh = face.mesh
    rows, mean, basis = _skin_model(head)
    k, e = head.n_identity, len(head.shape_names)
    x = np.zeros(k + e)
    target = mesh.vertices[rows]
    for _ in range(3):
        cur = mean + basis @ x
        s, r, t = similarity(cur, target)
        x = _solve_weights([(mean, basis, (target - t) @ r / s, np.ones(len(rows)), SURFACE_SIGMA)], k, e)
    cur = mean + basis @ x
    s, r, t = similarity(cur, target)
    model = s * _model_vertices(head, x) @ r.T + t
    iod = face.frame.iod
    lm = head.landmarks(model)
    lm_err = float(np.sqrt(np.mean(np.sum((lm - face.landmarks) ** 2, axis=1)))) / iod
    return Registration(head, s, r, t, x[:k], x[k:], model, mesh.vertices.copy(), lm_err, 0.0, 1.0)


def _model_vertices(head: GenericHead, x: np.ndarray) -> np.ndarray:
    k = head.n_identity
    out = head.identity(x[:k])
    for j in np.flatnonzero(x[k:] > 1e-6):
        rows, delta = head.sparse_shape(head.shape_names[j])
        out[rows] += x[k + j] * delta
    return out


def fit_landmarks(landmarks: np.ndarray, head: GenericHead | None = None):
    """Stage 1 alone: (s, R, t, weights (K + E,), RMS landmark residual in the head's metres)
    fitting the head's model to 478 landmark positions.

    With the rotation fixed, ``R^T p = s (mean + B x) + R^T t`` is linear in ``(s, y = s x, R^T
    t)``: scale, weights and translation are solved together (alternating the scale with the
    weights crawls along the valley where a bigger head trades for a smaller scale), then the
    rotation again (Umeyama), a few times."""
    from scipy.optimize import lsq_linear

    head = head or generic_head()
    p = np.asarray(landmarks, dtype=np.float64)[FACE_POINTS]
    mean, basis = _landmark_model(head)
    k, e = head.n_identity, len(head.shape_names)
    n = len(p)
    x = np.zeros(k + e)
    c = np.ones(n)
    s, r, t = similarity(mean, p, weights=c)
    eye = np.tile(np.eye(3), (n, 1))
    for _ in range(LANDMARK_ITERATIONS):
        q = p @ r  # R^T p, row by row
        sw = np.repeat(np.sqrt(c), 3) / (s * LANDMARK_SIGMA)
        a = np.column_stack([mean.reshape(-1), basis.reshape(-1, k + e), eye]) * sw[:, None]
        prior = np.zeros((k + e, 1 + k + e + 3))
        prior[:, 1:1 + k + e] = np.diag(np.r_[np.ones(k), np.full(e, np.sqrt(EXPRESSION_PRIOR))]) / s
        qa, ra = np.linalg.qr(np.vstack([a, prior]))
        rhs = qa.T @ np.r_[q.reshape(-1) * sw, np.zeros(k + e)]
        lo = np.r_[1e-3 * s, np.full(k, -IDENTITY_BOUND * s), np.zeros(e), np.full(3, -np.inf)]
        hi = np.r_[np.inf, np.full(k, IDENTITY_BOUND * s), np.full(e, s), np.full(3, np.inf)]
        u = lsq_linear(ra, rhs, bounds=(lo, hi), method="bvls").x
        x = u[1:1 + k + e] / u[0]
        cur = mean + basis @ x
        s, r, t = similarity(cur, p, weights=c)
        c = _huber(np.linalg.norm(cur - (p - t) @ r / s, axis=1))
    cur = mean + basis @ x
    res = np.linalg.norm(cur - (p - t) @ r / s, axis=1)
    return s, r, t, x, float(np.sqrt(np.mean(res ** 2)))


def check_face(face, head: GenericHead | None = None) -> None:
    """Refuse landmarks that do not look like a face's: flat (:data:`MIN_FACE_DEPTH`), without a
    nose (:data:`MIN_NOSE_RELIEF`: a face's pattern on a ball), or after
    stage 1 the residual or the identity weights outside the bounds measured on real faces
    (:data:`MAX_LANDMARK_ERROR`, :data:`MAX_IDENTITY_RMS`). Raises :class:`LandmarkError` ("no
    face found in ...")."""
    head = head or generic_head()
    if head.landmarks_on(face.mesh) is not None:
        return
    from faceanim.errors import shown
    from faceanim.face.landmarks import FACE_OVAL, NOSE_TIP

    name = shown(face.name, tail=True)
    local = face.frame.to_local(face.landmarks)
    depth = float(local[NOSE_TIP, 2] - local[list(FACE_OVAL), 2].mean()) / face.frame.iod
    if depth < MIN_FACE_DEPTH:
        raise LandmarkError(f"no face found in '{name}': its landmarks are flat (the nose {depth:.2f} inter-ocular "
                            f"distances in front of the face's outline; faces have at least {MIN_FACE_DEPTH}); "
                            "if it is a face, give its landmarks with --landmarks")
    relief = float(local[NOSE_TIP, 2] - local[list(CHEEKS), 2].mean()) / face.frame.iod
    if relief < MIN_NOSE_RELIEF:
        raise LandmarkError(f"no face found in '{name}': its landmarks have no nose (the tip {relief:.2f} inter-ocular "
                            f"distances in front of the cheeks; faces have at least {MIN_NOSE_RELIEF}); if it is a "
                            "face, give its landmarks with --landmarks")
    _, _, _, x, res = face.landmark_fit
    err = res / face_frame(head.landmarks()).iod
    spread = float(np.sqrt(np.mean(x[:head.n_identity] ** 2)))
    if err > MAX_LANDMARK_ERROR or spread > MAX_IDENTITY_RMS:
        raise LandmarkError(
            f"no face found in '{name}': its landmarks do not fit a head (residual {err:.2f} inter-ocular "
            f"distances, identity {spread:.1f} standard deviations; faces stay under {MAX_LANDMARK_ERROR} and "
            f"{MAX_IDENTITY_RMS}); if it is a face, give its landmarks with --landmarks")


def register(face, head: GenericHead | None = None, nicp: bool = True) -> Registration:
    """The generic head registered to ``face`` (the module docstring's three stages)."""
    from faceanim.deform.base import one_blas_thread

    head = head or generic_head()
    with one_blas_thread():  # also the same result whatever the machine's threads
        if head.landmarks_on(face.mesh) is not None:
            return _same_topology(face, head)
        return _register(face, head, nicp)


def _register(face, head: GenericHead, nicp: bool) -> Registration:
    iod = face.frame.iod
    k, e = head.n_identity, len(head.shape_names)
    s, r, t, x, lm_res = face.landmark_fit if head is generic_head() else fit_landmarks(face.landmarks, head)
    lm_err = lm_res * s / iod
    # stage 2: model ICP on a subset of the head's skin
    surface = _Surface(face)
    rows, d_mean, d_basis = _skin_model(head)
    l_mean, l_basis = _landmark_model(head)
    p = face.landmarks[FACE_POINTS]
    c_lm = np.ones(len(p))
    for limit in MODEL_ITERATIONS:
        model = _model_vertices(head, x)
        normals = _normals(model, head.mesh.faces)[rows] @ r.T
        pos, ok, _ = surface.pairs(s * model[rows] @ r.T + t, normals, limit * iod)
        if ok.sum() >= 50:
            # the similarity from landmarks and accepted pairs together
            src = np.vstack([l_mean + l_basis @ x, (d_mean + d_basis @ x)[ok]])
            dst = np.vstack([p, pos[ok]])
            s, r, t = similarity(src, dst, weights=np.concatenate([c_lm, np.full(ok.sum(), 0.25)]))
        blocks = [(l_mean, l_basis, (p - t) @ r / s, c_lm, LANDMARK_SIGMA)]
        if ok.any():
            blocks.append((d_mean[ok], d_basis[ok], (pos[ok] - t) @ r / s, np.full(ok.sum(), 0.25),
                           SURFACE_SIGMA))
        x = _solve_weights(blocks, k, e)
    model = s * _model_vertices(head, x) @ r.T + t
    vertices, surf_err, coverage = (_nicp(face, head, model, surface) if nicp else (model.copy(), np.nan, np.nan))
    return Registration(head, s, r, t, x[:k], x[k:], model, vertices, lm_err, surf_err, coverage)


def _nicp(face, head: GenericHead, model: np.ndarray, surface: _Surface):
    """Stage 3: the skin of ``model`` (face space) moved onto the face's skin; the off-skin parts
    follow the skin's displacement around them. Returns (vertices, RMS error, coverage)."""
    from scipy.sparse.linalg import splu
    from scipy.spatial import cKDTree

    iod = face.frame.iod
    skin = head.parts["skin"]
    n = len(skin)
    local = np.full(head.mesh.n_vertices, -1)
    local[skin] = np.arange(n)
    edges = head.mesh.edges
    edges = edges[(local[edges] >= 0).all(axis=1)]
    m = len(edges)
    g = sp.csr_matrix((np.r_[np.ones(m), -np.ones(m)], (np.r_[np.arange(m), np.arange(m)],
                                                        np.r_[local[edges[:, 0]], local[edges[:, 1]]])), shape=(m, n))
    gtg = (g.T @ g).tocsc()
    l_mat = head.landmark_matrix()[FACE_POINTS][:, skin].tocsr()
    btb = (l_mat.T @ l_mat).tocsc()
    p = face.landmarks[FACE_POINTS]
    x0 = model[skin]
    skin_faces = head.mesh.faces[(local[head.mesh.faces] >= 0).all(axis=1)]
    faces_local = local[skin_faces]
    # the head's face region: coverage is counted there
    face_rows = np.zeros(n, bool)
    face_rows[np.unique(local[head.mesh.faces[head.landmark_triangles[FACE_POINTS]]].ravel())] = True
    d = np.zeros((n, 3))
    ok = np.zeros(n, bool)
    dist = np.zeros(n)
    for alpha, beta, limit in NICP_STEPS:
        for _ in range(2):
            x = x0 + d
            normals = _normals(x, faces_local)
            pos, ok, dist = surface.pairs(x, normals, limit * iod)
            c = ok.astype(np.float64)
            a = sp.diags(c) + alpha * gtg + beta * btb
            rhs = c[:, None] * (pos - x0) + beta * (l_mat.T @ (p - l_mat @ x0))
            d = splu(a.tocsc()).solve(rhs)
    x = x0 + d
    normals = _normals(x, faces_local)
    pos, ok, dist = surface.pairs(x, normals, NICP_STEPS[-1][2] * iod)
    err = float(np.sqrt(np.mean(dist[ok] ** 2))) / iod if ok.any() else np.inf
    coverage = float(ok[face_rows].mean()) if face_rows.any() else 0.0
    out = model.copy()
    out[skin] = x
    # the off-skin parts move with the skin around them (inverse-distance weights, 8 nearest)
    other = np.setdiff1d(np.arange(head.mesh.n_vertices), skin)
    if len(other):
        dd, nn = cKDTree(model[skin]).query(model[other], k=8)
        w = 1.0 / np.maximum(dd, 1e-9 * iod) ** 2
        out[other] += np.einsum("nk,nkd->nd", w / w.sum(1, keepdims=True), d[nn])
    return out, err, coverage


# ---------------------------------------------------------------------------------------------
# the dense correspondence from a face to the generic head, through the registration

NEAR_SLIT = 0.75  # a vertex keeps to its side of a slit within this many slit widths of its centre
SLIT_NAMES = ("eye_L", "eye_R", "mouth")  # the columns of _sides
SHELL_MATCH = 0.05  # a face piece matches a head piece within this (IODs): centre distance + size difference
NEAR_EYE = 1.0  # an unmatched piece this near an eye (slit widths, centre to centre) rides on its lid...
ROUND = 0.2  # ...unless it is round (its points' distances from its centre vary less than this share)


def _sides(mesh, lm478: np.ndarray, skin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex: (sides (V, S) bool, True below slit s of :data:`SLIT_NAMES` (for what is not
    skin, below the mouth: the lower teeth; False for the eyes), near (V, S) bool, within
    :data:`NEAR_SLIT` slit widths of the slit's centre)."""
    from scipy.sparse.csgraph import connected_components

    from faceanim.face.landmarks import SLITS
    from faceanim.face.regions import slit_sides

    lm = np.asarray(lm478, dtype=np.float64)
    lower = slit_sides(mesh, lm)
    y = face_frame(lm).to_local(mesh.vertices)[:, 1]
    mouth_y = face_frame(lm).to_local(lm[list(SLITS["mouth"]["corners"])])[:, 1].mean()
    # what is not skin goes by whole shells (a lower tooth row whose crowns rise above the lips'
    # line is still lower): each connected piece by its mean height
    f = mesh.faces
    keep = ~skin[f].any(axis=1)
    rows = np.concatenate([f[keep, 0], f[keep, 1], f[keep, 2]])
    cols = np.concatenate([f[keep, 1], f[keep, 2], f[keep, 0]])
    n = mesh.n_vertices
    _, piece = connected_components(sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)), directed=False)
    piece_y = np.bincount(piece, weights=y, minlength=piece.max() + 1) / np.bincount(piece, minlength=piece.max() + 1)
    below_mouth = piece_y[piece] < mouth_y
    sides = np.zeros((mesh.n_vertices, len(SLIT_NAMES)), bool)
    near = np.zeros_like(sides)
    for k, name in enumerate(SLIT_NAMES):
        c = lm[list(SLITS[name]["corners"])]
        width = float(np.linalg.norm(c[1] - c[0]))
        sides[:, k] = np.where(skin, np.asarray(lower[name], dtype=bool), below_mouth & (name == "mouth"))
        near[:, k] = np.linalg.norm(mesh.vertices - c.mean(axis=0), axis=1) < NEAR_SLIT * width
    return sides, near


def _closest_on(vertices: np.ndarray, tris: np.ndarray, points: np.ndarray):
    """Closest points of ``points`` on the triangles ``tris`` (T, 3) of ``vertices``:
    (triangle index into tris, barycentric (N, 3)); libigl's AABB tree."""
    import igl
    import trimesh

    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(tris, dtype=np.int64)
    _, tri, closest = igl.point_mesh_squared_distance(np.ascontiguousarray(points, dtype=np.float64), v, f)
    tri = np.asarray(tri, dtype=np.int64)
    bary = trimesh.triangles.points_to_barycentric(v[f[tri]], np.asarray(closest))
    bary = np.clip(np.nan_to_num(bary, nan=1.0 / 3), 0.0, None)
    return tri, bary / np.maximum(bary.sum(axis=1, keepdims=True), 1e-12)


def _vertex_for_vertex(head: GenericHead) -> tuple[np.ndarray, np.ndarray]:
    src = head.mesh
    first = np.full(src.n_vertices, -1, dtype=np.int64)
    corner = np.full(src.n_vertices, -1, dtype=np.int64)
    for c in range(3):  # any triangle that has the vertex, with its corner
        unset = first[src.faces[:, c]] < 0
        first[src.faces[unset, c]] = np.flatnonzero(unset)
        corner[src.faces[unset, c]] = c
    if (first < 0).any():
        raise FaceAnimError("the generic head has vertices outside every triangle")
    bary = np.zeros((src.n_vertices, 3))
    bary[np.arange(src.n_vertices), corner] = 1.0
    return first, bary


def face_to_head(face, registration: Registration | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The dense correspondence from ``face`` to the generic head: per face vertex, the head
    triangle (rows of ``head.mesh.faces``) and barycentric coordinates of its point.

    Each face vertex is projected onto the registered head (:attr:`Registration.vertices`, in
    the face's own space) part by part: skin onto skin, near a slit each side onto its own side
    (a lower lip or lid onto a lower one), what is not skin onto what is not skin (the lower
    teeth onto the lower ones), a separate piece (eyeballs, a tooth row, eyelashes) onto the
    piece of the head it matches by place and size; a piece the head lacks that sits at an eye
    and is not round (eyelashes, a tear line) rides on its lid. A face made from the generic head
    corresponds vertex for vertex."""
    reg = registration or face.registration
    head = reg.head
    src = head.mesh
    if head.landmarks_on(face.mesh) is not None:
        return _vertex_for_vertex(head)
    src_v = reg.vertices
    points = face.mesh.vertices
    src_skin = np.zeros(src.n_vertices, bool)
    src_skin[head.parts["skin"]] = True
    tgt_skin = np.asarray(face.skin, dtype=bool)
    src_sides, _ = _head_sides(head)
    tgt_sides, tgt_near = _sides(face.mesh, face.landmarks, tgt_skin)
    # a head triangle's kind: skin or not, and its side of each slit (all three corners agree)
    t_skin = src_skin[src.faces].all(axis=1)
    t_other = (~src_skin[src.faces]).all(axis=1)
    t_side = src_sides[src.faces]  # (T, 3, S)
    t_lower, t_upper = t_side.all(axis=1), (~t_side).all(axis=1)
    # each face vertex's constraint: skin or not; below (1) / above (2) / free (0) per slit
    near = tgt_near | ~tgt_skin[:, None]  # what is not skin keeps to its side of the mouth always
    key = np.where(near, np.where(tgt_sides, 1, 2), 0)
    eyes = [k for k, name in enumerate(SLIT_NAMES) if name != "mouth"]
    key[np.ix_(~tgt_skin, eyes)] = 0  # (the eyes' sides mean nothing off the skin)
    key = np.column_stack([tgt_skin, key])
    uniq, group = np.unique(key, axis=0, return_inverse=True)
    tri = np.empty(face.mesh.n_vertices, dtype=np.int64)
    bary = np.empty((face.mesh.n_vertices, 3))
    for g, k in enumerate(uniq):
        ok = t_skin.copy() if k[0] else t_other.copy()
        for s, want in enumerate(k[1:]):
            if want == 1:
                ok &= t_lower[:, s]
            elif want == 2:
                ok &= t_upper[:, s]
        pool = np.flatnonzero(ok)
        if len(pool) == 0:  # no such side on the generic head: the whole surface
            pool = np.arange(len(src.faces))
        mine = np.flatnonzero(group.ravel() == g)
        t, b = _closest_on(src_v, src.faces[pool], points[mine])
        tri[mine], bary[mine] = pool[t], b
    # a separate piece onto its own piece: the closest point alone lands an eyelash on the eyeball
    # just under it, which does not blink
    from faceanim.face.landmarks import SLITS

    src_lm = head.landmarks(src_v)
    iod = face.frame.iod
    matched, unmatched = _matching_shells(face.mesh, points, ~tgt_skin, src, src_v, ~src_skin, SHELL_MATCH * iod)
    for mine, pool in matched:
        t, b = _closest_on(src_v, src.faces[pool], points[mine])
        tri[mine], bary[mine] = pool[t], b
    # a piece the head has no counterpart for, at an eye and not round (eyelashes, a tear line):
    # it rides on its lid, the skin on its side of the slit, as it is fixed to it
    up = face.frame.rotation[1]
    for mine in unmatched:
        centre = points[mine].mean(0)
        for k, name in enumerate(SLIT_NAMES):
            if name == "mouth":
                continue
            corners = src_lm[list(SLITS[name]["corners"])]
            width = float(np.linalg.norm(corners[1] - corners[0]))
            d = np.linalg.norm(points[mine] - centre, axis=1)
            round_ = d.std() < ROUND * d.mean()
            if np.linalg.norm(centre - corners.mean(0)) > NEAR_EYE * width or round_:
                continue
            upper = (centre - corners.mean(0)) @ up > 0
            pool = np.flatnonzero(t_skin & (t_upper[:, k] if upper else t_lower[:, k]))
            if len(pool):
                t, b = _closest_on(src_v, src.faces[pool], points[mine])
                tri[mine], bary[mine] = pool[t], b
            break
    return tri, bary


@lru_cache(maxsize=2)
def _head_sides(head: GenericHead):
    """:func:`_sides` of the generic head (its slits' sides follow its topology: computed once)."""
    skin = np.zeros(head.mesh.n_vertices, bool)
    skin[head.parts["skin"]] = True
    return _sides(head.mesh, head.landmarks(), skin)


def _shells(mesh, vertices: np.ndarray, off_skin: np.ndarray):
    """The connected pieces made only of off-skin triangles: (triangles per piece, vertices per
    piece, centre (P, 3), RMS radius (P,)) with ``vertices`` as the positions."""
    from scipy.sparse.csgraph import connected_components

    f = mesh.faces
    keep = np.flatnonzero(off_skin[f].all(axis=1))
    n = mesh.n_vertices
    rows = np.concatenate([f[keep, 0], f[keep, 1]])
    cols = np.concatenate([f[keep, 1], f[keep, 2]])
    _, label = connected_components(sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)), directed=False)
    tri_label = label[f[keep, 0]]
    pieces = np.unique(tri_label)
    tris = [keep[tri_label == p] for p in pieces]
    verts = [np.unique(f[t]) for t in tris]
    centre = np.array([vertices[v].mean(0) for v in verts]).reshape(-1, 3)
    radius = np.array([np.sqrt(np.mean(np.sum((vertices[v] - c) ** 2, axis=1))) for v, c in zip(verts, centre)])
    return tris, verts, centre, radius


def _matching_shells(target, points: np.ndarray, tgt_off: np.ndarray, src, src_v: np.ndarray,
                     src_off: np.ndarray, tolerance: float):
    """The face's pieces off the skin matched to the registered head's: (pairs (face vertices,
    head triangles) for each piece whose centre distance plus size difference to one head piece
    is under ``tolerance`` (many face pieces may match one head piece), the vertices of each
    piece that matches none)."""
    _, t_verts, t_centre, t_radius = _shells(target, points, tgt_off)
    s_tris, _, s_centre, s_radius = _shells(src, src_v, src_off)
    if not len(t_verts) or not len(s_tris):
        return [], list(t_verts)
    score = np.linalg.norm(t_centre[:, None] - s_centre[None], axis=2) + np.abs(t_radius[:, None] - s_radius[None])
    best = np.argmin(score, axis=1)
    ok = score[np.arange(len(t_verts)), best] < tolerance
    return ([(t_verts[k], s_tris[best[k]]) for k in np.flatnonzero(ok)],
            [t_verts[k] for k in np.flatnonzero(~ok)])

