"""The bad-input rule, command by command, as one table: every case runs ``faceanim ARGS`` in a fresh
folder and must end with exit code 2, exactly one stderr line starting with 'faceanim ' that holds a
specific phrase of the expected message (a regular expression), no control characters on stderr,
and the folder exactly as it was (no output, no hidden temporary file, nothing replaced), TMPDIR
empty too.

A representative subset of a larger sweep (several hundred hostile inputs over every command and
reader, plus truncated and byte-flipped valid files). Each case is quick: outputs and inputs are
checked before any real work. Cases that fail today are ``xfail(strict=True)`` with the reason:
when one is fixed it turns into an XPASS failure, so the mark has to come off.
"""

import hashlib
import io
import json
import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

# ====================================================================== valid inputs, made once
TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    """Valid inputs for every reader: the default head as a textured OBJ (with its .mtl and
    texture), as an OBJ without UVs or texture (its outputs are small: a write limit can fall between
    them), and as GLB, its landmarks, handles, a wire template, an edit file, a .fap file, a scene
    script, a WAV and its transcript, the average face model."""
    from faceanim.face.default import default_face, default_landmarks
    from faceanim.face.mesh import Mesh
    from faceanim.io.meshio import save_mesh
    from faceanim.rig.wires import WireTemplate, default_wires

    a = tmp_path_factory.mktemp("assets")
    base = default_face()
    save_mesh(base, a / "face.obj")
    save_mesh(Mesh(base.vertices, base.faces, polygon_sizes=base.polygon_sizes, name="bare"), a / "bare.obj")
    save_mesh(base, a / "face.glb")
    lms = default_landmarks(base)
    lms.save(a / "lm478.json")
    wires = default_wires(lms.positions)
    WireTemplate(wires, [w.reference.control + 1e-3 for w in wires.wires], np.ones(len(wires.wires)),
                 base.n_vertices).save(a / "smile.wires.json")
    WireTemplate(wires, [w.reference.control for w in wires.wires], np.ones(len(wires.wires)),
                 base.n_vertices).save(a / "neutral.wires.json")
    v = base.vertices
    (a / "gde.json").write_text(json.dumps({"method": "gde", "elements": [
        {"control": v[61].tolist(), "offset": [0, 0.003, 0], "metric": "edges", "extent": 4}]}))
    (a / "rbf.json").write_text(json.dumps({"method": "rbf", "handles": v[[4, 33, 263, 152]].tolist(),
                                            "offsets": [[0, 0.002, 0]] + [[0, 0, 0]] * 3}))
    (a / "joy.fap").write_text(_fap("2.1 joy 10 1"))
    (a / "scene.yaml").write_text("fps: 10\nevents:\n  - expression: joy\n    at: 0\n    duration: 0.5\n")
    import soundfile as sf

    sf.write(str(a / "short.wav"), (0.3 * np.sin(np.arange(16000) / 7.0)).astype(np.float32), 16000,
             subtype="PCM_16")
    (a / "short.txt").write_text("hello\n")
    from importlib import resources

    (a / "average_face.npz").write_bytes(resources.files("faceanim").joinpath("assets", "average_face.npz")
                                         .read_bytes())
    return a


def _fap(header, values="0 100"):
    return f"{header}\n{' '.join(['0', '0', '1'] + ['0'] * 65)}\n{values}\n"


def _wav_header(rate=16000, channels=1, bits=16, data_len=0, fmt=1):
    fmtc = struct.pack("<HHIIHH", fmt, channels, rate, rate * channels * bits // 8, channels * bits // 8, bits)
    body = b"WAVE" + b"fmt " + struct.pack("<I", 16) + fmtc + b"data" + struct.pack("<I", data_len)
    return b"RIFF" + struct.pack("<I", (len(body) + data_len) & 0xFFFFFFFF) + body


def _npz_with(assets, **arrays):
    d = dict(np.load(assets / "average_face.npz"))
    d.update(arrays)
    b = io.BytesIO()
    np.savez(b, **d)
    return b.getvalue()


def _wires_with(assets, mutate):
    d = json.loads((assets / "smile.wires.json").read_text())
    mutate(d)
    return json.dumps(d)


def _glb_json_chunk(js: str) -> bytes:
    j = js.encode()
    j += b" " * (-len(j) % 4)
    body = struct.pack("<II", len(j), 0x4E4F534A) + j
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


# ====================================================================== the table
# (id, args, files in the case folder, expected phrase (regex), reason if it fails today or None)
# In args and files, "{A}" is the assets folder. A file value is text, bytes, a callable of the assets
# folder (returning text or bytes), ("link", target) or ("dir",).
LM = ["--landmarks", "{A}/lm478.json"]
WIRES_APPLY = ["wires", "apply", "--base", "{A}/face.obj", *LM, "--wires"]
DEEP = "[" * 100_000 + "]" * 100_000

CASES = [
    # ---------------------------------------------------------------- meshes
    ("mesh_missing", ["render", "nope.obj", "-o", "o.png"], {}, r"mesh file 'nope\.obj' does not exist", None),
    ("mesh_empty_obj", ["render", "in.obj", "-o", "o.png"], {"in.obj": ""}, r"is empty \(no vertices or no faces\)",
     None),
    ("mesh_folder", ["render", "in.obj", "-o", "o.png"], {"in.obj": ("dir",)}, r"'in\.obj' is a folder", None),
    ("mesh_nan_obj", ["deform", "in.obj", "--handles", "{A}/gde.json", "-o", "o.obj"],
     {"in.obj": TRI + "v nan 0 0\nf 1 2 4\n"}, r"line 4: NaN or infinite coordinates", None),
    ("mesh_binary_obj", ["render", "in.obj", "-o", "o.png"], {"in.obj": bytes(range(256)) * 8},
     r"binary data in a text OBJ file", None),
    ("mesh_etc_passwd_as_obj", ["render", "in.obj", "-o", "o.png"], {"in.obj": ("link", "/etc/passwd")},
     r"'in\.obj' is empty", None),
    ("mesh_ply_claims_2GB", ["render", "in.ply", "-o", "o.png"],
     {"in.ply": b"ply\nformat binary_little_endian 1.0\nelement vertex 500000000\nproperty float x\n"
                b"property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                b"end_header\n" + b"\0" * 64}, r"PLY header promises more elements than the file holds", None),
    ("mesh_ply_point_cloud", ["render", "in.ply", "-o", "o.png"],
     {"in.ply": "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                "end_header\n0 0 0\n1 0 0\n0 1 0\n"}, r"not a point cloud", None),
    ("mesh_glb_deep_json", ["render", "in.glb", "-o", "o.png"], {"in.glb": _glb_json_chunk(DEEP)},
     r"not a valid GLB file", None),
    ("mesh_gltf_buffer_etc_passwd", ["render", "in.gltf", "-o", "o.png"],
     {"in.gltf": json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": "/etc/passwd", "byteLength": 64}],
                             "bufferViews": [{"buffer": 0, "byteLength": 36}],
                             "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3}],
                             "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
                             "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]})},
     r"refers to a file outside its folder", None),
    ("mesh_uv_index_without_uvs", ["render", "in.obj", "-o", "o.png"],
     {"in.obj": TRI + "v 0 0 1\nf 1/5 2/5 3/5\nf 1 2 4\n"}, r"texture coordinate",
     None),
    ("mesh_wrong_suffix", ["render", "in.stl", "-o", "o.png"], {"in.stl": TRI + "f 1 2 3\n"},
     r"unsupported format '\.stl'", None),
    ("mesh_texture_bomb", ["render", "in.obj", "-o", "o.png"],
     {"in.obj": lambda a: (a / "face.obj").read_bytes(), "face.mtl": lambda a: (a / "face.mtl").read_bytes(),
      "face.texture.png": lambda a: _png_bomb()}, r"decompression bombs", None),
    ("mesh_binary_mtl", ["render", "in.obj", "-o", "o.png"],
     {"in.obj": lambda a: (a / "face.obj").read_bytes(), "face.mtl": b"\0\1\2" * 100,
      "face.texture.png": lambda a: (a / "face.texture.png").read_bytes()}, r"material file .* is not a text file",
     None),
    ("mesh_fifo_names_the_problem", ["render", "in.obj", "-o", "o.png"], {"in.obj": ("fifo",)},
     r"not a (regular )?file|is a (pipe|FIFO|special)",
     None),
    ("mesh_degenerate_long_line", ["render", "in.obj", "-o", "o.png"],
     {"in.obj": "v " + "1 " * 100_000 + "\nf 1 1 1\n"}, r"degenerate|no area|empty|same vertex",
     None),
    ("mesh_glb_header_claims_2GB", ["render", "in.glb", "-o", "o.png"],
     {"in.glb": lambda a: struct.pack("<III", 0x46546C67, 2, 2_000_000_000) + (a / "face.glb").read_bytes()[12:]},
     r"not a valid GLB file|truncated|length",
     None),
    ("mesh_gltf_image_etc_passwd", ["render", "in.gltf", "-o", "o.png"], {"in.gltf": lambda a: _gltf_image_passwd(a),
                                                                           "b.bin": lambda a: _gltf_bin(a)},
     r"texture|image", None),
    ("mesh_glb_corrupt_texture", ["render", "in.glb", "-o", "o.png"], {"in.glb": lambda a: _glb_corrupt_texture(a)},
     r"texture|image", None),
    ("mesh_texture_name_escape_codes", ["render", "in.obj", "-o", "o.png"],
     {"in.obj": lambda a: (a / "face.obj").read_bytes(), "face.mtl": "newmtl faceanim_skin\nmap_Kd \x1b[31mred.png\n",
      "\x1b[31mred.png": b"not a png"}, r"cannot be read", None),
    # ---------------------------------------------------------------- landmarks
    ("landmarks_deep_json", ["au", "{A}/face.obj", "--landmarks", "lm.json", "--au", "12", "-o", "o.obj"],
     {"lm.json": DEEP}, r"nested too deeply", None),
    ("landmarks_nan", ["landmarks", "{A}/face.obj", "--from", "lm.json", "-o", "o.json"],
     {"lm.json": '{"points": [{"index": 0, "position": [NaN, 0, 0]}]}'}, r"point 0 has an invalid position: NaN",
     None),
    ("landmarks_far_from_surface", ["au", "{A}/face.obj", "--landmarks", "lm.json", "--au", "12", "-o", "o.obj"],
     {"lm.json": lambda a: json.dumps({"points": [dict(p, position=[x + 5 for x in p["position"]]) for p in
                                                  json.loads((a / "lm478.json").read_text())["points"]]})},
     r"from the surface of", None),
    ("landmarks_dev_zero", ["au", "{A}/face.obj", "--landmarks", "lm.json", "--au", "12", "-o", "o.obj"],
     {"lm.json": ("link", "/dev/zero")}, r"landmark file 'lm\.json'", None),
    ("landmarks_name_with_escape_codes", ["landmarks", "{A}/face.obj", "--from", "lm.json", "-o", "o.json"],
     {"lm.json": json.dumps({"points": [{"name": "\x1b]0;x\x07", "position": [0, 0, 0]},
                                        {"name": "\x1b]0;x\x07", "position": [0, 0, 0]}]})}, r"repeats point 0",
     None),
    # ---------------------------------------------------------------- handles
    ("handles_not_json", ["deform", "{A}/face.obj", "--handles", "h.json", "-o", "o.obj"], {"h.json": "{"},
     r"handle file 'h\.json' is not valid JSON", None),
    ("handles_unknown_kernel", ["deform", "{A}/face.obj", "--handles", "h.json", "-o", "o.obj"],
     {"h.json": lambda a: json.dumps(dict(json.loads((a / "rbf.json").read_text()), kernel="cosine"))},
     r"kernel", None),
    ("handles_coincident", ["deform", "{A}/face.obj", "--handles", "h.json", "-o", "o.obj"],
     {"h.json": json.dumps({"method": "rbf", "handles": [[0, 0, 0]] * 4, "offsets": [[0, 0, 0]] * 4})},
     r"coincid", None),
    ("handles_gde_extent_1e9", ["deform", "{A}/face.obj", "--handles", "h.json", "-o", "o.obj"],
     {"h.json": lambda a: json.dumps({"method": "gde", "elements": [
         dict(json.loads((a / "gde.json").read_text())["elements"][0], extent=10**9)]})}, r"extent", None),
    # ---------------------------------------------------------------- wire templates and edits
    ("wires_not_a_template", WIRES_APPLY + ["t.json", "-o", "o.obj"], {"t.json": "[1]"},
     r"not a faceanim wire template", None),
    ("wires_other_base", WIRES_APPLY + ["t.json", "-o", "o.obj"],
     {"t.json": lambda a: _wires_with(a, lambda d: d.__setitem__("n_vertices", 12))},
     r"extracted on a base face with 12 vertices", None),
    ("wires_side_unknown_slit", WIRES_APPLY + ["t.json", "-o", "o.obj"],
     {"t.json": lambda a: _wires_with(a, lambda d: d["wires"][0].__setitem__("side", ["nose", "upper"]))},
     r"side|slit", None),
    ("wires_scale_inf_warning", WIRES_APPLY + ["t.json", "-o", "o.obj"],
     {"t.json": lambda a: _wires_with(a, lambda d: d["wires"][0].__setitem__("scale", float("inf")))},
     r"NaN or infinite|scale", None),
    ("wires_scale_1e300", WIRES_APPLY + ["t.json", "-o", "o.obj"],
     {"t.json": lambda a: _wires_with(a, lambda d: d["wires"][0].__setitem__("scale", 1e300))},
     r"scale|absurd|too large", None),
    ("wires_control_point_1e300", WIRES_APPLY + ["t.json", "-o", "o.obj"],
     {"t.json": lambda a: _wires_with(a, lambda d: d["wires"][0]["wire"][1].__setitem__(0, 1e300))},
     r"absurd|too large|control point", None),
    ("wires_reference_1e300_warning", WIRES_APPLY + ["t.json", "-o", "o.obj"],
     {"t.json": lambda a: _wires_with(a, lambda d: d["wires"][0]["reference"][1].__setitem__(0, 1e300))},
     r"t\.json", None),
    ("wires_blend_unknown_function", ["wires", "blend", "--base", "{A}/face.obj", *LM, "--from",
                                      "{A}/smile.wires.json", "--to", "{A}/smile.wires.json", "--eyes", "wobbly",
                                      "-o", "o.glb"], {}, r"unknown blending function 'wobbly'", None),
    ("wires_blend_samples_1e308", ["wires", "blend", "--base", "{A}/face.obj", *LM, "--from",
                                   "{A}/neutral.wires.json", "--to", "{A}/smile.wires.json", "--mouth", "0,1e308",
                                   "--frames", "3", "-o", "o.glb"], {}, r"blending|mouth|sample",
     None),
    ("edit_unknown_wire", WIRES_APPLY + ["{A}/smile.wires.json", "--edit", "e.json", "-o", "o.obj"],
     {"e.json": json.dumps({"edits": [{"wire": "ears", "scale": 1}]})}, r"edit 0: unknown wire 'ears'", None),
    ("edit_scale_list", WIRES_APPLY + ["{A}/smile.wires.json", "--edit", "e.json", "-o", "o.obj"],
     {"e.json": json.dumps({"edits": [{"wire": "brow_L", "scale": [1]}]})}, r"edit 0.*scale",
     None),
    ("edit_control_text", WIRES_APPLY + ["{A}/smile.wires.json", "--edit", "e.json", "-o", "o.obj"],
     {"e.json": json.dumps({"edits": [{"wire": "brow_L", "control": "x", "offset": [0, 0, 0]}]})},
     r"edit 0.*control", None),
    # ---------------------------------------------------------------- .fap files
    ("fap_frames_2e9", ["fap", "play", "in.fap", "-o", "o.glb"], {"in.fap": _fap("2.1 joy 25 2000000000")},
     r"more than faceanim's limit", None),
    ("fap_nul", ["fap", "play", "in.fap", "-o", "o.glb"], {"in.fap": "2.1 joy\0 25 1\n"}, r"NUL byte", None),
    ("fap_value_nan", ["fap", "play", "in.fap", "-o", "o.glb"], {"in.fap": _fap("2.1 joy 10 1", "0 nan")},
     r"not a finite number", None),
    ("fap_write_nothing", ["fap", "write", "-o", "o.fap"], {}, r"give --expression, --fap NAME=VALUE", None),
    # ---------------------------------------------------------------- audio and transcripts
    ("audio_empty", ["say", "--audio", "in.wav", "--transcript", "{A}/short.txt", "-o", "o.fap"], {"in.wav": b""},
     r"'in\.wav' is empty", None),
    ("audio_claims_2GB", ["say", "--audio", "in.wav", "--transcript", "{A}/short.txt", "-o", "o.fap"],
     {"in.wav": _wav_header(data_len=2_000_000_000) + b"\1\0" * 500}, r"truncated or damaged", None),
    ("audio_float_nan", ["fap", "play", "{A}/joy.fap", "--audio", "in.wav", "-o", "o.glb"],
     {"in.wav": _wav_header(bits=32, fmt=3, data_len=400) + np.full(100, np.nan, "<f4").tobytes()},
     r"NaN or infinite samples", None),
    ("audio_mp3_garbage", ["say", "--audio", "in.mp3", "--transcript", "{A}/short.txt", "-o", "o.fap"],
     {"in.mp3": b"ID3" + bytes(range(256)) * 12}, r"is not audio that faceanim can read",
     None),
    ("audio_missing_under_mp4", ["fap", "play", "{A}/joy.fap", "--audio", "nope.wav", "--size", "16", "-o", "o.mp4"],
     {}, r"'nope\.wav' does not exist",
     None),
    ("audio_truncated_under_mp4", ["fap", "play", "{A}/joy.fap", "--audio", "in.wav", "--size", "16", "-o", "o.mp4"],
     {"in.wav": _wav_header(data_len=2_000_000_000) + b"\1\0" * 500}, r"truncated or damaged",
     None),
    ("transcript_binary", ["say", "--audio", "{A}/short.wav", "--transcript", "t.txt", "-o", "o.fap"],
     {"t.txt": b"\xff\xfe\x00\x81" * 50}, r"not UTF-8 text", None),
    ("say_empty_text", ["say", "", "-o", "o.fap"], {}, r"text|nothing to say|empty", None),
    # ---------------------------------------------------------------- scene scripts
    ("script_missing", ["direct", "nope.yaml", "-o", "o.fap"], {}, r"script 'nope\.yaml' does not exist", None),
    ("script_billion_laughs", ["direct", "s.yaml", "-o", "o.fap"],
     {"s.yaml": "a: &a [x,x,x,x,x,x,x,x,x]\n" + "".join(
         f"{chr(98 + i)}: &{chr(98 + i)} [" + ",".join([f"*{chr(97 + i)}"] * 9) + "]\n" for i in range(8))},
     r"s\.yaml", None),
    ("script_python_tag", ["direct", "s.yaml", "-o", "o.fap"],
     {"s.yaml": "!!python/object/apply:os.system ['echo PWNED']\n"}, r"s\.yaml", None),
    ("script_unknown_key", ["direct", "s.yaml", "-o", "o.fap"], {"s.yaml": "fps: 10\nfpz: 3\nevents: []\n"},
     r"unknown key 'fpz'", None),
    ("script_deep_json", ["direct", "s.json", "-o", "o.fap"], {"s.json": DEEP}, r"nested too deeply", None),
    ("script_json_int_100k_digits", ["direct", "s.json", "-o", "o.fap"],
     {"s.json": '{"fps": ' + "9" * 100_000 + ', "events": []}'}, r"s\.json",
     None),
    # ---------------------------------------------------------------- the average face model
    ("npz_random_bytes", ["preprocess", "{A}/face.obj", *LM, "--grid", "20", "--reference", "r.npz", "-o", "o.obj"],
     {"r.npz": bytes(range(256)) * 4}, r"not an average face model", None),
    ("npz_truncated", ["preprocess", "{A}/face.obj", *LM, "--grid", "20", "--reference", "r.npz", "-o", "o.obj"],
     {"r.npz": lambda a: (a / "average_face.npz").read_bytes()[:5000]}, r"average face model",
     None),
    ("npz_landmarks_wrong_shape", ["preprocess", "{A}/face.obj", *LM, "--grid", "20", "--reference", "r.npz",
                                   "-o", "o.obj"], {"r.npz": lambda a: _npz_with(a, landmarks=np.zeros(3))},
     r"average face model|landmarks", None),
    ("npz_landmarks_all_zero", ["preprocess", "{A}/face.obj", *LM, "--grid", "20", "--reference", "r.npz",
                                "-o", "o.obj"], {"r.npz": lambda a: _npz_with(a, landmarks=np.zeros((478, 3)))},
     r"average face model|landmarks|degenerate",
     None),
    # ---------------------------------------------------------------- outputs
    ("out_missing_folder", ["render", "--size", "32", "-o", "nodir/o.png"], {},
     r"folder 'nodir' does not exist; create it first", None),
    ("out_is_folder", ["fap", "write", "--expression", "joy", "-o", "o.fap"], {"o.fap": ("dir",)},
     r"'o\.fap' is a folder", None),
    ("out_parent_is_file", ["landmarks", "{A}/face.obj", "--from", "{A}/lm478.json", "-o", "f.txt/o.json"],
     {"f.txt": "keep"}, r"'f\.txt' is not a folder", None),
    ("out_wrong_suffix", ["deform", "{A}/face.obj", "--handles", "{A}/gde.json", "-o", "o.stl"], {},
     r"must end in one of: \.obj, \.ply, \.glb", None),
    ("out_link_to_dev_full", ["render", "--size", "32", "-o", "o.png"], {"o.png": ("link", "/dev/full")},
     r"not a regular file", None),
    ("out_in_proc", ["fap", "write", "--expression", "joy", "-o", "/proc/o.fap"], {}, r"not writable|cannot write",
     None),
    ("out_name_300_bytes", ["fap", "write", "--expression", "joy", "-o", "x" * 300 + ".fap"], {},
     r"File name too long|longer than 255 bytes", None),
    # the grid OBJ (32 KB) is written, its landmarks (58 KB) are not; the untextured head, since the
    # textured one's grid takes its 600 KB texture along and that write fails first
    ("out_second_output_fails", ["@fsize=40000", "preprocess", "{A}/bare.obj", *LM, "--grid", "20", "-o", "o.obj"],
     {}, r"cannot write output 'o\.landmarks\.json'", None),
    ("opt_forward_unknown_axis", ["deform", "{A}/face.obj", "--handles", "{A}/gde.json", "--forward", "up",
                                  "-o", "o.obj"], {}, r"--forward",
     None),
    ("out_preprocess_landmarks_exist", ["preprocess", "{A}/face.obj", *LM, "--grid", "20", "-o", "o.obj"],
     {"o.landmarks.json": "mine"}, r"'o\.landmarks\.json' .* exists already", None),
    ("out_demo_is_file", ["demo", "--out", "d"], {"d": "keep"}, r"--out 'd' is a file", None),
    # ---------------------------------------------------------------- numbers and names
    ("opt_size_1e9", ["render", "-o", "o.png", "--size", "1e9"], {}, r"--size must be at least 16 and at most 4096",
     None),
    ("opt_fps_0", ["fap", "write", "--expression", "joy", "--fps", "0", "-o", "o.fap"], {}, r"--fps must be more than 0",
     None),
    ("opt_unknown_emotion", ["au", "--emotion", "glee", "-o", "o.obj"], {}, r"glee", None),
    ("opt_unknown_au", ["au", "--au", "99", "-o", "o.obj"], {}, r"99", None),
    ("opt_magnitude_nan", ["au", "--au", "12", "--magnitude", "nan", "-o", "o.obj"], {}, r"magnitude|intensity",
     None),
    ("opt_unknown_voice", ["say", "hi", "--voice", "klingon", "-o", "o.fap"], {}, r"voice 'klingon'|klingon", None),
]


def _png_bomb() -> bytes:
    import zlib

    def chunk(t, data):
        return struct.pack(">I", len(data)) + t + data + struct.pack(">I", zlib.crc32(t + data) & 0xFFFFFFFF)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 100000, 100000, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 1000)) + chunk(b"IEND", b""))


def _glb_corrupt_texture(a) -> bytes:
    """face.glb with its embedded PNG zeroed after the signature and IHDR length (same size)."""
    b = bytearray((a / "face.glb").read_bytes())
    jlen = struct.unpack("<I", b[12:16])[0]
    js = json.loads(b[20:20 + jlen])
    view = js["bufferViews"][js["images"][0]["bufferView"]]
    start = 20 + jlen + 8 + view.get("byteOffset", 0)
    b[start + 16:start + view["byteLength"]] = bytes(view["byteLength"] - 16)
    return bytes(b)


def _gltf_bin(a) -> bytes:
    from faceanim.io.meshio import load_mesh

    m = load_mesh(a / "face.obj")
    return m.vertices.astype("<f4").tobytes() + m.faces.astype("<u4").tobytes() + m.uv.astype("<f4").tobytes()


def _gltf_image_passwd(a) -> str:
    from faceanim.io.meshio import load_mesh

    m = load_mesh(a / "face.obj")
    nv, nf = m.n_vertices, m.n_faces
    lo, hi = m.vertices.min(0).tolist(), m.vertices.max(0).tolist()
    return json.dumps({
        "asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "scene": 0, "nodes": [{"mesh": 0}],
        "buffers": [{"uri": "b.bin", "byteLength": nv * 12 + nf * 12 + nv * 8}],
        "bufferViews": [{"buffer": 0, "byteLength": nv * 12}, {"buffer": 0, "byteOffset": nv * 12, "byteLength": nf * 12},
                        {"buffer": 0, "byteOffset": nv * 12 + nf * 12, "byteLength": nv * 8}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": nv, "min": lo, "max": hi},
                      {"bufferView": 1, "componentType": 5125, "type": "SCALAR", "count": nf * 3},
                      {"bufferView": 2, "componentType": 5126, "type": "VEC2", "count": nv}],
        "images": [{"uri": "/etc/passwd"}], "textures": [{"source": 0}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 2}, "indices": 1, "material": 0}]}]})


# ====================================================================== running a case
def _materialise(folder: Path, files: dict, assets: Path) -> None:
    for name, value in files.items():
        p = folder / name
        if callable(value):
            value = value(assets)
        if isinstance(value, tuple):
            if value[0] == "link":
                os.symlink(value[1], p)
            elif value[0] == "dir":
                p.mkdir()
            elif value[0] == "fifo":
                os.mkfifo(p)
            continue
        if isinstance(value, str):
            p.write_text(value, encoding="utf-8")
        else:
            p.write_bytes(value)


def _state(folder: Path) -> dict:
    """Every entry under ``folder`` (hidden ones too) with what it is and its content's hash."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(folder):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            rel = str(p.relative_to(folder))
            if p.is_symlink():
                out[rel] = ("link", os.readlink(p))
            elif p.is_dir():
                out[rel] = ("dir",)
            elif p.is_file():
                out[rel] = ("file", hashlib.sha1(p.read_bytes()).hexdigest())
            else:
                out[rel] = ("special",)
    return out


def _params():
    out = []
    for cid, args, files, phrase, reason in CASES:
        marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
        out.append(pytest.param(args, files, phrase, id=cid, marks=marks))
    return out


def test_the_table_has_40_to_80_distinct_cases():
    ids = [c[0] for c in CASES]
    assert len(ids) == len(set(ids)) and 40 <= len(ids) <= 80


@pytest.mark.parametrize("args,files,phrase", _params())
def test_bad_input_is_one_clean_line_and_leaves_nothing(tmp_path, assets, args, files, phrase):
    work = tmp_path / "cwd"
    work.mkdir()
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    _materialise(work, files, assets)
    before, assets_before = _state(work), _state(assets)
    fsize = None
    if args and args[0].startswith("@fsize="):  # a per-file size limit (RLIMIT_FSIZE): a write fails midway
        fsize, args = int(args[0].split("=")[1]), args[1:]
    argv = [a.replace("{A}", str(assets)) for a in args]
    env = dict(os.environ, TMPDIR=str(tmp))

    def limit():
        if fsize is not None:
            import resource

            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
    proc = subprocess.run([sys.executable, "-m", "faceanim", *argv], cwd=work, env=env, stdin=subprocess.DEVNULL,
                          preexec_fn=limit if fsize is not None else None,
                          capture_output=True, text=True, errors="replace", timeout=60, check=False)
    lines = proc.stderr.splitlines()
    assert proc.returncode == 2, f"exit {proc.returncode}; stderr: {proc.stderr[-500:]!r}"
    assert len(lines) == 1, f"{len(lines)} stderr lines: {proc.stderr[-800:]!r}"
    assert lines[0].startswith("faceanim "), lines[0]
    assert re.search(phrase, lines[0]), f"{phrase!r} not in {lines[0]!r}"
    assert not re.search(r"[\x00-\x08\x0b-\x1f\x7f]", proc.stderr), f"control characters on stderr: {lines[0]!r}"
    assert "Traceback" not in proc.stderr
    assert _state(work) == before, "the folder changed: a file was left, replaced or removed"
    assert os.listdir(tmp) == [], f"left in TMPDIR: {os.listdir(tmp)}"
    assert _state(assets) == assets_before, "an input file was changed"


def test_the_sound_beside_a_glb_skips_a_dangling_link(tmp_path, assets):
    os.symlink(tmp_path / "gone.wav", tmp_path / "out.wav")
    proc = subprocess.run([sys.executable, "-m", "faceanim", "fap", "play", str(assets / "joy.fap"), "--audio",
                           str(assets / "short.wav"), "-o", "out.glb"], cwd=tmp_path, stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    assert os.readlink(tmp_path / "out.wav") == str(tmp_path / "gone.wav")  # the link is left alone
    assert (tmp_path / "out.glb").is_file() and (tmp_path / "out-1.wav").is_file()
