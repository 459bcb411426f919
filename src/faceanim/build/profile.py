"""Feature points from a true profile photo (head turned about 90 degrees).

Landmark detectors fail on a profile; its silhouette holds the face's midline instead (the seed
paper, section 2.1, takes the profile points of the FDP set from the side photo). The person is
segmented with the selfie segmentation models MediaPipe published (shipped in ``assets/mediapipe``), the
silhouette's edge refined with GrabCut, and the profile curve (the silhouette's facing edge,
from the top of the head down the face to the neck) searched for the points a profile shows,
named by their MediaPipe face mesh indices on the midline, as the rest of the pipeline names
points:

- found on the curve: 168 nasion (the deepest point between brow and nose), 4 pronasale (the
  nose tip), 2 subnasale, 0 upper lip, 13/14 where the lips meet (two points when the mouth is
  open), 17 lower lip, 18 mentolabial sulcus, 175 chin, 152 menton;
- placed on the curve by MediaPipe's own proportions from the nasion and the nose tip: the nose
  ridge 6, 197, 195, 5 and the forehead 9, 151, 10 (the hairline cannot be seen on a silhouette);
- ``head_top`` (the highest point of the silhouette) and ``head_back`` (the back of the skull at
  the eyes' height); hair counts as head: both are the hair's outline on a person with hair.

Everything is in pixels of the given image (x right, y down; the image spans 0..W, so a pixel's
centre is at +0.5). Accuracy on side renders of a real head scan: tests/test_profile.py.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from faceanim.errors import LandmarkError

MIN_SIZE = 32  # pixels per side of an image
MAX_SIZE = 16384
WORK_SIZE = 768  # the silhouette is traced at most this many pixels per side (GrabCut's time grows with it)
SEGMENTATION_SIZE = 512  # the segmentation models see at most this (they work at 256)
MIN_HEAD = 48  # pixels: a head at least this long (nose to back of the skull) in the image
PROFILE_YAW = 50.0  # estimated yaw (degrees) from which a face is a profile (55 to 60 true, see face_yaw)

# the points returned, top to bottom (MediaPipe face mesh indices on the midline)
PROFILE_INDICES = (10, 151, 9, 168, 6, 197, 195, 5, 4, 2, 0, 13, 14, 17, 18, 175, 152)


@dataclass
class ProfilePoints:
    """Feature points found on a profile photo, in pixels (x right, y down).

    ``points``: MediaPipe landmark index -> (2,) pixel position, for the midline points a
    profile shows; ``extra``: ``head_top`` (the highest point of the silhouette, the vertex of
    the skull) and ``head_back`` (the back of the skull at the height of the eyes); ``facing``:
    +1 when the nose points to the image's right, -1 to its left; ``curve``: (N, 2) the profile
    curve from the top of the head down the face to the neck, in order, every half pixel of the
    traced silhouette. ``info``: what else was measured (``yaw``: the face mesh's estimate or
    None, ``open_mouth``, ``nose_length``: nasion to nose tip in pixels).
    """

    points: dict[int, np.ndarray]
    extra: dict[str, np.ndarray]
    facing: int
    curve: np.ndarray
    info: dict = field(default_factory=dict, repr=False)


def _as_image(image) -> np.ndarray:
    try:
        img = np.asarray(image)
    except (TypeError, ValueError):
        raise LandmarkError("expected an RGB image (an H x W x 3 array of uint8)") from None
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.dtype != np.uint8:
        raise LandmarkError(f"expected an RGB image (H x W x 3 uint8), got an array of shape {img.shape} "
                            f"and type {img.dtype}; load the photo as 8-bit RGB")
    h, w = img.shape[:2]
    if min(h, w) < MIN_SIZE or max(h, w) > MAX_SIZE:
        raise LandmarkError(f"expected an image of {MIN_SIZE} to {MAX_SIZE} pixels per side, got {w}x{h}")
    return np.ascontiguousarray(img[..., :3])


def _resized(img: np.ndarray, longest: int) -> tuple[np.ndarray, float]:
    """``img`` shrunk so its longest side is at most ``longest``, and the factor (new / old)."""
    import cv2

    h, w = img.shape[:2]
    s = min(1.0, longest / max(h, w))
    if s == 1.0:
        return img, 1.0
    small = cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    return small, s


# ----------------------------------------------------------------------------- segmentation
def _person_probability(img: np.ndarray) -> np.ndarray:
    """(H, W) float32 probability of 'person' per pixel: both selfie segmentation models (the
    general one, 0, at 256 x 256, and the landscape one, 1, at 144 x 256), each on the image and
    on its mirror, averaged.

    Model 0 is the better one on heads: on the face's edge in 120 side renders of a real head
    scan (with and without shoulders, on grey, busy and noisy backgrounds), its mean error is
    0.5 px against 0.8 on grey and 1.1 against 1.5 on busy backgrounds at 512 px. Alone, though,
    it lost the nose in 8 of the 120 renders (a busy background half-believed around a head
    without shoulders) where the mean of both models on image and mirror lost none; the mirror
    halves one-sided errors. GrabCut (:func:`_grabcut`) then takes the edge to within a pixel.
    """
    import cv2

    from faceanim.face.mediapipe import selfie_segmenter

    h, w = img.shape[:2]
    small, _ = _resized(img, SEGMENTATION_SIZE)
    mirror = np.ascontiguousarray(small[:, ::-1])
    probs = []
    for model in (0, 1):
        with selfie_segmenter(model, "profile points") as segment:
            probs.append(segment(small))
            probs.append(segment(mirror)[:, ::-1])
    p = np.mean(probs, axis=0).astype(np.float32)
    if p.shape != (h, w):
        p = cv2.resize(p, (w, h), interpolation=cv2.INTER_LINEAR)
    return np.clip(p, 0.0, 1.0)


def _largest_component(mask: np.ndarray) -> np.ndarray:
    import cv2

    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros_like(mask, dtype=bool)
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return labels == k


def _head_extent(mask: np.ndarray) -> tuple[int, int, float]:
    """Top row, neck row and head length (the widest extent of the head, forehead or nose to the
    back of the skull) of a person's silhouette.

    Going down from the top, the silhouette widens to the head's length, narrows at the neck and
    widens again at the shoulders: the neck is the narrowest row between 1.0 and 1.8 head
    lengths below the top (the chin is about 1.1 below it), or the last row when the picture
    ends first.
    """
    rows = np.flatnonzero(mask.any(axis=1))
    top, bottom = int(rows[0]), int(rows[-1])
    xs = np.arange(mask.shape[1])
    width = np.zeros(mask.shape[0])
    for y in range(top, bottom + 1):
        r = xs[mask[y]]
        width[y] = r[-1] - r[0] + 1 if r.size else 0
    # the head's length: the widest row in the top part, grown while the head widens
    length = width[top]
    y = top
    while y <= bottom and (y - top) <= 1.3 * max(length, 1):
        length = max(length, width[y])
        y += 1
    lo, hi = top + int(1.0 * length), min(bottom, top + int(1.8 * length))
    if lo >= hi:
        return top, bottom, float(length)
    return top, lo + int(np.argmin(width[lo:hi + 1])), float(length)


def _grabcut(img: np.ndarray, prob: np.ndarray, band: int) -> np.ndarray | None:
    """The silhouette refined by GrabCut in a band around the segmentation's edge (None when
    GrabCut disagrees too much with the segmentation to be trusted)."""
    import cv2

    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band + 1, 2 * band + 1))
    confident = (prob > 0.9).astype(np.uint8)
    sure_fg = cv2.erode(confident, kernel).astype(bool)
    # the person is within two bands of where the segmentation is confident: farther out, an
    # unsure segmentation (a busy background, or below a head without a body) is background
    near = cv2.dilate(cv2.dilate(confident, kernel), kernel).astype(bool)
    seg = (prob > 0.5) & near
    sure_bg = ~(cv2.dilate((prob > 0.1).astype(np.uint8), kernel).astype(bool) & near)
    if sure_fg.sum() < 50 or sure_bg.sum() < 50:
        return None
    m = np.where(seg, cv2.GC_PR_FGD, cv2.GC_PR_BGD).astype(np.uint8)
    m[sure_fg] = cv2.GC_FGD
    m[sure_bg] = cv2.GC_BGD
    bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
    try:
        cv2.grabCut(np.ascontiguousarray(img[..., ::-1]), m, None, bgd, fgd, 3, cv2.GC_INIT_WITH_MASK)
    except cv2.error:
        return None
    out = (m == cv2.GC_FGD) | (m == cv2.GC_PR_FGD)
    inter, union = (out & seg).sum(), (out | seg).sum()
    if union == 0 or inter / union < 0.85:
        return None
    return out


def _silhouette(img: np.ndarray) -> tuple[np.ndarray, float, float, float]:
    """The person's silhouette around the head: (mask, scale, x0, y0), the mask covering a crop
    of ``img`` from (x0, y0) shrunk by ``scale`` (pixel (i, j) of the mask is at
    x0 + (j + 0.5) / scale, y0 + (i + 0.5) / scale in the image)."""
    import cv2

    small, s = _resized(img, WORK_SIZE)
    prob0 = _person_probability(small)
    # the person: where the segmentation says so, near where it is sure (a busy background can
    # be half-believed over large areas)
    r = max(2, int(0.02 * max(small.shape[:2])))
    sure = cv2.dilate((prob0 > 0.9).astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2))
    person = _largest_component((prob0 > 0.5) & sure.astype(bool))
    if person.sum() < 0.002 * person.size or person.sum() < 100:
        raise LandmarkError("no person found in the image; give a photo of a head in profile, lit and "
                            "against a plain background")
    top, neck, length = _head_extent(person)
    if length / s < MIN_HEAD:
        raise LandmarkError(f"the head's silhouette is too small ({length / s:.0f} pixels from front to back, "
                            f"at least {MIN_HEAD} needed); give a larger or closer photo")
    cols = np.flatnonzero(person[top:neck + 1].any(axis=0))
    pad = 0.35 * length
    h, w = img.shape[:2]
    x0 = max(0, int((cols[0] - pad) / s))
    x1 = min(w, int(np.ceil((cols[-1] + 1 + pad) / s)))
    y0 = max(0, int((top - pad) / s))
    y1 = min(h, int(np.ceil((neck + 1 + pad) / s)))
    work, sc = _resized(img[y0:y1, x0:x1], WORK_SIZE)
    if (x1 - x0) * (y1 - y0) < 0.5 * w * h:
        prob = _person_probability(work)  # a small head: segmented again, closer
    else:  # the head fills the picture: its first segmentation, resampled onto the crop
        # work pixel (j, i) is at x = x0 + (j + 0.5) / sc in the image, at x * s - 0.5 in ``small``
        a = s / sc
        m = np.array([[a, 0.0, x0 * s + 0.5 * a - 0.5], [0.0, a, y0 * s + 0.5 * a - 0.5]])
        prob = cv2.warpAffine(prob0, m, (work.shape[1], work.shape[0]),
                              flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    band = max(3, round(0.045 * length * sc / s))
    refined = _grabcut(work, prob, band)
    if refined is None:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (4 * band + 1, 4 * band + 1))
        refined = (prob > 0.5) & cv2.dilate((prob > 0.9).astype(np.uint8), kernel).astype(bool)
    from scipy.ndimage import binary_fill_holes

    mask = binary_fill_holes(_largest_component(refined))
    if mask.sum() < 100:
        raise LandmarkError("no person found in the image (nothing left of the silhouette around the head); give a "
                            "photo of a head in profile, lit and against a plain background")
    return mask, sc, float(x0), float(y0)


def _outline(mask: np.ndarray, sigma: float) -> np.ndarray:
    """(N, 2) closed outline (x, y) of ``mask`` in its index coordinates, sub-pixel: the 0.5
    level of the mask blurred by ``sigma`` pixels."""
    from scipy.ndimage import gaussian_filter
    from skimage.measure import find_contours

    blur = gaussian_filter(np.pad(mask.astype(np.float32), 2), sigma)
    lines = find_contours(blur, 0.5)
    if not lines:
        raise LandmarkError("no outline found around the person's silhouette; give a photo of a head in profile")
    c = max(lines, key=len)
    return np.ascontiguousarray(c[:, ::-1] - 2.0)


def _facing(mask: np.ndarray, top: int, neck: int, length: float) -> tuple[int, float]:
    """+1 when the face looks to the right of the image, -1 to the left, and how sure (the share
    of the narrow protrusions on the facing side, 0.5..1).

    The face side of a profile carries narrow protrusions (the nose, the lips, the chin) that an
    opening with a disc of a fifteenth of the head's length removes; the back of the skull is one
    wide curve that the opening keeps.
    """
    import cv2

    r = max(2, round(length / 15))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    m = np.pad(mask.astype(np.uint8), 2 * r, mode="edge")  # no false corners where the crop cuts
    opened = cv2.morphologyEx(m, cv2.MORPH_OPEN, disc)[2 * r:-2 * r, 2 * r:-2 * r].astype(bool)
    residue = mask & ~opened
    residue[:top + int(0.15 * (neck - top))] = False
    residue[neck:] = False
    cols = np.flatnonzero(mask[top:neck + 1].any(axis=0))
    centre = 0.5 * (cols[0] + cols[-1])
    xs = np.arange(mask.shape[1])
    left = residue[:, xs < centre].sum()
    right = residue[:, xs >= centre].sum()
    total = left + right
    if total == 0:
        return 1, 0.5
    return (1 if right > left else -1), max(left, right) / total


def _profile_curve(outline: np.ndarray, facing: int, top: int, neck: int, length: float) -> np.ndarray:
    """The facing edge of the outline: from its highest point down the face to the neck row,
    resampled every half pixel."""
    x, y = outline[:, 0], outline[:, 1]
    n = len(outline)
    ymin = y.min()
    tops = np.flatnonzero(y <= ymin + 0.5)
    # the middle of the highest run (a flat top)
    i_top = int(tops[np.argmin(np.abs(x[tops] - np.median(x[tops])))])
    best = None
    for step in (1, -1):
        idx = [i_top]
        k, lowest = i_top, y[i_top]
        for _ in range(n - 1):
            k = (k + step) % n
            if y[k] >= neck or y[k] < lowest - 0.05 * length:  # at the neck, or turning back up
                break
            idx.append(k)
            lowest = max(lowest, y[k])
        idx = np.array(idx)
        idx = idx[:int(np.argmax(y[idx])) + 1]  # down to its lowest point
        below = y[idx] >= top + 0.3 * length
        probe = idx[np.argmax(below)] if below.any() else idx[-1]
        score = facing * x[probe]
        if best is None or score > best[0]:
            best = (score, idx)
    curve = outline[best[1]]
    # uniform arc length, every half pixel
    seg = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        raise LandmarkError("the silhouette has no profile edge; give a photo of a head in profile")
    t = np.arange(0.0, s[-1], 0.5)
    return np.stack([np.interp(t, s, curve[:, 0]), np.interp(t, s, curve[:, 1])], axis=1)


# where MediaPipe's midline points sit, as fractions of the nasion -> nose tip distance (mean
# over FaceWarehouse's 20 expressions, five ICT shapes and faceanim's default face, whose
# landmarks MediaPipe placed): the nose ridge points along that chord (MediaPipe spaces them
# evenly), the forehead points by arc length up the profile from the nasion
NOSE_RIDGE = {6: 0.2, 197: 0.4, 195: 0.6, 5: 0.8}
FOREHEAD = {9: 0.34, 151: 0.75, 10: 1.12}
EYE_HEIGHT = 0.10  # the eyes' height below the nasion, in nasion -> nose tip distances


def _depth(curve: np.ndarray, a: int, b: int, facing: int) -> np.ndarray:
    """How far behind the chord from ``curve[a]`` to ``curve[b]`` each point between them lies
    (towards the back of the head)."""
    lo, hi = min(a, b), max(a, b)
    p, q = curve[a], curve[b]
    d = q - p
    n = np.array([d[1], -d[0]]) / max(np.linalg.norm(d), 1e-9)
    if n[0] * facing < 0:
        n = -n  # the normal that points forward
    return -((curve[lo:hi + 1] - p) @ n)


def _deepest(curve: np.ndarray, a: int, b: int, facing: int) -> tuple[int, float]:
    depth = _depth(curve, a, b, facing)
    k = int(np.argmax(depth))
    return min(a, b) + k, float(depth[k])


def _outer_chain(curve: np.ndarray, a: int, b: int, facing: int) -> list[int]:
    """Indices of the curve's convex hull on its facing side from ``a`` to ``b`` (QuickHull:
    the point farthest in front of a chord is on the hull)."""
    stack = [(a, b)]
    done = []
    while stack:
        p, q = stack.pop()
        if q - p < 2:
            done.append((p, q))
            continue
        depth = _depth(curve, p, q, facing)[1:-1]
        k = int(np.argmin(depth))
        if depth[k] >= -1e-9:
            done.append((p, q))
            continue
        m = p + 1 + k
        stack.append((m, q))
        stack.append((p, m))
    ends = sorted(done)
    return [ends[0][0]] + [q for _, q in ends]


def _features(curve: np.ndarray, a: int, b: int, facing: int, significant: float) -> list[tuple[str, int, float]]:
    """The alternating convex ("+") and concave ("-") features of the curve from ``a`` to
    ``b`` whose depth exceeds ``significant``: the pockets between the outer hull's vertices,
    each split at its deepest point and searched again on both sides (a concavity tree).

    Returns (kind, index, depth) in curve order; a convex feature's depth is how far it stands
    in front of the chord between the concave features on either side of it. Neighbouring
    pockets with no significant bump between them count as one (the deeper).
    """
    pockets = []  # (deepest index, depth)
    todo = [(a, b)]
    while todo:
        p, q = todo.pop()
        chain = _outer_chain(curve, p, q, facing)
        for h, h2 in itertools.pairwise(chain):
            if h2 - h < 2:
                continue
            m, d = _deepest(curve, h, h2, facing)
            if d > significant:
                pockets.append((m, d))
                todo += [(h, m), (m, h2)]
    pockets.sort()
    # neighbouring pockets with no significant bump between them are one pocket (the deeper)
    merged = True
    while merged and len(pockets) > 1:
        merged = False
        for k in range(len(pockets) - 1):
            (p, dp), (q, dq) = pockets[k], pockets[k + 1]
            bump = -float(_depth(curve, p, q, facing).min())
            if bump < significant:
                del pockets[k + 1 if dq <= dp else k]
                merged = True
                break
    out: list[tuple[str, int, float]] = []
    for k, (m, d) in enumerate(pockets):
        if k:
            p = pockets[k - 1][0]
            depth = _depth(curve, p, m, facing)
            j = int(np.argmin(depth))
            out.append(("+", p + j, float(-depth[j])))
        out.append(("-", m, d))
    return out


# directions (degrees forward of straight down) in which the chin's extreme points are the
# MediaPipe menton (152) and the point above it (175), on FaceWarehouse and ICT side renders
MENTON_DIRECTION, CHIN_DIRECTION = 40.0, 50.0
# the stomion and the mentolabial sulcus, as fractions of the profile's arc from the subnasale to
# the chin (175), when the lips show no notch to find it by
STOMION_ARC = 0.34
# and the lower lip and the sulcus, as fractions of the arc from the stomion to the chin, when the
# lower lip and the chin make one curve (lips pressed or stretched)
LOWER_LIP_BELOW_STOMION, SULCUS_BELOW_STOMION = 0.23, 0.42
OPEN_MOUTH = 0.2  # a lip notch deeper than this (in nasion -> nose tip distances) is an open mouth


def _extreme(curve: np.ndarray, lo: int, hi: int, facing: int, degrees: float) -> int:
    """The point of curve[lo..hi] farthest in the direction ``degrees`` forward of straight down."""
    t = np.radians(degrees)
    seg = curve[lo:hi + 1]
    return lo + int(np.argmax(seg[:, 1] * np.cos(t) + facing * seg[:, 0] * np.sin(t)))


def _frontmost(curve: np.ndarray, a: int, b: int, facing: int) -> int:
    """The point between ``a`` and ``b`` farthest in front of their chord."""
    if b - a < 2:
        return a
    return min(a, b) + int(np.argmin(_depth(curve, a, b, facing)))


def _at_arc(a: int, b: int, fraction: float) -> int:
    return round(a + fraction * (b - a))


def _find_points(curve: np.ndarray, facing: int, top: int, length: float,
                 nose_hint: np.ndarray | None = None) -> tuple[dict[int, int], dict]:
    """Curve indices of the profile's points (MediaPipe index -> index into ``curve``), and
    what else was measured on the way (the nasion -> nose tip distance, the open mouth).

    The profile's concavity tree (:func:`_features`) gives the nose: a bump within 6% of a head
    length of the most forward one (lips pushed out in a kiss can stand as far forward as the
    nose), the one nearest to ``nose_hint`` (the face detector's nose) or else the uppermost;
    the tip is its most forward point, the nasion and the subnasale the pockets either side.
    Below it, the notches between subnasale and chin give the stomion and the mentolabial
    sulcus (with the lips between), and the chin's extremes in fixed directions give 175 and
    152. The nose ridge and the forehead are placed by MediaPipe's proportions from the nasion
    and the nose tip. All lengths below the nose are in nasion -> nose tip distances (``nt``).
    """
    n = len(curve)
    u, v = facing * curve[:, 0], curve[:, 1]
    feats = _features(curve, 0, n - 1, facing, max(0.008 * length, 0.75))
    band = (v >= top + 0.3 * length) & (v <= top + 1.0 * length)
    noses = []
    for j, (kind, i, depth) in enumerate(feats):
        if kind != "+" or not band[i] or j == 0 or j == len(feats) - 1:
            continue
        lo, hi = feats[j - 1][1], feats[j + 1][1]
        tip = lo + int(np.argmax(u[lo:hi + 1]))
        noses.append((j, tip, depth))
    if not noses:
        raise LandmarkError("no nose found on the silhouette's edge; give a photo of a head in true profile "
                            "(turned about 90 degrees), the face's outline against the background")
    front = max(u[t] for _, t, _ in noses)
    noses = [x for x in noses if u[x[1]] >= front - 0.06 * length]
    if nose_hint is not None:
        j_tip, i_tip, bump = min(noses, key=lambda x: float(np.linalg.norm(curve[x[1]] - nose_hint)))
    else:
        j_tip, i_tip, bump = min(noses, key=lambda x: v[x[1]])
    i_nasion, nasion_depth = feats[j_tip - 1][1], feats[j_tip - 1][2]
    i_sub = feats[j_tip + 1][1]
    nt = float(np.linalg.norm(curve[i_tip] - curve[i_nasion]))
    if not (0.08 * length <= nt <= 0.45 * length and bump >= 0.03 * length and nasion_depth >= 0.015 * length):
        raise LandmarkError("the silhouette's edge shows no nose in profile (no bump between a brow and a lip); "
                            "give a photo of a head in true profile (turned about 90 degrees)")
    step = float(np.mean(np.linalg.norm(np.diff(curve, axis=0), axis=1)))

    def arc(i: int, j: int) -> float:
        return (j - i) * step

    # the chin lies within 3.5 nose lengths of arc below the subnasale (1.6 to 2.9 measured): a
    # silhouette that runs on below it (into an unsure background) is not searched
    i_neck = min(n - 1, i_sub + int(3.5 * nt / step))
    if arc(i_sub, i_neck) < 1.5 * nt:
        raise LandmarkError("the silhouette ends below the nose; give a photo that shows the chin and the neck")

    points: dict[int, int] = {168: i_nasion, 4: i_tip, 2: i_sub}
    # the notches between the subnasale and the neck (arc lengths in nose lengths, nasion to tip,
    # measured on FaceWarehouse and ICT: the stomion 0.48 to 0.69 below the subnasale, the
    # sulcus 0.94 to 1.43; an open mouth's deepest point 1.0 to 1.4): the stomion is an open
    # mouth's pocket if there is one, else the deepest notch 0.3 to 0.85 below the subnasale; the
    # mentolabial sulcus the deepest within one nose length below the stomion (plus the way out
    # of an open mouth)
    notches = [(i, d) for kind, i, d in _features(curve, i_sub, i_neck, facing, max(0.01 * nt, 0.5))
               if kind == "-"]
    upper = [(i, d) for i, d in notches if 0.25 * nt <= arc(i_sub, i) <= 1.6 * nt and d > OPEN_MOUTH * nt]
    if not upper:
        upper = [(i, d) for i, d in notches if 0.3 * nt <= arc(i_sub, i) <= 0.85 * nt]
    i_sto, sto_depth = max(upper, key=lambda x: x[1]) if upper else (None, 0.0)
    lower = [(i, d) for i, d in notches
             if i_sto is not None and 0.2 * nt <= arc(i_sto, i) <= nt + 2 * sto_depth and d >= 0.015 * nt]
    i_sulcus = max(lower, key=lambda x: x[1])[0] if lower else None
    # the chin: its extremes below the last of these notches
    lo = i_sulcus if i_sulcus is not None else i_sto if i_sto is not None else i_sub
    i_chin = points[175] = _extreme(curve, lo, i_neck, facing, CHIN_DIRECTION)
    # the menton, searched down to the throat (the first notch below the chin: the neck goes on
    # down, a chest comes forward again)
    throats = [i for kind, i, d in _features(curve, i_chin, i_neck, facing, max(0.01 * nt, 0.5))
               if kind == "-" and d >= 0.03 * nt]
    points[152] = _extreme(curve, lo, throats[0] if throats else i_neck, facing, MENTON_DIRECTION)
    if i_sto is None:
        i_sto = _at_arc(i_sub, i_chin, STOMION_ARC)
    opened = sto_depth > OPEN_MOUTH * nt
    points[0] = _frontmost(curve, i_sub, i_sto, facing)
    if opened:  # the lips' edges: the corners where each lip turns into the mouth
        points[13] = _frontmost(curve, points[0], i_sto, facing)
        points[14] = _frontmost(curve, i_sto, i_sulcus if i_sulcus is not None else i_chin, facing)
    else:
        points[13] = points[14] = i_sto
    if i_sulcus is not None:
        points[17] = _frontmost(curve, points[14], i_sulcus, facing)
        points[18] = i_sulcus
    else:  # lower lip and chin in one curve: placed by the usual proportions below the stomion
        points[17] = _at_arc(i_sto, i_chin, LOWER_LIP_BELOW_STOMION)
        points[18] = _at_arc(i_sto, i_chin, SULCUS_BELOW_STOMION)
    # the nose ridge along the nasion -> tip chord, the forehead by arc length above the nasion
    chord = curve[i_tip] - curve[i_nasion]
    t = (curve[i_nasion:i_tip + 1] - curve[i_nasion]) @ chord / max(chord @ chord, 1e-9)
    for k, frac_k in NOSE_RIDGE.items():
        points[k] = i_nasion + int(np.argmin(np.abs(t - frac_k)))
    for k, frac_k in FOREHEAD.items():
        points[k] = max(0, i_nasion - round(frac_k * nt / step))
    return points, {"nt": nt, "open_mouth": bool(opened)}


# ----------------------------------------------------------------------------- frontal or profile
_MIDLINE = (4, 168, 152, 10, 0, 17, 2, 6)


# a frontal face's MediaPipe points (x right, y up, z forward; eye distance 1, origin at the nose
# tip): the mean of FaceWarehouse's neutral scan and the ICT head, made left-right symmetric
FRONTAL = {
    10: (0.000, 0.872, -0.329), 151: (0.000, 0.705, -0.279), 9: (0.000, 0.519, -0.253),
    168: (0.000, 0.364, -0.256), 6: (0.000, 0.294, -0.213), 197: (0.000, 0.226, -0.159),
    195: (0.000, 0.158, -0.101), 4: (0.000, 0.000, 0.000), 2: (0.000, -0.135, -0.132),
    0: (0.000, -0.300, -0.087), 17: (0.000, -0.461, -0.117), 152: (0.000, -0.843, -0.313),
    33: (-0.499, 0.310, -0.413), 133: (-0.197, 0.305, -0.387), 234: (-0.783, 0.097, -0.991),
    61: (-0.256, -0.373, -0.262), 70: (-0.638, 0.438, -0.563), 105: (-0.457, 0.529, -0.363),
    50: (-0.512, -0.031, -0.356), 172: (-0.625, -0.540, -0.745),
    263: (0.499, 0.310, -0.413), 362: (0.197, 0.305, -0.387), 454: (0.783, 0.097, -0.991),
    291: (0.256, -0.373, -0.262), 300: (0.638, 0.438, -0.563), 334: (0.457, 0.529, -0.363),
    280: (0.512, -0.031, -0.356), 397: (0.625, -0.540, -0.745),
}


def _yaw(points: np.ndarray) -> float:
    """Yaw in degrees of the face mesh's 3D layout (image x, y, and MediaPipe's z, in pixels):
    the rotation that best takes :data:`FRONTAL` onto the same points (Kabsch)."""
    idx = list(FRONTAL)
    ref = np.array([FRONTAL[i] for i in idx])
    q = points[idx] * np.array([1.0, -1.0, -1.0])  # x right, y up, z towards the camera
    a, b = q - q.mean(0), ref - ref.mean(0)
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    rot = (u @ np.diag([1.0, 1.0, d]) @ vt).T
    forward = rot @ np.array([0.0, 0.0, 1.0])
    return float(np.degrees(np.arctan2(forward[0], forward[2])))


def face_yaw(image) -> float | None:
    """How far (degrees, 0..90) the face is turned from frontal by the MediaPipe face mesh, or
    None when the face mesh does not find one face consistently (no face, or a fit that the
    mirrored image does not repeat: the mesh forced onto a profile).

    The face mesh runs on the image and on its mirror; the yaw is the mean of the two
    estimates. It reads low on strongly turned faces: 54 at a true 60 degrees, 55 to 60 at 70
    to 80 degrees (renders of FaceWarehouse and ICT heads).
    """
    img, _ = _resized(_as_image(image), SEGMENTATION_SIZE * 2)
    from faceanim.face.mediapipe import FaceMesh
    from faceanim.io.files import native_stderr_quiet

    with native_stderr_quiet(), FaceMesh(video=False, confidence=0.3, what="profile points") as mesh:
        p = mesh(img)
        if p is None:
            return None
        pm = mesh(img[:, ::-1])
    if pm is None:
        return None
    yaw = 0.5 * (abs(_yaw(p)) + abs(_yaw(pm)))
    pm[:, 0] = img.shape[1] - pm[:, 0]  # back to this image's x
    size = float(np.linalg.norm(p[10, :2] - p[152, :2])) or 1.0
    if np.linalg.norm(p[list(_MIDLINE), :2] - pm[list(_MIDLINE), :2], axis=1).max() > 0.15 * size:
        return None
    return yaw


def is_profile(image) -> bool:
    """True when the face in ``image`` is turned so far that it should go through
    :func:`profile_points`: the face mesh finds no face consistently (see :func:`face_yaw`) or
    finds one turned more than about 60 degrees (an estimated yaw of ``PROFILE_YAW``)."""
    yaw = face_yaw(image)
    return yaw is None or yaw >= PROFILE_YAW


def _face_detection(img: np.ndarray) -> dict | None:
    """The MediaPipe face detector's best face: its nose tip and the mean of its two ear
    keypoints (pixels of ``img``) and its box width, or None.

    Unlike the face mesh it finds faces in true profile (FaceWarehouse side renders on plain,
    busy and noisy backgrounds: 60 of 60 with the short-range model), its nose keypoint within
    0.3 eye distances of the nose tip, the nose on the facing side of the ears.
    """
    from faceanim.face.mediapipe import face_detector

    small, s = _resized(img, WORK_SIZE)
    for model in (0, 1):  # short range (a face filling the picture), then full range
        with face_detector(model, 0.3, "profile points") as detect:
            found = detect(small)
        if found:
            best = found[0]
            kp = best.keypoints / s
            return {"nose": kp[2], "ears": 0.5 * (kp[4] + kp[5]), "score": best.score, "width": best.width / s}
    return None


def head_outline(image) -> np.ndarray:
    """(N, 2) the closed outline of the person's silhouette around the head, in pixels of
    ``image`` (x right, y down), counter-clockwise on the screen (the outward normal of the step
    from ``p[i]`` to ``p[i+1]`` is its tangent ``t`` turned to (-t_y, t_x)), every half pixel of the traced
    silhouette. For a front photo: the jaw, cheeks, ears and skull (or hair) against the background."""
    img = _as_image(image)
    mask, scale, x0, y0 = _silhouette(img)
    c = _outline(mask, 1.0)
    c = np.stack([x0 + (c[:, 0] + 0.5) / scale, y0 + (c[:, 1] + 0.5) / scale], axis=1)
    x, y = c[:, 0], c[:, 1]
    area = 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))  # > 0: clockwise on the screen (y down)
    return np.ascontiguousarray(c[::-1] if area > 0 else c)


# ----------------------------------------------------------------------------- the profile
def profile_points(image) -> ProfilePoints:
    """Feature points of a head photographed in true profile (turned about 90 degrees).

    ``image``: (H, W, 3) uint8 RGB. Returns the midline points MediaPipe would name
    (:data:`PROFILE_INDICES`), the top and back of the head, the facing direction and the
    profile curve, in pixels of ``image`` (x right, y down; the image spans 0..W and 0..H, so a
    pixel's centre is at +0.5).

    Raises :class:`LandmarkError` when there is no person, the head is too small, the face is
    not turned far enough (:func:`is_profile` would say False), or the silhouette's edge shows no
    nose between a brow and a lip.
    """
    img = _as_image(image)
    yaw = face_yaw(img)
    if yaw is not None and yaw < PROFILE_YAW:
        raise LandmarkError(
            f"the face is turned only about {yaw:.0f} degrees from frontal; profile points need a head in true "
            "profile (turned about 90 degrees): use the face mesh landmarks for this photo")
    mask, scale, x0, y0 = _silhouette(img)
    top, neck, length = _head_extent(mask)
    outline = _outline(mask, 1.0)
    # which way the face looks: the face detector's nose against its ears (when its nose is on
    # the silhouette's edge), else the narrow protrusions of the silhouette; the other side last
    face = _face_detection(img)
    sil_facing, _ = _facing(mask, top, neck, length)
    attempts = [(sil_facing, None), (-sil_facing, None)]
    if face is not None and abs(face["nose"][0] - face["ears"][0]) > 0.1 * face["width"]:
        hint = (face["nose"] - [x0, y0]) * scale - 0.5  # in the mask's index coordinates
        if np.min(np.linalg.norm(outline - hint, axis=1)) < 0.15 * length:
            attempts.insert(0, (1 if face["nose"][0] > face["ears"][0] else -1, hint))
    errors = []
    for facing, hint in attempts:
        try:
            curve = _profile_curve(outline, facing, top, neck, length)
            found, info = _find_points(curve, facing, top, length, hint)
            break
        except LandmarkError as exc:
            errors.append(exc)
    else:
        raise errors[0]

    def to_image(p):
        return np.array([x0 + (p[0] + 0.5) / scale, y0 + (p[1] + 0.5) / scale])

    points = {k: to_image(curve[found[k]]) for k in PROFILE_INDICES}
    # the back of the skull at the eyes' height: where the outline crosses that row at the back
    eye_y = curve[found[168], 1] + EYE_HEIGHT * info["nt"]
    ox, oy = outline[:, 0], outline[:, 1]
    nxt = np.roll(np.arange(len(outline)), -1)
    cross = np.flatnonzero((oy - eye_y) * (oy[nxt] - eye_y) <= 0)
    if cross.size:
        t = (eye_y - oy[cross]) / np.where(oy[nxt[cross]] == oy[cross], 1.0, oy[nxt[cross]] - oy[cross])
        xs = ox[cross] + t * (ox[nxt[cross]] - ox[cross])
        back = np.array([xs[np.argmin(facing * xs)], eye_y])
    else:
        back = outline[np.argmin(facing * ox)]
    extra = {"head_top": to_image(curve[0]), "head_back": to_image(back)}
    image_curve = np.stack([x0 + (curve[:, 0] + 0.5) / scale, y0 + (curve[:, 1] + 0.5) / scale], axis=1)
    return ProfilePoints(points, extra, int(facing), image_curve,
                         {"yaw": yaw, "open_mouth": info["open_mouth"], "nose_length": info["nt"] / scale})
