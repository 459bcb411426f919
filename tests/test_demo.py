"""The demo end to end (small and fast): every promised file, consistent with the rig."""

import imageio_ffmpeg
import numpy as np
import pygltflib
from PIL import Image

from faceanim.cli import main


def test_demo_writes_glb_mp4_and_pngs(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--fps", "5", "--size", "128", "--quiet"]) == 0
    names = {p.name for p in out.iterdir()}
    gde = ["smile", "sadness", "anger", "A"]
    facs = [f"facs_{e}" for e in ("joy", "sadness", "surprise", "fear", "anger", "disgust")]
    head = ["blink", "jaw_open"]  # the head's own shapes: lids over its eyeballs, the jaw onto its teeth
    assert names == {"demo.glb", "demo.mp4", "neutral.png"} | {f"{n}.png" for n in gde + facs + head}
    assert "wrote 15 files" in capsys.readouterr().out

    gltf = pygltflib.GLTF2().load(str(out / "demo.glb"))
    assert gltf.meshes[0].extras["targetNames"] == gde + facs + head
    n_keys = gltf.accessors[gltf.animations[0].samplers[0].input].count

    reader = imageio_ffmpeg.read_frames(str(out / "demo.mp4"))
    meta = next(reader)
    assert meta["size"] == (128, 128)
    assert sum(1 for _ in reader) == n_keys  # one video frame per animation sample

    neutral = np.asarray(Image.open(out / "neutral.png")).astype(float)
    for name in gde + facs + head:
        img = np.asarray(Image.open(out / f"{name}.png")).astype(float)
        changed = np.abs(img - neutral).mean(-1) > 20
        assert 20 < changed.sum() < 0.25 * changed.size  # the face changed, locally


def test_render_command(tmp_path, base_face):
    from faceanim.io.meshio import save_mesh

    save_mesh(base_face, tmp_path / "f.obj")
    assert main(["render", str(tmp_path / "f.obj"), "-o", str(tmp_path / "f.png"), "--size", "96"]) == 0
    img = np.asarray(Image.open(tmp_path / "f.png"))
    assert img.shape == (96, 96, 3) and img.std() > 10
