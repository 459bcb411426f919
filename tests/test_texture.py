"""The seamless head texture (build/texture.py): atlas layout, baking from photos, the merge.

Known truth twice: a sphere whose colour is a known function of position, photographed
analytically (every texel must come back as the function, the mirrored side as the function of
the mirrored point); and the FaceWarehouse scan, textured from its own photo, rendered from the
front and the sides, baked into our atlas and rendered again from 45 degrees against a render
of the original.
"""


import numpy as np
import pytest
from conftest import FACEWAREHOUSE, need

from faceanim.build import texture as tx
from faceanim.build.camera import ViewCamera
from faceanim.errors import FaceAnimError
from faceanim.render.bake import ortho_depth, ortho_render, uv_raster


# ----------------------------------------------------------------------------- helpers
def sphere(subdivisions=4):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces, dtype=np.int64)


def colour_fn(p):
    """A smooth colour field, not symmetric in x (so the mirror is checked), in 40..215."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    return np.stack([127.5 + 85 * np.sin(2.2 * x + 0.4 * y),
                     127.5 + 85 * np.cos(1.9 * y - 0.7 * z + 0.3),
                     127.5 + 85 * np.sin(1.5 * z + 1.1 * x + 0.8)], 1)


def yaw_camera(yaw_deg, size=256, scale=110.0):
    a = np.radians(yaw_deg)
    d = np.array([np.sin(a), 0.0, np.cos(a)])
    right = np.array([np.cos(a), 0.0, -np.sin(a)])
    rot = np.vstack([right, [0.0, 1.0, 0.0], d])
    return ViewCamera(rot, scale, np.array([size / 2, size / 2]), (size, size))


def sphere_photo(cam, background=(30, 30, 30)):
    """What a camera sees of the unit sphere coloured by colour_fn (ray casting per pixel)."""
    w, h = cam.size
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    a = (xs - cam.offset[0]) / cam.scale
    b = -(ys - cam.offset[1]) / cam.scale
    t2 = 1 - a * a - b * b
    hit = t2 > 0
    local = np.stack([a, b, np.sqrt(np.clip(t2, 0, None))], -1)[hit]
    img = np.empty((h, w, 3), dtype=np.uint8)
    img[:] = background
    img[hit] = np.clip(np.rint(colour_fn(local @ cam.rotation)), 0, 255).astype(np.uint8)
    return img


def texel_points(vertices, faces, uv, face_uv, size):
    """Each texel's 3D point (nan where no triangle covers it) the way the bake finds it."""
    tri, bary = uv_raster(uv[face_uv], (size, size))
    pts = np.full((size, size, 3), np.nan)
    ok = tri >= 0
    pts[ok] = np.einsum("nk,nkd->nd", bary[ok].astype(np.float64), vertices[faces[tri[ok]]])
    return pts


@pytest.fixture(scope="module")
def sphere_atlas():
    v, f = sphere()
    uv, face_uv = tx.atlas_uv(v, f, {"skin": np.arange(len(v))})
    return v, f, uv, face_uv


# ----------------------------------------------------------------------------- atlas layout
def test_atlas_layout_on_a_sphere(sphere_atlas):
    v, f, uv, face_uv = sphere_atlas
    assert face_uv.shape == f.shape and uv.shape[1] == 2
    assert uv.min() >= 0 and uv.max() <= 1
    c = uv[face_uv]
    area = 0.5 * ((c[:, 1, 0] - c[:, 0, 0]) * (c[:, 2, 1] - c[:, 0, 1])
                  - (c[:, 2, 0] - c[:, 0, 0]) * (c[:, 1, 1] - c[:, 0, 1]))
    assert (area > 0).all(), "a sphere's chart folds nowhere (outward triangles keep their winding)"
    assert area.min() > 0.02 * np.median(area), "no sliver triangles, the pole included"
    # the one seam: vertices at the back carry two UVs exactly one period apart, nothing else does
    per_vertex = {}
    for vid, (a, b) in zip(f.ravel(), c.reshape(-1, 2)):
        per_vertex.setdefault(vid, set()).add((a, b))
    split = {k: s for k, s in per_vertex.items() if len(s) > 1}
    top = int(np.argmax(v[:, 1]))
    for vid, s in split.items():
        if vid == top:
            continue  # the pole: one copy per triangle around it, all on the chart's top edge
        us = sorted(p[0] for p in s)
        assert len(s) == 2 and abs(us[1] - us[0] - tx.PERIOD) < 1e-9, (vid, s)
        assert v[vid, 2] < 0, "the seam is at the back of the head"
    assert len({p[1] for p in per_vertex[top]}) == 1 and max(p[1] for p in per_vertex[top]) > 0.99
    # the front 120 degrees get half a turn of width
    u60 = tx._theta_to_u(np.radians([-60.0, 60.0]))
    assert np.isclose(u60[1] - u60[0], tx.PERIOD / 2, atol=1e-3)
    front = (np.abs(np.degrees(np.arctan2(v[:, 0], v[:, 2]))) < 60) & (np.hypot(v[:, 0], v[:, 2]) > 0.3)
    assert np.ptp(c[np.isin(f, np.flatnonzero(front))][:, 0]) <= tx.PERIOD / 2 + 0.01


def test_atlas_checks_parts():
    v, f = sphere(2)
    with pytest.raises(FaceAnimError, match="skin"):
        tx.atlas_uv(v, f, {"head": np.arange(len(v))})
    with pytest.raises(FaceAnimError, match="unknown part"):
        tx.atlas_uv(v, f, {"skin": np.arange(len(v)), "hair": [0]})


# ----------------------------------------------------------------------------- analytic bakes
@pytest.mark.parametrize("blend", ["pyramid", "none"])
def test_sphere_bake_matches_the_colour_function(sphere_atlas, blend):
    v, f, uv, face_uv = sphere_atlas
    views = [tx.BakeView(sphere_photo(cam), cam) for cam in (yaw_camera(0), yaw_camera(90), yaw_camera(-90))]
    size = 512
    result = tx.bake(v, f, uv, face_uv, {"skin": np.arange(len(v))}, views, size=size, blend=blend)
    pts = texel_points(v, f, uv, face_uv, size)
    chart = ~np.isnan(pts[..., 0])
    chart[:, round(tx.PERIOD * size):] = False
    seen = result.split >= 0
    assert seen.sum() > 0.55 * chart.sum()
    err = np.abs(result.texture[seen].astype(float) - colour_fn(pts[seen]))
    assert err.mean() < 1.5 and np.percentile(err, 99) < 6, (err.mean(), np.percentile(err, 99))
    # the back, that the three photos see at grazing angles only, is filled within the range
    assert (result.texture[chart] >= 25).all() and (result.texture[chart] <= 230).all()
    # the texels past one period repeat the left edge (the back of the head shows no seam)
    p = round(tx.PERIOD * size)
    assert np.array_equal(result.texture[:, p:], result.texture[:, :size - p])
    assert set(result.sources) == {"photo 0", "photo 1", "photo 1 mirrored", "photo 2", "photo 2 mirrored"}


def test_unseen_side_comes_from_the_mirror_image(sphere_atlas):
    v, f, uv, face_uv = sphere_atlas
    cams = [yaw_camera(0), yaw_camera(90)]  # the front, and the subject's left (+x) only
    views = [tx.BakeView(sphere_photo(c), c) for c in cams]
    size = 512
    # the hard split: the pyramid mixes the low frequencies of the mirror image and the front's
    # far into both (they differ: the function is not symmetric)
    result = tx.bake(v, f, uv, face_uv, {"skin": np.arange(len(v))}, views, size=size, blend="none")
    pts = texel_points(v, f, uv, face_uv, size)
    mirrored = result.split == result.sources.index("photo 1 mirrored")
    assert mirrored.sum() > 2000
    assert (pts[mirrored][:, 0] < -0.1).all(), "the mirror paints the right side (-x)"
    core = mirrored & (pts[..., 0] < -0.5)
    got = result.texture[core].astype(float)
    assert np.abs(got - colour_fn(pts[core] * [-1, 1, 1])).mean() < 2.0
    assert np.abs(got - colour_fn(pts[core])).mean() > 20, "not the function at the point itself"


def test_only_a_front_photo_fills_the_back_smoothly(sphere_atlas):
    v, f, uv, face_uv = sphere_atlas
    cam = yaw_camera(0)
    result = tx.bake(v, f, uv, face_uv, {"skin": np.arange(len(v))}, [tx.BakeView(sphere_photo(cam), cam)],
                     size=256)
    pts = texel_points(v, f, uv, face_uv, 256)
    back = ~np.isnan(pts[..., 0]) & (pts[..., 2] < -0.5)
    assert (result.split[back] == -1).all()
    img = result.texture.astype(float)
    assert (img[back] > 25).all(), "no black texels"
    # smooth: no jumps between neighbouring texels of the filled back, across the seam either
    for a, b in ((img[:, 1:], img[:, :-1]), (img[1:], img[:-1])):
        both = (back[:, 1:] & back[:, :-1]) if a.shape[1] < img.shape[1] else (back[1:] & back[:-1])
        assert np.abs(a - b)[both].max() <= 8
    p = round(tx.PERIOD * 256)
    rows = back[:, p - 1]
    assert rows.sum() > 100 and np.abs(img[rows, 0] - img[rows, p - 1]).max() <= 8


def test_seam_step_measures_a_known_step():
    tex = np.full((64, 64, 3), 100, dtype=np.uint8)
    split = np.zeros((64, 64), dtype=np.int16)
    split[:, 32:] = 1
    tex[:, 32:] = 130
    assert tx.seam_step(tex, split) == pytest.approx(30.0)
    split[:, :4] = -1  # unseen texels take no part
    assert tx.seam_step(tex, split) == pytest.approx(30.0)
    assert tx.seam_step(tex, np.zeros_like(split)) == 0.0


def test_push_pull_wraps_around():
    img = np.zeros((32, 64, 3), dtype=np.float32)
    known = np.zeros((32, 64), dtype=bool)
    known[:, 10:20] = True
    img[:, 10:20] = 200
    known[:, 40:50] = True
    img[:, 40:50] = 50
    out = tx.push_pull(img, known, wrap=True)
    assert np.allclose(out[known], img[known])
    # across the wrap (columns 50..63, 0..9) the fill runs smoothly from 50 back to 200
    row = out[16, :, 0]
    assert abs(row[63] - row[0]) < 12
    flat = tx.push_pull(img, known, wrap=False)
    assert abs(flat[16, 63, 0] - flat[16, 0, 0]) > abs(row[63] - row[0])


def test_bake_checks_its_inputs(sphere_atlas):
    v, f, uv, face_uv = sphere_atlas
    cam = yaw_camera(0)
    view = tx.BakeView(sphere_photo(cam), cam)
    parts = {"skin": np.arange(len(v))}
    with pytest.raises(FaceAnimError, match="64 to 8192"):
        tx.bake(v, f, uv, face_uv, parts, [view], size=32)
    with pytest.raises(FaceAnimError, match="blend"):
        tx.bake(v, f, uv, face_uv, parts, [view], size=128, blend="feather")
    with pytest.raises(FaceAnimError, match="at least one"):
        tx.bake(v, f, uv, face_uv, parts, [], size=128)
    with pytest.raises(FaceAnimError, match="camera is for"):
        tx.bake(v, f, uv, face_uv, parts, [tx.BakeView(view.image[:100], cam)], size=128)


# ----------------------------------------------------------------------------- the generic head
@pytest.fixture(scope="module")
def generic():
    """The shipped generic head (ICT FaceKit: skin, gums and tongue, teeth, two eyeballs)."""
    from faceanim.face.generic_head import generic_head

    head = generic_head()
    return head.mesh.vertices, head.mesh.faces, head.parts


def test_generic_head_atlas_and_bake(generic):
    from faceanim.face.mesh import Mesh
    from faceanim.render import OffscreenRenderer

    v, f, parts = generic
    uv, face_uv = tx.atlas_uv(v, f, parts)
    c = uv[face_uv]
    assert uv.min() >= 0 and uv.max() <= 1
    part_of = np.full(len(v), -1)
    for k, idx in enumerate(parts.values()):
        part_of[idx] = k
    for k, name in enumerate(parts):
        sel = part_of[f[:, 0]] == k
        if name == "skin":
            chart = sel & (c[:, :, 1].min(1) >= tx.STRIP)
            assert chart.sum() > 0.75 * sel.sum()  # the rest: mouth and eye sockets, in the cavity tile
            u0, v0, u1, v1 = tx.TILES["cavity"]
            cav = c[sel & ~chart]
            assert (cav[..., 0] >= u0).all() and (cav[..., 0] <= u1).all() and (cav[..., 1] <= v1).all()
            area = 0.5 * ((c[chart, 1, 0] - c[chart, 0, 0]) * (c[chart, 2, 1] - c[chart, 0, 1])
                          - (c[chart, 2, 0] - c[chart, 0, 0]) * (c[chart, 1, 1] - c[chart, 0, 1]))
            # folds only where the surface folds over itself seen from the axis (ears, nostrils, lids)
            assert -area[area < 0].sum() < 0.03 * area[area > 0].sum()
        else:
            boxes = [tx.TILES["gums"], tx.TILES["tongue"]] if name == "gums_tongue" else [tx.TILES[name]]
            inside = np.zeros(sel.sum(), dtype=bool)
            for u0, v0, u1, v1 in boxes:
                inside |= ((c[sel, :, 0] >= u0) & (c[sel, :, 0] <= u1) & (c[sel, :, 1] >= v0)
                           & (c[sel, :, 1] <= v1)).all(1)
            assert inside.all(), name
    mesh = Mesh(v, f)
    views = []
    for yaw in (0, 90, -90):
        with OffscreenRenderer(mesh, (768, 768), yaw=yaw, parallel=True) as r:
            views.append(tx.BakeView(r.render(), tx.view_camera(r)))
    result = tx.bake(v, f, uv, face_uv, parts, views, size=1024)  # speed: benchmarks/bench_texture.py
    tex = result.texture
    # the untextured render's eyes are skin-coloured: not an iris, the default is used
    assert np.allclose(result.iris, tx.DEFAULT_IRIS)
    size = tex.shape[0]
    # blue irises with dark pupils painted into the front photo come back as the iris colour
    painted = views[0].image.copy()
    cam = views[0].camera
    ys, xs = np.mgrid[0:painted.shape[0], 0:painted.shape[1]] + 0.5
    for name in ("eyeball_L", "eyeball_R"):
        centre, radius = tx._sphere_fit(v[parts[name]])
        px = cam.project((centre + radius * np.array([0.0, 0.0, 1.0]))[None])[0]
        r = np.hypot(xs - px[0], ys - px[1]) / (radius * np.sin(tx.IRIS_ANGLE) * cam.scale)
        painted[r < 1] = (40, 90, 160)
        painted[r < 0.4] = (10, 10, 10)
    eyes = tx.bake(v, f, uv, face_uv, parts, [tx.BakeView(painted, cam)] + views[1:], size=256)
    assert np.abs(eyes.iris - (40, 90, 160)).max() < 8, eyes.iris

    def at(u, v_):
        return tex[int((1 - v_) * size), int(u * size)].astype(int)

    for name in ("eyeball_L", "eyeball_R"):
        u0, v0, u1, v1 = tx.TILES[name]
        assert at((u0 + u1) / 2, (v0 + v1) / 2).max() < 40, "a dark pupil in the middle"
        assert at((u0 + u1) / 2 + 0.3 * (u1 - u0), (v0 + v1) / 2).min() > 200, "white sclera"
    assert (tex[int(size * 0.9):, :] > 0).all(axis=2).mean() > 0.99, "tiles filled, no black"
    # the skin: what the photos see, every texel of the chart painted
    rows = round((1 - tx.STRIP) * size)
    assert (tex[:rows].max(axis=2) > 20).all()
    none = tx.bake(v, f, uv, face_uv, parts, views, size=1024, blend="none")
    assert tx.seam_step(tex, result.split) < 0.6 * tx.seam_step(none.texture, none.split)


def test_mouth_interior_lies_in_the_lips_shadow(monkeypatch):
    """The default face's gums and tongue: painted with today's colours (the committed atlas is
    what repaint_mouth makes), dark against the same paint at full light by GUMS_LIGHT and
    TONGUE_LIGHT, the tongue's tip lit, every other texel untouched."""
    from faceanim.face.default import default_face, default_parts

    m, parts = default_face(), default_parts()
    now = tx.repaint_mouth(m.vertices, m.faces, m.uv, m.face_uv, parts, m.texture)
    assert np.array_equal(now, m.texture), "rebuild it: python scripts/build_default_face.py --mouth-only"
    gums_light, tongue_light = tx.GUMS_LIGHT, tx.TONGUE_LIGHT
    monkeypatch.setattr(tx, "GUMS_LIGHT", 1.0)
    monkeypatch.setattr(tx, "TONGUE_LIGHT", 1.0)
    lit = tx.repaint_mouth(m.vertices, m.faces, m.uv, m.face_uv, parts, m.texture).astype(float)
    size = m.texture.shape[0]
    boxes = {}
    for key in ("gums", "tongue"):
        u0, v0, u1, v1 = tx.TILES[key]
        boxes[key] = np.s_[round((1 - v1) * size):round((1 - v0) * size), round(u0 * size):round(u1 * size)]
    outside = np.ones((size, size), dtype=bool)
    for box in boxes.values():
        outside[box] = False
    assert np.array_equal(lit[outside], m.texture[outside])
    bright = lit.sum(-1) > 150  # away from uint8 rounding
    ratio = m.texture.sum(-1) / np.maximum(lit.sum(-1), 1)
    gums = ratio[boxes["gums"]][bright[boxes["gums"]]]
    tongue = ratio[boxes["tongue"]][bright[boxes["tongue"]]]
    assert abs(np.median(gums) - gums_light) < 0.02  # the gums tile is mostly gums
    assert abs(np.percentile(tongue, 5) - tongue_light) < 0.03
    assert tongue.max() > 0.8 and np.mean(tongue > 0.5) > 0.01, "the tip at full light"


# ----------------------------------------------------------------------------- FaceWarehouse oracle
def _fit_camera(points, pixels, size):
    """Least-squares scaled orthographic camera from 3D points to pixels (affine, then the
    nearest scaled rotation)."""
    a = np.c_[points, np.ones(len(points))]
    sol = np.linalg.lstsq(a, pixels, rcond=None)[0]
    m = sol[:3].T * np.array([[1.0], [-1.0]])
    scale = float(np.linalg.norm(m, axis=1).mean())
    u, _, vt = np.linalg.svd(m / scale, full_matrices=False)
    r2 = u @ vt
    rot = np.vstack([r2, np.cross(r2[0], r2[1])])
    offset = pixels.mean(0) - scale * np.array([1.0, -1.0]) * (points.mean(0) @ rot.T)[:2]
    return ViewCamera(rot, scale, offset, size)


@pytest.fixture(scope="module")
def scan_with_truth():
    """The FaceWarehouse neutral scan with a true texture in its own UVs: its photo projected
    onto it (MediaPipe landmarks on a render of the scan and on the photo fit the camera)."""
    pytest.importorskip("mediapipe")
    from PIL import Image

    from faceanim.face.landmarks import detect_landmarks, detect_landmarks_in_image
    from faceanim.face.mesh import Mesh
    from faceanim.io.meshio import load_mesh

    scan = load_mesh(need(FACEWAREHOUSE / "pose_0.obj"))
    photo = np.asarray(Image.open(FACEWAREHOUSE / "pose_0.png").convert("RGB"))
    h, w = photo.shape[:2]
    marks = detect_landmarks(scan)
    pixels = detect_landmarks_in_image(photo)[:, :2] * [w, h]
    cam = _fit_camera(marks.positions, pixels, (w, h))
    assert np.abs(cam.project(marks.positions) - pixels).mean() < 4
    truth = tx.bake_texture(scan.vertices, scan.faces, scan.uv, scan.face_uv, {"skin": np.arange(scan.n_vertices)},
                            [tx.BakeView(photo, cam)], size=1024)
    return Mesh(scan.vertices, scan.faces, scan.uv, scan.face_uv, truth)


def _face_pixels(mesh, cam):
    """Pixels of the front half of the head (surface points in front of the middle of its depth)."""
    size = cam.size
    depth = ortho_depth(mesh.vertices, mesh.faces, cam.matrix, cam.offset, cam.direction, size)
    ys, xs = np.mgrid[0:size[1], 0:size[0]] + 0.5
    hit = depth > -np.inf
    a = (xs[hit] - cam.offset[0]) / cam.scale
    b = -(ys[hit] - cam.offset[1]) / cam.scale
    pts = np.stack([a, b, depth[hit]], 1) @ cam.rotation
    z = mesh.vertices[:, 2]
    mask = np.zeros(hit.shape, dtype=bool)
    mask[hit] = pts[:, 2] > (z.min() + z.max()) / 2
    return mask


def _unlit(mesh, cam):
    return ortho_render(mesh.vertices, mesh.faces, mesh.uv[mesh.face_uv], mesh.texture, cam.matrix,
                        cam.offset, cam.direction, cam.size)


def test_facewarehouse_rebake_matches_the_scan_from_a_new_angle(scan_with_truth):
    from faceanim.face.mesh import Mesh
    from faceanim.render import OffscreenRenderer

    scan = scan_with_truth
    parts = {"skin": np.arange(scan.n_vertices)}
    uv, face_uv = tx.atlas_uv(scan.vertices, scan.faces, parts)
    lit, unlit = [], []
    for yaw in (0, 90, -90):
        with OffscreenRenderer(scan, (512, 512), yaw=yaw, parallel=True) as r:
            cam = tx.view_camera(r)
            lit.append(tx.BakeView(r.render(), cam))
        unlit.append(tx.BakeView(_unlit(scan, cam), cam))
    with OffscreenRenderer(scan, (512, 512), yaw=45, parallel=True) as r:
        cam45 = tx.view_camera(r)
    face = _face_pixels(scan, cam45)
    reference = _unlit(scan, cam45).astype(float)
    # accuracy: albedo photos (no lighting) baked, rendered from 45 degrees, against the scan
    baked = tx.bake_texture(scan.vertices, scan.faces, uv, face_uv, parts, unlit, size=1024)
    again = _unlit(Mesh(scan.vertices, scan.faces, uv, face_uv, baked), cam45).astype(float)
    error = np.abs(again - reference)[face].mean()
    assert error < 3.0, error
    # seams: lit photos (each view lit differently, as real photos are) merged with and without
    # the pyramid; the pyramid's step across the merge lines is well under the hard split's
    pyramid = tx.bake(scan.vertices, scan.faces, uv, face_uv, parts, lit, size=1024)
    hard = tx.bake(scan.vertices, scan.faces, uv, face_uv, parts, lit, size=1024, blend="none")
    assert np.array_equal(pyramid.split, hard.split)
    step_pyramid = tx.seam_step(pyramid.texture, pyramid.split)
    step_hard = tx.seam_step(hard.texture, hard.split)
    assert step_pyramid < 0.5 * step_hard, (step_pyramid, step_hard)
