"""Issue 23: generated files of the kinds users really have, through the readers added since the
last fuzzing pass: photos (EXIF rotation, CMYK, 16-bit, alpha, animated GIF and WebP named .jpg),
videos (variable frame rate, rotation metadata, audio only, empty, one frame) and avatars that
need a compression extension. Each is read right (an oracle says what it must look like) or
refused in one line."""

import subprocess

import numpy as np
import pytest
from PIL import Image

from faceanim.errors import FaceAnimError


@pytest.fixture(scope="module")
def picture():
    """A real photo (scikit-image's astronaut), 512 x 512 RGB."""
    from skimage import data

    return data.astronaut()


def _close(a, b, tol=12.0):
    return a.shape == b.shape and float(np.abs(a.astype(float) - b).mean()) < tol


def test_photos_of_every_common_kind_read_upright_as_rgb(tmp_path, picture):
    from faceanim.build.photo import read_photo

    im = Image.fromarray(picture)
    tall = picture[:, 64:448]  # 512 x 384: a rotation shows in the shape
    cases = {}
    # EXIF orientation 6: the pixels are stored turned, the camera says "turn 90 clockwise to show"
    stored = Image.fromarray(np.rot90(tall, 1))  # what a phone held upright stores
    exif = Image.Exif()
    exif[0x0112] = 6
    stored.save(tmp_path / "exif.jpg", exif=exif.tobytes(), quality=95)
    cases["exif.jpg"] = tall
    im.convert("CMYK").save(tmp_path / "cmyk.jpg", quality=95)
    cases["cmyk.jpg"] = picture
    grey16 = (np.asarray(im.convert("L"), dtype=np.uint16) * 257)
    Image.fromarray(grey16).save(tmp_path / "grey16.png")
    cases["grey16.png"] = np.repeat(np.asarray(im.convert("L"))[..., None], 3, axis=2)
    rgba = np.dstack([picture, np.full(picture.shape[:2], 255, np.uint8)])
    Image.fromarray(rgba).save(tmp_path / "alpha.png")
    cases["alpha.png"] = picture
    frames = [im.convert("P", palette=Image.ADAPTIVE), Image.fromarray(255 - picture).convert("P")]
    frames[0].save(tmp_path / "animated.jpg", format="GIF", save_all=True, append_images=frames[1:], duration=100)
    cases["animated.jpg"] = picture  # the first frame
    im.save(tmp_path / "webp.jpg", format="WEBP", quality=95)
    cases["webp.jpg"] = picture
    for name, expected in cases.items():
        got = read_photo(tmp_path / name)
        assert got.dtype == np.uint8 and got.ndim == 3 and got.shape[2] == 3, name
        assert _close(got, expected, 16.0 if name == "animated.jpg" else 12.0), (name, got.shape, expected.shape)


def _ffmpeg():
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def _make(args, out):
    subprocess.run([_ffmpeg(), "-v", "error", "-y", *args, str(out)], check=True, capture_output=True)
    return out


def test_videos_of_every_common_kind_read_in_time_or_refused(tmp_path):
    from faceanim.io.video import video_frames, video_info

    src = ["-f", "lavfi", "-i", "testsrc=size=320x240:rate=25", "-t", "2", "-pix_fmt", "yuv420p"]
    plain = _make(src, tmp_path / "plain.mp4")
    rotated = _make(["-display_rotation", "90", "-i", str(plain), "-c", "copy"], tmp_path / "rotated.mp4")
    # variable frame rate: 10 frames 20 ms apart, then 40 frames 60 ms apart (about 2.6 s)
    vfr = _make([*src, "-vf", "setpts='if(lt(N,10),N*0.02/TB,(0.2+(N-10)*0.06)/TB)'", "-fps_mode", "vfr"],
                tmp_path / "vfr.mp4")
    one = _make(["-f", "lavfi", "-i", "testsrc=size=320x240:rate=25", "-frames:v", "1", "-pix_fmt", "yuv420p"],
                tmp_path / "one.mp4")
    sound_only = _make(["-f", "lavfi", "-i", "sine=frequency=440:duration=2"], tmp_path / "sound.mp4")
    (tmp_path / "empty.mp4").write_bytes(b"")

    info = video_info(plain)
    frames = list(video_frames(info))
    assert info.size == (320, 240) and len(frames) == 50 and frames[0].shape == (240, 320, 3)
    info = video_info(rotated)  # shown upright: the frames are turned, and the size says so
    turned = list(video_frames(info))
    assert info.size == (240, 320) and len(turned) == 50 and turned[0].shape == (320, 240, 3)
    assert _close(turned[0], np.rot90(frames[0], 1)) or _close(turned[0], np.rot90(frames[0], -1))
    info = video_info(vfr)  # frame k is at k / fps: as many frames as the clip lasts at that rate
    got = list(video_frames(info))
    assert abs(len(got) - info.duration * info.fps) <= 2, (len(got), info.duration, info.fps)
    info = video_info(one)
    assert len(list(video_frames(info))) == 1
    for bad in (sound_only, tmp_path / "empty.mp4"):
        with pytest.raises(FaceAnimError) as exc:
            list(video_frames(video_info(bad)))
        assert "\n" not in str(exc.value) and bad.name in str(exc.value)


@pytest.mark.parametrize("extension", ["EXT_meshopt_compression", "KHR_draco_mesh_compression",
                                       "KHR_mesh_quantization"])
def test_avatars_that_need_a_compression_extension_are_refused_in_one_line(tmp_path, extension, capsys):
    from test_scene import build_avatar

    from faceanim.cli import main
    from faceanim.io.scene import read_scene

    g = build_avatar()
    g.extensionsUsed = list(g.extensionsUsed or []) + [extension]
    g.extensionsRequired = list(g.extensionsRequired or []) + [extension]
    path = tmp_path / "compressed.glb"
    path.write_bytes(b"".join(g.save_to_bytes()))
    with pytest.raises(FaceAnimError) as exc:
        read_scene(path)
    assert extension in str(exc.value) and "\n" not in str(exc.value)
    rc = main(["rig", str(path), "-o", str(tmp_path / "out.glb")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and not (tmp_path / "out.glb").exists()
