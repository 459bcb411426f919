"""An artist's avatar: faceanim's ARKit and viseme shapes against the ones the artist made.

    python scripts/eval_avatar.py ../shared/data/avatars/vroid-sample.glb [--sheet docs/avatar_sheet.png]

The avatar's head is found as ``faceanim rig`` finds it (:func:`faceanim.avatar.find_head`), its
meshes welded into one face in the bind pose, landmarks detected and ARKit + visemes generated
(nothing of the artist's targets is read for that: they are not part of the geometry). Then each
generated shape is compared with the artist's target of the same name over the vertices the
artist's moves (more than 5% of its largest motion): cosine, and the relative error at the best
scale (the artist's shapes are often not at a human's full range), with the scale, and the error
as made (scale 1). Shapes the artist left empty (VRoid's ``jawOpen`` and ``tongueOut`` move
nothing) are listed and left out. Then how far each Left shape's figures are from its Right's, and
per blink the share of the eye's opening the front view still shows after it (faceanim's and the
artist's; ``faceanim.rig.arkit.eye_opening``).

The avatar is used for measuring only; it is never copied into the project.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from faceanim.autorig import auto_rig
from faceanim.avatar import avatar_face, find_head
from faceanim.io.scene import read_scene

MOVING = 0.05


def compare(gen: np.ndarray, art: np.ndarray) -> tuple[float, float, float, float]:
    """(cosine, best-scale relative error, best scale, relative error as made: scale 1) over the
    artist's moving region."""
    m = np.linalg.norm(art, axis=1)
    region = m > MOVING * m.max()
    g, a = gen[region].ravel(), art[region].ravel()
    gg = float(g @ g)
    scale = float(g @ a) / gg if gg > 0 else 0.0
    cos = float(g @ a) / max(np.sqrt(gg) * np.linalg.norm(a), 1e-30)
    size = np.linalg.norm(a)
    return cos, float(np.linalg.norm(scale * g - a) / size), scale, float(np.linalg.norm(g - a) / size)


def set_summary(rows: dict) -> list[tuple]:
    """Per set (ARKit, visemes) of ``rows`` (name -> :func:`compare`'s figures): (set, count,
    median cosine, median best-scale error, median scale, the four worst cosines as text)."""
    out = []
    for label, keep in (("ARKit", lambda n: not n.startswith("viseme_")), ("visemes", lambda n: n.startswith("viseme_"))):
        sel = {n: r for n, r in rows.items() if keep(n)}
        if sel:
            c, e, s = (np.median([r[k] for r in sel.values()]) for k in range(3))
            worst = sorted(sel.items(), key=lambda kv: kv[1][0])[:4]
            out.append((label, len(sel), c, e, s, ", ".join(f"{n} {r[0]:.2f}" for n, r in worst)))
    return out


def blinks(face, auto, artist) -> None:
    """Per eye: how much of its opening the front view still shows after faceanim's and after the
    artist's blink (``eye_opening``), and the blink's error as made against the artist's."""
    from faceanim.rig.arkit import eye_opening, face_eyes

    eyes = face_eyes(face)
    print("\n| blink | eye seen at rest | open after faceanim's | open after the artist's | error as made |")
    print("|---|---|---:|---:|---:|")
    for slit, name in (("eye_L", "eyeBlinkLeft"), ("eye_R", "eyeBlinkRight")):
        if name not in auto.shapes or name not in artist:
            continue
        error = compare(auto.shapes[name], artist[name])[3]
        rest = eye_opening(face, slit, eyes)
        if rest is None:  # the front view finds no opening: whether a blink closes cannot be told
            print(f"| {name} | no | | | {error:.2f} |")
            continue
        left = [getattr(eye_opening(face, slit, eyes, face.mesh.vertices + d[name]), "area", 0.0) / rest.area
                for d in (auto.shapes, artist)]
        print(f"| {name} | yes | {left[0]:.1%} | {left[1]:.1%} | {error:.2f} |")


def load_avatar(path: Path, style: str = "realistic"):
    """(the avatar's head welded into one Face, faceanim's rig of it (``auto_rig`` ARKit +
    visemes), the artist's shapes of the same names on the welded face, the names of the
    artist's shapes that move nothing, the seconds the rig took)."""
    t = time.perf_counter()
    scene = read_scene(path)
    head, companions = find_head(scene)
    meshes = [head, *companions]
    face, parts = avatar_face(scene, meshes)
    auto = auto_rig(face, ["arkit", "visemes"], style=style)
    took = time.perf_counter() - t
    # the artist's targets on the welded face (each welded vertex: its first merged copy)
    art_rows = []
    for mi, (offset, count, index) in zip(meshes, parts):
        first = np.full(count, -1)
        first[index[::-1]] = np.arange(len(index))[::-1]
        art_rows.append((mi, first))
    names = [n for n in auto.shapes if all(n in scene.meshes()[mi].target_names for mi in meshes[:1])]
    artist = {}
    for mi, first in art_rows:
        targets = scene.targets(mi, names)
        for n in names:
            artist.setdefault(n, []).append(targets[n][first])
    artist = {n: np.vstack(v) for n, v in artist.items()}
    empty = [n for n, d in artist.items() if np.abs(d).max() == 0]
    face.mesh.name = scene.meshes()[head].name
    return face, auto, artist, empty, took


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("avatar", type=Path)
    ap.add_argument("--sheet", type=Path, help="write a picture sheet (artist's row, faceanim's row) here")
    ap.add_argument("--style", choices=("realistic", "stylised"), default="realistic",
                    help="faceanim rig's --style (the blinks' lids)")
    args = ap.parse_args(argv)
    face, auto, artist, empty, took = load_avatar(args.avatar, args.style)
    names = list(artist)
    rows = {n: compare(auto.shapes[n], artist[n]) for n in names if n not in empty}
    print(f"{face.mesh.name}: {face.mesh.n_vertices} welded vertices, rig {took:.1f} s "
          f"(read, find, land, rig)")
    print(f"the artist's shapes that move nothing (left out): {', '.join(empty) or 'none'}\n")
    print("| set | shapes | median cosine | median best-scale error | median scale | worst cosine |")
    print("|---|---:|---:|---:|---:|---|")
    for label, count, cos, err, scale, worst in set_summary(rows):
        print(f"| {label} | {count} | {cos:.2f} | {err:.2f} | {scale:.2f} | {worst} |")
    print()
    for n, (c, e, s, raw) in rows.items():
        print(f"    {n}: cosine {c:.3f} best-scale error {e:.3f} scale {s:.2f} error as made {raw:.3f}")
    pairs = [(n, n.replace("Left", "Right")) for n in rows if "Left" in n and n.replace("Left", "Right") in rows]
    if pairs:
        gap = max(pairs, key=lambda p: abs(rows[p[0]][0] - rows[p[1]][0]))
        print(f"\nleft against right, {len(pairs)} pairs: the largest cosine difference "
              f"{abs(rows[gap[0]][0] - rows[gap[1]][0]):.3f} ({gap[0]} {rows[gap[0]][0]:.3f}, {gap[1]} {rows[gap[1]][0]:.3f})")
    blinks(face, auto, artist)
    if args.sheet:
        from faceanim.render import save_png
        from faceanim.render.gl import OffscreenRenderer

        shown = ["eyeBlinkLeft", "eyeBlinkRight", "jawOpen", "mouthSmileLeft", "browInnerUp", "mouthPucker",
                 "noseSneerLeft", "mouthFunnel", "viseme_aa", "viseme_PP", "viseme_FF", "viseme_O"]
        shown = [n for n in shown if n in auto.shapes]
        size = 220
        lines = []
        for source in (artist, auto.shapes):
            with OffscreenRenderer(face.mesh, size=(size, size), **face.view()) as r:
                cells = []
                for n in shown:
                    d = source.get(n, np.zeros_like(face.mesh.vertices))
                    cells += [r.render(face.mesh.vertices + d), np.full((size, 4, 3), 255, np.uint8)]
            lines += [np.hstack(cells), np.full((4, len(shown) * (size + 4), 3), 255, np.uint8)]
        args.sheet.parent.mkdir(parents=True, exist_ok=True)
        save_png(args.sheet, np.vstack(lines[:-1]))
        print(f"\nwrote {args.sheet}: top the artist's, bottom faceanim's; columns {', '.join(shown)}")


if __name__ == "__main__":
    from faceanim.errors import FaceAnimError

    try:
        main()
    except FaceAnimError as exc:  # a missing or damaged avatar: one line, as faceanim's commands say it
        print(f"{Path(__file__).name}: error: {exc}", file=sys.stderr)
        sys.exit(2)
