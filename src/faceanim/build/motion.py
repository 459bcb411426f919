"""Facial motion capture from recorded ARKit takes (Chai, Xiao & Hodgins 2003, section 3): markers.

The paper records 76 reflective markers on a real face. We have real facial motion as ARKit
curves (Live Link Face takes, :mod:`faceanim.io.arkit_csv`) and a head that has all of ARKit's
shapes (the generic head, ICT FaceKit): playing a take on the head and reading the positions of
76 marker vertices spread over its face gives marker trajectories driven by real motion, which the
rest of the paper's pipeline takes like real markers.

- :func:`marker_vertices`: the paper's 19 tracked features (so that the control parameters of
  the video analysis can be read off the markers) and more skin vertices of the face chosen by
  farthest-point sampling, 76 in all, deterministic.
- :func:`play_take`: (F, 76, 3) marker positions of a take on the head: rest + the ICT shapes
  weighted by the curves, turned by the recorded (or a given) head rotation about the head's pivot.
- :func:`factorise` (section 3.1): head pose separated from expression by the rank-3L
  factorisation; :func:`stable_registration`: the same by rigid registration weighted towards the
  stillest markers, which recovers the pose four to seven times more accurately on the real take
  (the database's default); :func:`marker_controls`: the 15 control parameters of every frame;
  :func:`deformation_bases`: the L bases that carry the motion to other faces (section 5);
  :func:`build_database` / :class:`MotionDatabase`: all of it in one file (its format is in the
  class docstring).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from faceanim.errors import FaceAnimError
from faceanim.face.controls import FEATURE_NAMES, FEATURES
from faceanim.face.generic_head import GenericHead
from faceanim.face.regions import face_region

N_MARKERS = 76  # as the paper's motion capture
# the 19 features of the video analysis, as MediaPipe landmarks, in their order
FEATURE_LANDMARKS = tuple(FEATURES[n] for n in FEATURE_NAMES)


def marker_vertices(head: GenericHead, n: int = N_MARKERS) -> np.ndarray:
    """(n,) skin vertices of the head's face used as motion capture markers: the vertices at the
    19 tracked features first, then farthest-point samples of the face region."""
    if not len(FEATURE_LANDMARKS) <= n <= 2000:
        raise FaceAnimError(f"markers: give {len(FEATURE_LANDMARKS)} to 2000, got {n}")
    mesh = head.mesh
    lm = head.landmarks()
    skin = np.zeros(mesh.n_vertices, bool)
    skin[head.parts["skin"]] = True
    region = face_region(mesh, lm) & skin
    cand = np.flatnonzero(region)
    chosen = []
    for i in FEATURE_LANDMARKS:
        corners = mesh.faces[head.landmark_triangles[i]]
        chosen.append(int(corners[np.argmax(head.landmark_barycentric[i])]))
    chosen = list(dict.fromkeys(chosen))  # in order, no repeats
    d = np.min(np.linalg.norm(mesh.vertices[cand][:, None] - mesh.vertices[chosen][None], axis=2), axis=1)
    while len(chosen) < n:
        k = int(np.argmax(d))
        chosen.append(int(cand[k]))
        d = np.minimum(d, np.linalg.norm(mesh.vertices[cand] - mesh.vertices[cand[k]], axis=1))
    return np.array(chosen, dtype=np.int64)


def head_rotation(yaw, pitch, roll) -> np.ndarray:
    """(F, 3, 3) head rotations Ry(yaw) Rx(pitch) Rz(roll) (radians; head coordinates: x the
    head's left, y up, z forward): yaw turns the head to its own left, pitch nods it down, roll
    tilts it to its right (the video analysis uses the same angles)."""
    yaw, pitch, roll = (np.atleast_1d(np.asarray(a, dtype=np.float64)) for a in (yaw, pitch, roll))
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    z, o = np.zeros_like(yaw), np.ones_like(yaw)
    ry = np.stack([np.stack([cy, z, sy], -1), np.stack([z, o, z], -1), np.stack([-sy, z, cy], -1)], -2)
    rx = np.stack([np.stack([o, z, z], -1), np.stack([z, cp, -sp], -1), np.stack([z, sp, cp], -1)], -2)
    rz = np.stack([np.stack([cr, -sr, z], -1), np.stack([sr, cr, z], -1), np.stack([z, z, o], -1)], -2)
    return ry @ rx @ rz


def play_take(head: GenericHead, names: list[str], curves: np.ndarray, markers: np.ndarray,
              rotation: np.ndarray | None = None, pivot: np.ndarray | None = None) -> np.ndarray:
    """(F, P, 3) marker positions: the head's rest + sum of its shapes ``names`` weighted by
    ``curves`` (F, C), then turned by ``rotation`` (F, 3, 3) about ``pivot`` (default: the
    midpoint between the ears at the eyes' height, behind the face)."""
    curves = np.asarray(curves, dtype=np.float64)
    unknown = [n for n in names if n not in head.shape_names]
    if unknown:
        raise FaceAnimError(f"the head has no shape {unknown[0]}; its shapes are ARKit's (ICT names)")
    if curves.ndim != 2 or curves.shape[1] != len(names) or not np.all(np.isfinite(curves)):
        raise FaceAnimError(f"curves must be finite (frames, {len(names)}), got shape {curves.shape}")
    rest = head.mesh.vertices[markers]
    basis = np.stack([head.shape(n)[markers] for n in names])  # (C, P, 3)
    pos = rest[None] + np.einsum("fc,cpd->fpd", curves, basis)
    if rotation is not None:
        if pivot is None:
            lm = head.landmarks()
            pivot = np.array([0.0, lm[[33, 263], 1].mean(), head.mesh.vertices[head.parts["skin"], 2].mean()])
        pos = np.einsum("fij,fpj->fpi", rotation, pos - pivot) + pivot
    return pos


# ---------------------------------------------------------------------------------------- section 3.1
def _polar(a: np.ndarray) -> np.ndarray:
    """The rotation nearest a 3 x 3 matrix (its polar factor, det +1)."""
    u, _, vt = np.linalg.svd(a)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    return r


class Factorisation:
    """Head pose separated from expression (section 3.1): marker frames ``X_f = R_f (sum_k
    c_fk S_k) + T_f``. ``rotations`` (F, 3, 3), ``translations`` (F, 3), ``coefficients`` (F, L),
    ``bases`` (L, 3, P) (the shapes of the ``basis_frames`` with their pose taken out), ``energy``
    the fraction of the data's energy the rank 3L keeps. ``expression`` (F, P, 3) is the motion
    with the head pose removed."""

    def __init__(self, rotations, translations, coefficients, bases, basis_frames, energy):
        self.rotations, self.translations = rotations, translations
        self.coefficients, self.bases = coefficients, bases
        self.basis_frames, self.energy = basis_frames, energy

    @property
    def n_bases(self) -> int:
        return len(self.bases)

    @property
    def expression(self) -> np.ndarray:
        return np.einsum("fk,kdp->fpd", self.coefficients, self.bases)


def _sym_rows(qa: np.ndarray, qb: np.ndarray, iu: tuple) -> np.ndarray:
    """Rows of the linear map N -> qa^T N qb over the upper triangle of a symmetric N (qa, qb:
    (n, 3L) stacks of vectors)."""
    outer = qa[:, :, None] * qb[:, None, :]  # (n, 3L, 3L)
    sym = outer + np.transpose(outer, (0, 2, 1))
    d = np.arange(qa.shape[1])
    sym[:, d, d] = outer[:, d, d]
    return sym[:, iu[0], iu[1]]


def factorise(markers: np.ndarray, energy: float = 0.996, max_bases: int = 25,
              rotation_frames: int = 400) -> Factorisation:
    """Separate head pose from expression in (F, P, 3) marker positions (Chai et al. 2003, eqs.
    1-4; Xiao, Chai & Kanade's closed form). Translation is the markers' mean; the centred data
    ``M`` (3F x P) is cut to rank 3L by its SVD, L the fewest bases keeping ``energy`` of it
    (at most ``max_bases``); ``M ~ Q~ B~`` is then corrected by the 3L x 3L matrix G found from
    the **rotation constraints** (each frame's 3 x 3 blocks of ``Q~ G`` are scaled rotations:
    ``Q~_f g_k g_k^T Q~_f^T = c_fk^2 I``, on ``rotation_frames`` frames spread over the take) and
    the **basis constraints** (L frames chosen to span the deformations, by pivoted QR of the
    rows of ``Q~``, are the bases: ``c_{f_i k} = delta_ik``), solved for each ``g_k g_k^T`` by
    least squares with one shared matrix; each ``g_k`` is its rank-3 factor, turned into one
    common frame (the first basis) by Procrustes."""
    from scipy.linalg import qr

    x = np.asarray(markers, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3 or x.shape[0] < 2 or x.shape[1] < 4 or not np.all(np.isfinite(x)):
        raise FaceAnimError(f"markers must be finite (frames >= 2, points >= 4, 3), got shape {x.shape}")
    f_count, p_count = x.shape[:2]
    t = x.mean(axis=1)
    m = np.transpose(x - t[:, None], (0, 2, 1)).reshape(3 * f_count, p_count)
    u, s, vt = np.linalg.svd(m, full_matrices=False)
    kept = np.cumsum(s ** 2) / max(float((s ** 2).sum()), 1e-300)
    n_l = int(min(max_bases, max(1, np.ceil((np.searchsorted(kept, energy) + 1) / 3))))
    r3 = min(3 * n_l, len(s))
    n_l = r3 // 3
    r3 = 3 * n_l
    q = u[:, :r3] * np.sqrt(s[:r3])
    b = np.sqrt(s[:r3])[:, None] * vt[:r3]
    qf = q.reshape(f_count, 3, r3)
    # basis frames: the L frames whose blocks are the most independent
    _, _, piv = qr(qf.reshape(f_count, 3 * r3).T, pivoting=True, mode="economic")
    basis = np.sort(piv[:n_l])
    iu = np.triu_indices(r3)
    rows = []
    # rotation constraints (the right side is 0 for every k)
    pick = np.unique(np.linspace(0, f_count - 1, min(rotation_frames, f_count)).astype(int))
    qs = qf[pick]
    for a, c in ((0, 1), (0, 2), (1, 2)):
        rows.append(_sym_rows(qs[:, a], qs[:, c], iu))
    for a, c in ((0, 1), (1, 2)):
        rows.append(_sym_rows(qs[:, a], qs[:, a], iu) - _sym_rows(qs[:, c], qs[:, c], iu))
    n_rot = sum(len(r) for r in rows)
    # basis constraints: Q~_{f_i} N_k Q~_{f_j}^T = I if i == j == k else 0
    pairs = [(i, j) for i in range(n_l) for j in range(i, n_l)]
    for i, j in pairs:
        for a in range(3):
            for c in range(3):
                if i == j and c < a:
                    continue
                rows.append(_sym_rows(qf[basis[i], a][None], qf[basis[j], c][None], iu))
    big = np.vstack(rows)
    rhs = np.zeros((len(big), n_l))
    r = n_rot
    for i, j in pairs:
        for a in range(3):
            for c in range(3):
                if i == j and c < a:
                    continue
                if i == j and a == c:
                    rhs[r, i] = 1.0
                r += 1
    sol, *_ = np.linalg.lstsq(big, rhs, rcond=None)
    g_cols = []
    for k in range(n_l):
        nk = np.zeros((r3, r3))
        nk[iu] = sol[:, k]
        nk = nk + nk.T - np.diag(np.diag(nk))
        w, v = np.linalg.eigh(nk)
        top = np.argsort(w)[::-1][:3]
        g_cols.append(v[:, top] * np.sqrt(np.maximum(w[top], 0.0)))
    # one frame for all k: A_fk O_k = c_fk R_f; O_1 = I, O_k from sum_f A_fk^T A_f1 (Procrustes)
    a_fk = np.einsum("fir,krj->fkij", qf, np.stack(g_cols))  # (F, L, 3, 3)
    o = [np.eye(3)]
    for k in range(1, n_l):
        h = np.einsum("fji,fjl->il", a_fk[:, k], a_fk[:, 0])
        uu, _, vv = np.linalg.svd(h)
        ok = uu @ vv
        o.append(ok * np.sign(np.linalg.det(ok)))
    g = np.concatenate([gk @ ok for gk, ok in zip(g_cols, o)], axis=1)
    qg = np.einsum("fir,rj->fij", qf, g).reshape(f_count, 3, n_l, 3).transpose(0, 2, 1, 3)  # (F, L, 3, 3)
    strongest = np.argmax(np.linalg.norm(qg, axis=(2, 3)), axis=1)
    # the strongest block is c R with c of either sign: det(c R) = c^3 gives the sign
    blocks = qg[np.arange(f_count), strongest]
    rot = np.stack([_polar(np.sign(np.linalg.det(bk)) * bk) for bk in blocks])
    coeff = np.einsum("fij,fkij->fk", rot, qg) / 3.0
    bases = (np.linalg.pinv(g) @ b).reshape(n_l, 3, p_count)
    # gauge: the first basis frame's head pose is the identity
    ref = rot[basis[0]].copy()
    rot = rot @ ref.T
    bases = np.einsum("ij,kjp->kip", ref, bases)
    return Factorisation(rot, t, coeff, bases, basis, float(kept[r3 - 1]))



def pose_free(fact: Factorisation, markers: np.ndarray) -> np.ndarray:
    """(F, P, 3) the recorded markers with the head pose the factorisation found taken out,
    ``R_f^T (X_f - T_f)``: every detail of the expression kept (the rank-3L model's own
    reconstruction keeps only what its L bases span)."""
    return np.einsum("fji,fpj->fpi", fact.rotations, np.asarray(markers, dtype=np.float64) - fact.translations[:, None])


def _weighted_rigid(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation r and translation t minimising sum_p w_p |r a_p + t - b_p|^2 (Kabsch)."""
    w = w / w.sum()
    ca, cb = w @ a, w @ b
    h = ((a - ca) * w[:, None]).T @ (b - cb)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cb - r @ ca


def stable_registration(markers: np.ndarray, rest: np.ndarray, iterations: int = 10,
                        floor: float = 3e-4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Head pose by rigid registration of every frame onto ``rest`` (P, 3), each marker weighted by
    how still it is: weights start equal and are re-estimated ``iterations`` times as
    ``1 / (s_p^2 + floor^2)``, ``s_p`` the marker's RMS spread about its median in the pose-free
    frames (no face model needed: markers on the forehead and nose bridge earn the weight).
    Returns (rotations (F, 3, 3), translations (F, 3), weights (P,)) with ``X_f = R_f Y_f + T_f``,
    ``Y_f`` in ``rest``'s frame. On the real take turned by the head motion tracked in d0.mp4
    (``faceanim mocap build ... --head-motion d0.mp4`` prints it): 0.15 degrees median, 0.61 at the
    95th percentile, against the factorisation's 0.73 and 4.25 (``tests/test_motion.py`` checks
    it on a known sweep)."""
    x = np.asarray(markers, dtype=np.float64)
    w = np.ones(x.shape[1])
    for _ in range(max(1, int(iterations))):
        rt = [_weighted_rigid(rest, xf, w) for xf in x]
        rot = np.stack([r for r, _ in rt])
        tr = np.stack([t for _, t in rt])
        y = np.einsum("fji,fpj->fpi", rot, x - tr[:, None])
        spread = np.sqrt(((y - np.median(y, axis=0)) ** 2).sum(axis=2).mean(axis=0))
        w = 1.0 / (spread ** 2 + floor ** 2)
    return rot, tr, w


def head_frame(fact: Factorisation, markers: np.ndarray, rest: np.ndarray, floor: float = 3e-4) -> np.ndarray:
    """(F, P, 3) the markers with the factorisation's head pose taken out (:func:`pose_free`), in
    the neutral head's frame: turned once onto ``rest`` (the factorisation's frame is its first
    basis frame's), then each frame shifted so that the stillest markers (weighted as in
    :func:`stable_registration`) sit on their rest places (the factorisation centres every frame
    on its mean, which an open jaw drags down)."""
    from faceanim.face.frame import similarity

    expr = pose_free(fact, markers)
    _, w, _ = similarity(expr.mean(axis=0), rest, scale=False)
    aligned = expr @ w.T
    spread = np.sqrt(((aligned - np.median(aligned, axis=0)) ** 2).sum(axis=2).mean(axis=0))
    weights = 1.0 / (spread ** 2 + floor ** 2)
    shift = np.einsum("p,fpd->fd", weights / weights.sum(), rest[None] - aligned)
    return aligned + shift[:, None]


def rotation_error(recovered: np.ndarray, applied: np.ndarray) -> np.ndarray:
    """(F,) degrees between recovered and applied (F, 3, 3) rotations after the one free global
    rotation between their frames (fitted by Procrustes over all frames)."""
    u, _, vt = np.linalg.svd(np.einsum("fji,fjk->ik", recovered, applied))
    w = u @ vt
    cos = (np.einsum("fij,fij->f", recovered @ w, applied) - 1) / 2
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def marker_controls(markers: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Section 3.1's last step: the 15 control parameters of every motion capture frame from its
    markers in the head's frame (:func:`head_frame`), seen fronto-parallel (the first 19 markers are
    the tracked features, as :func:`marker_vertices` orders them), measured from the database's
    typical face and in the lengths of its neutral frame, found as in a video
    (:func:`~faceanim.face.controls.typical_controls`, :func:`~faceanim.face.controls.find_neutral`:
    the same rule on both sides, so that a performer's relaxed face and the database's meet at 0).
    Returns (raw (F, 15), normalised (F, 15), the neutral frame)."""
    from faceanim.face.controls import control_parameters, find_neutral, normalise, typical_controls

    feats = markers[:, : len(FEATURE_NAMES), :2]
    raw = np.stack([control_parameters(f) for f in feats])
    still, every = np.zeros((len(raw), 6)), np.ones(len(raw), dtype=bool)
    neutral = find_neutral(raw, still, every)
    return raw, normalise(raw, typical_controls(raw, still, every), feats[neutral]), neutral


def deformation_bases(markers: np.ndarray, rest: np.ndarray, energy: float = 0.999,
                      max_bases: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """The database's deformation bases (section 5, ``delta x_s,i``): the principal directions of
    the markers' motion from the neutral face, ``markers - rest`` (F, P, 3), uncentred (the neutral
    face is weight 0), the fewest keeping ``energy`` of the motion's energy (at most
    ``max_bases``). Returns (bases (L, P, 3), orthonormal as 3P vectors; the energy kept by 1..L)."""
    d = (np.asarray(markers, dtype=np.float64) - rest).reshape(len(markers), -1)
    _, s, vt = np.linalg.svd(d, full_matrices=False)
    kept = np.cumsum(s ** 2) / max(float((s ** 2).sum()), 1e-300)
    n = int(min(max_bases, np.searchsorted(kept, energy) + 1, len(s)))
    return vt[:n].reshape(n, -1, 3), kept[:n]


# ---------------------------------------------------------------------------------------- the database
DATABASE_FORMAT = "faceanim motion database 2"
MAX_ARRAY = 50_000_000  # elements of any one array in a database file (motion, the largest, is F x 228)


@dataclass
class MotionDatabase:
    """A motion database (section 3): per frame, the markers with the head pose taken out and
    their 15 control parameters, and the deformation bases that retarget it (section 5).

    File format (``.npz``, :meth:`save` / :func:`load_database`): ``format`` (the string
    :data:`DATABASE_FORMAT`), ``fps``, ``control_names`` (15 strings: a database is refused by a
    program that measures other controls), ``marker_vertices`` (P,) of the generic head,
    ``rest`` (P, 3) the markers on the neutral head (metres, the head's frame: x its left, y up,
    z forward), ``motion`` (F, P, 3) float16 the pose-free markers minus ``rest``, ``controls``
    (F, 15) normalised and ``raw`` (F, 15) measured control parameters, ``neutral`` (the neutral
    frame), ``take_starts`` (T,) the first frame of each recording, ``take_names`` (T,),
    ``rotation_error`` (F,) degrees between the head rotation applied and the one the
    pose recovery found (NaN where none was applied), ``bases`` (L, P, 3) the deformation
    bases (orthonormal), ``weights`` (F, L) each frame's motion in them, ``curve_names`` (C,) the
    generic head's shapes (ARKit's, ICT names) and ``basis_curves`` (L, C) each basis as a
    combination of those shapes (from the recorded curves: the bases on the whole head).
    """

    fps: float
    control_names: tuple
    marker_vertices: np.ndarray
    rest: np.ndarray
    markers: np.ndarray
    controls: np.ndarray
    raw: np.ndarray
    neutral: int
    take_starts: np.ndarray
    take_names: tuple
    rotation_error: np.ndarray
    bases: np.ndarray
    weights: np.ndarray
    curve_names: tuple
    basis_curves: np.ndarray

    @property
    def n_frames(self) -> int:
        return len(self.controls)

    @property
    def n_bases(self) -> int:
        return len(self.bases)

    def basis_weights(self, markers: np.ndarray) -> np.ndarray:
        """(F, L) weights of (F, P, 3) markers (head frame) in the deformation bases (eq. 7's
        lambda: the projection of the motion from rest)."""
        d = np.asarray(markers, dtype=np.float64) - self.rest
        return d.reshape(len(d), -1) @ self.bases.reshape(self.n_bases, -1).T

    def save(self, path) -> None:
        from faceanim.io.files import atomic_output, npz_bytes

        with atomic_output(path, "motion database") as tmp, open(tmp, "wb") as fh:
            fh.write(npz_bytes(
                format=np.array(DATABASE_FORMAT), fps=np.array(self.fps),
                control_names=np.array(self.control_names), marker_vertices=self.marker_vertices,
                rest=self.rest, motion=(self.markers - self.rest).astype(np.float16), controls=self.controls,
                raw=self.raw, neutral=np.array(self.neutral), take_starts=self.take_starts,
                take_names=np.array(self.take_names), rotation_error=self.rotation_error, bases=self.bases,
                weights=self.weights.astype(np.float32), curve_names=np.array(self.curve_names),
                basis_curves=self.basis_curves))


POSE_METHODS = ("stable", "factorisation")
UNSEEN_SHAPES = ("eyeLook",)  # shapes no marker sees: left out of the bases' shape combinations


def build_database(takes, fps: float = 30.0, head_motion: np.ndarray | None = None, head=None,
                   energy: float = 0.999, pose: str = "stable") -> MotionDatabase:
    """Build a motion database from ARKit takes ``[(name, ArkitTake), ...]``: each resampled to
    ``fps``, played on the generic head's 76 markers with its recorded head rotation, or with
    ``head_motion`` ((N, 3) yaw, pitch, roll in degrees, looped over the frames) where given; the
    pose separated by :func:`stable_registration` (``pose="stable"``) or the paper's
    :func:`factorise` (``"factorisation"``, put in the head's frame by :func:`head_frame`); the
    control parameters by :func:`marker_controls`; the deformation bases keeping ``energy``
    (:func:`deformation_bases`), each written as a combination of the head's shapes (all but the
    eyes' gaze, :data:`UNSEEN_SHAPES`) by least squares against the recorded curves."""
    from faceanim.face.controls import CONTROL_NAMES
    from faceanim.face.generic_head import generic_head

    head = head or generic_head()
    if not takes:
        raise FaceAnimError("give at least one take")
    markers = marker_vertices(head)
    rest = head.mesh.vertices[markers]
    frames, starts, names, rotations, curves = [], [], [], [], []
    shape_names = None
    n = 0
    from faceanim.limits import MAX_FRAMES

    total = sum(int(np.floor(take.duration * fps + 1e-6)) + 1 for _, take in takes)
    if total > MAX_FRAMES:
        raise FaceAnimError(f"the takes make {total} frames at {fps:g} fps; give at most {MAX_FRAMES} "
                            "(fewer or shorter takes, or a lower --fps)")
    for name, take in takes:
        r = take.resample(fps)
        shape_names, c = r.ict_curves()
        angles = r.head  # the recorded head yaw, pitch, roll (radians, as ARKit reports them)
        if head_motion is not None:
            hm = np.radians(np.asarray(head_motion, dtype=np.float64))
            angles = hm[(n + np.arange(r.n_samples)) % len(hm)]
        rot = head_rotation(angles[:, 0], angles[:, 1], angles[:, 2])
        frames.append(play_take(head, shape_names, c, markers, rot))
        rotations.append(rot)
        curves.append(c)
        starts.append(n)
        names.append(str(name))
        n += r.n_samples
    if np.ptp(np.concatenate(curves), axis=0).max() < 1e-6:
        raise FaceAnimError("the takes have no facial motion (every curve is constant); give recordings of a "
                            "moving face")
    x = np.concatenate(frames)
    applied = np.concatenate(rotations)
    if pose == "stable":
        recovered, shift, _ = stable_registration(x, rest)
        pose_free_markers = np.einsum("fji,fpj->fpi", recovered, x - shift[:, None])
    elif pose == "factorisation":
        fact = factorise(x)
        recovered, pose_free_markers = fact.rotations, head_frame(fact, x, rest)
    else:
        raise FaceAnimError(f"unknown pose method '{pose}'; choose {' or '.join(POSE_METHODS)}")
    raw, controls, neutral = marker_controls(pose_free_markers)
    bases, _ = deformation_bases(pose_free_markers, rest, energy)
    d = (pose_free_markers - rest).reshape(len(x), -1)
    weights = d @ bases.reshape(len(bases), -1).T
    # the bases as the head's shapes, except the eyes' gaze (the eyeballs turn; no marker is on
    # them, so the bases cannot say where the eyes look)
    seen = [k for k, n in enumerate(shape_names) if not n.startswith(UNSEEN_SHAPES)]
    shape_names = [shape_names[k] for k in seen]
    basis_curves, *_ = np.linalg.lstsq(weights, np.concatenate(curves)[:, seen], rcond=None)
    # the recovered rotations against the applied ones, after the free global rotation
    err = rotation_error(recovered, applied)
    moved = np.ptp(applied.reshape(len(applied), -1), axis=0).max() > 1e-9  # was any turn applied?
    return MotionDatabase(float(fps), tuple(CONTROL_NAMES), markers, rest, pose_free_markers, controls, raw, neutral,
                          np.array(starts), tuple(names), err if moved else np.full(len(x), np.nan), bases, weights,
                          tuple(shape_names), basis_curves)


def load_database(path) -> MotionDatabase:
    """Read a motion database written by :meth:`MotionDatabase.save`, checked (one line per fault)."""
    import zipfile

    from faceanim.errors import InputFileError, shown
    from faceanim.face.controls import CONTROL_NAMES
    from faceanim.io.files import check_input_file
    from faceanim.limits import MAX_FPS, MAX_FRAMES

    p = check_input_file(path, "motion database", "a database made by faceanim mocap build")
    name = shown(p, 80, tail=True)
    damaged = InputFileError(f"motion database '{name}' is damaged (inconsistent arrays); rebuild it")
    not_npz = InputFileError(f"motion database '{name}' is not a readable .npz file; build one with "
                             "faceanim mocap build")
    # the arrays' shapes from their headers, before anything is loaded (a header may claim more
    # than memory holds)
    try:
        with zipfile.ZipFile(p) as z:
            for info in z.infolist():
                if not info.filename.endswith(".npy"):
                    continue  # (not an array; np.load ignores it too)
                with z.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    read = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                            else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read(fh)
                if dtype.hasobject or int(np.prod(shape, dtype=np.float64)) > MAX_ARRAY:
                    raise damaged
    except InputFileError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError, RuntimeError):
        raise not_npz from None
    try:
        with np.load(p, allow_pickle=False) as d:
            data = {k: d[k] for k in d.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError):
        raise not_npz from None
    need = ("format", "fps", "control_names", "marker_vertices", "rest", "motion", "controls", "raw", "neutral",
            "take_starts", "take_names", "rotation_error", "bases", "weights", "curve_names", "basis_curves")
    fmt = str(data["format"]) if "format" in data and data["format"].dtype.kind == "U" else ""
    if fmt.startswith("faceanim motion database") and fmt != DATABASE_FORMAT:
        raise InputFileError(f"motion database '{name}' is in an older format; rebuild it with faceanim mocap build")
    missing = [k for k in need if k not in data]
    if missing or fmt != DATABASE_FORMAT:
        raise InputFileError(f"'{name}' is not a faceanim motion database ({DATABASE_FORMAT}); build one with "
                             "faceanim mocap build")
    if data["control_names"].dtype.kind != "U" or tuple(str(c) for c in data["control_names"]) != tuple(CONTROL_NAMES):
        raise InputFileError(f"motion database '{name}' was built for other control parameters; rebuild it with "
                             "this faceanim (faceanim mocap build)")
    from faceanim.face.generic_head import generic_head

    def within(key, bound):
        a = data[key]
        return a.dtype.kind in "fiu" and bool(np.all(np.isfinite(a))) and float(np.abs(a).max(initial=0.0)) <= bound

    try:
        f, p_count = data["controls"].shape[0], len(data["marker_vertices"])
        n_l, n_c = data["bases"].shape[0], len(data["curve_names"])
        starts = data["take_starts"]
        ok = (data["controls"].shape == (f, 15) and data["raw"].shape == (f, 15) and 1 <= f <= MAX_FRAMES
              and data["motion"].shape == (f, p_count, 3) and data["rest"].shape == (p_count, 3) and p_count >= 4
              and data["rotation_error"].shape == (f,) and 0 <= int(data["neutral"]) < f
              and data["bases"].shape == (n_l, p_count, 3) and 1 <= n_l <= 3 * p_count
              and data["weights"].shape == (f, n_l) and data["basis_curves"].shape == (n_l, n_c) and n_c >= 1
              and data["marker_vertices"].dtype.kind in "iu" and data["curve_names"].dtype.kind == "U"
              and starts.dtype.kind in "iu" and starts.ndim == 1 and len(starts) >= 1 and int(starts[0]) == 0
              and bool(np.all(np.diff(starts) > 0)) and int(starts[-1]) < f
              and data["take_names"].dtype.kind == "U" and data["take_names"].shape == starts.shape
              and data["fps"].shape == () and np.isfinite(float(data["fps"])) and 1.0 <= float(data["fps"]) <= MAX_FPS
              and within("controls", 1e4) and within("raw", 1e4) and within("rest", 10.0) and within("motion", 1.0)
              and within("bases", 1.0 + 1e-6) and within("weights", 1e3) and within("basis_curves", 1e6)
              and len(set(data["curve_names"].tolist())) == n_c
              and len(set(data["marker_vertices"].tolist())) == p_count)
        if ok:
            b = data["bases"].reshape(n_l, -1).astype(np.float64)
            ok = bool(np.allclose(b @ b.T, np.eye(n_l), atol=1e-4))  # orthonormal, as built
        head = generic_head()
        ok = ok and bool(np.all((data["marker_vertices"] >= 0) & (data["marker_vertices"] < head.mesh.n_vertices)))
        ok = ok and {str(c) for c in data["curve_names"]} <= set(head.shape_names)
    except (TypeError, ValueError, IndexError, OverflowError):
        ok = False
    if not ok:
        raise damaged
    rest = data["rest"].astype(np.float64)
    return MotionDatabase(float(data["fps"]), tuple(CONTROL_NAMES), data["marker_vertices"].astype(np.int64),
                          rest, rest + data["motion"].astype(np.float64),
                          data["controls"].astype(np.float64), data["raw"].astype(np.float64), int(data["neutral"]),
                          data["take_starts"].astype(np.int64), tuple(str(t) for t in data["take_names"]),
                          data["rotation_error"].astype(np.float64), data["bases"].astype(np.float64),
                          data["weights"].astype(np.float64), tuple(str(c) for c in data["curve_names"]),
                          data["basis_curves"].astype(np.float64))
