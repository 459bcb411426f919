"""Speech in any language espeak-ng speaks (phones through IPA) and Rhubarb Lip Sync's mouth cues."""

import json
import re
import shutil
import subprocess

import numpy as np
import pytest
from conftest import DATA, need
from hypothesis import given, settings
from hypothesis import strategies as st

from faceanim.cli import main
from faceanim.drivers.cues import arkit_cues, phone_cues
from faceanim.drivers.speech.lipsync import lipsync_curves, phone_target
from faceanim.drivers.speech.phonemes import Phone, SpeechError, check_text
from faceanim.standards.arkit import ARKIT_NAMES
from faceanim.io.rhubarb import tidy_cues, write_cues
from faceanim.standards.ipa import IPA_ARPABET, arpabet
from faceanim.standards.rhubarb import PHONE_SHAPES, SHAPES

has_espeak = pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed (scripts/setup.sh installs it)")
APPLE = [n[0].lower() + n[1:] for n in ARKIT_NAMES]
KNOWN = {"AA", "AE", "AH", "AO", "AW", "AY", "B", "CH", "D", "DH", "EH", "ER", "EY", "F", "G", "HH", "IH", "IY", "JH",
         "K", "L", "M", "N", "NG", "OW", "OY", "P", "R", "S", "SH", "T", "TH", "UH", "UW", "V", "W", "Y", "Z", "ZH"}


# ---------------------------------------------------------------------------------------------- IPA

def test_ipa_phones_take_the_mouth_of_their_articulation():
    assert arpabet("p") == ["P"] and arpabet("β") == ["B"] and arpabet("m") == ["M"]  # lips shut or nearly
    assert arpabet("øː") == ["AO"] and arpabet("y") == ["UW"] and arpabet("œ") == ["AO"]  # front rounded vowels
    assert arpabet("o") == ["AO"] and arpabet("oʊ") == ["OW"] and arpabet("eː") == ["EH"]  # one mouth, or a glide
    assert arpabet("ɔ̃") == ["AO"] and arpabet("ɛ̃") == ["EH"]  # French nasal vowels: the base vowel's mouth
    assert arpabet("ç") == ["HH"] and arpabet("x") == ["HH"] and arpabet("ʁ") == ["HH"]  # no lips (ç stays whole)
    assert arpabet("tʃ") == ["CH"] and arpabet("tɕ") == ["CH"] and arpabet("ts") == ["T", "S"]  # affricates
    assert arpabet("aɪ") == ["AY"] and arpabet("aɪə") == ["AY", "AH"]  # longest match first
    assert arpabet("dʲ") == ["D"] and arpabet("ˈiː") == ["IY"] and arpabet("ʲ") == []  # marks change nothing
    assert arpabet("Q") is None and arpabet("(en)") is None  # not IPA: the caller keeps the phone before


def test_every_ipa_symbol_has_a_mouth_target():
    from faceanim.drivers.speech.lipsync import _table

    glides = _table()["diphthongs"]
    for symbol, phones in IPA_ARPABET.items():
        for p in phones.split():
            assert p in KNOWN, symbol
            assert p in glides or phone_target(p) is not phone_target("SIL"), symbol


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=12))
def test_ipa_reader_never_fails_on_any_text(text):
    got = arpabet(text)
    assert got is None or set(got) <= KNOWN


def test_text_of_any_script_is_speakable():
    assert check_text("Привет, как дела") and check_text("你好") and check_text("Guten Tag")
    with pytest.raises(SpeechError, match="no words"):
        check_text(" ,.!? -- ")


@has_espeak
def test_english_words_outside_the_dictionary_are_spoken(tmp_path):
    from faceanim.drivers.speech import say_timed

    phones = [p.phone for p in say_timed("how vexingly quick daft zebras jump", tmp_path / "s.wav") if p.phone != "SIL"]
    assert "V EH K S IH NG L IY" in " ".join(phones)
    assert phones[:3] == ["HH", "AW", "V"] and phones[-3:] == ["AH", "M", "P"]


def espeak_ipa(text: str, voice: str) -> str:
    """espeak-ng's own IPA transcription of the text (the program, not faceanim's library run)."""
    out = subprocess.run(["espeak-ng", "-q", "--ipa", "-v", voice, text], capture_output=True, text=True, check=True)
    return out.stdout


@has_espeak
@pytest.mark.parametrize("voice,text", [("de", "Peter und Paul bauen ein Boot am Meer"),
                                        ("es", "Pablo bebe mucho vino blanco"),
                                        ("fr", "Pierre boit une bouteille de bon vin"),
                                        ("ru", "Папа пьёт молоко")])
def test_other_languages_shut_the_lips_at_each_bilabial(voice, text):
    """As many p, b, m (and Spanish β) as espeak-ng's own IPA of the text has, each with the lips
    shut (mouthClose equal to jawOpen) at its middle in say's curves; rounded vowels round."""
    from faceanim.drivers.speech.phonemes import espeak_phones

    _, _, phones = espeak_phones(text, voice)
    bilabial = [p for p in phones if p.phone in ("P", "B", "M")]
    assert len(bilabial) == len(re.findall("[pbmβ]", espeak_ipa(text, voice)))
    fps = 100.0
    curves = lipsync_curves(phones, APPLE, fps)
    jaw, close = APPLE.index("jawOpen"), APPLE.index("mouthClose")
    for p in bilabial:
        k = min(int(round((p.start + p.end) / 2 * fps)), len(curves) - 1)
        assert curves[k, jaw] - curves[k, close] < 0.03, (p, curves[k, jaw], curves[k, close])
    assert any(p.phone in ("OW", "UW", "AO", "W") for p in phones)  # each sentence has a rounded sound


# --------------------------------------------------------------------------------------- Rhubarb


def read_rhubarb_tsv(text: str) -> list[tuple[float, str]]:
    """Rhubarb's TSV as its documentation describes it: "<seconds>\\t<shape>" per line, the first at
    0.00, times not decreasing, the last line the recording's end with a closed mouth (X or A)."""
    rows = []
    for line in text.split("\n")[:-1]:
        time, shape = line.split("\t")
        assert re.fullmatch(r"\d+\.\d\d", time) and shape in "ABCDEFGHX" and len(shape) == 1
        rows.append((float(time), shape))
    assert rows[0][0] == 0.0 and rows[-1][1] in "XA"
    assert all(b[0] >= a[0] for a, b in zip(rows, rows[1:]))
    return rows


def read_rhubarb_json(text: str) -> dict:
    """Rhubarb's JSON as documented: metadata (soundFile, duration) and mouthCues, each cue's end the
    next one's start, from 0 to the duration."""
    doc = json.loads(text)
    cues = doc["mouthCues"]
    assert set(doc["metadata"]) == {"soundFile", "duration"}
    assert cues[0]["start"] == 0 and cues[-1]["end"] == doc["metadata"]["duration"]
    for a, b in zip(cues, cues[1:]):
        assert a["end"] == b["start"] and a["start"] < a["end"] and a["value"] in SHAPES
    return doc


def test_cue_files_read_back_as_rhubarb_documents_them(tmp_path):
    cues = [(0.0, "X"), (0.05, "D"), (0.27, "C"), (0.31, "B"), (0.43, "X")]
    tsv = write_cues(tmp_path / "hi.tsv", cues, 0.479)
    assert read_rhubarb_tsv(tsv.read_text()) == [(0.0, "X"), (0.05, "D"), (0.27, "C"), (0.31, "B"), (0.43, "X"),
                                                  (0.47, "X")]
    doc = read_rhubarb_json(write_cues(tmp_path / "hi.json", cues, 0.479, "hi.wav").read_text())
    assert doc["metadata"] == {"soundFile": "hi.wav", "duration": 0.47}
    assert [(c["start"], c["end"], c["value"]) for c in doc["mouthCues"]] == [
        (0.0, 0.05, "X"), (0.05, 0.27, "D"), (0.27, 0.31, "C"), (0.31, 0.43, "B"), (0.43, 0.47, "X")]
    assert b"\r" not in tsv.read_bytes()


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(-1, 10, allow_nan=False), st.sampled_from(list(SHAPES))), max_size=30),
       st.floats(0.01, 10))
def test_any_cues_tidy_into_a_contiguous_track(cues, duration):
    rows = tidy_cues(cues, duration)
    assert rows[0][0] == 0 and rows[-1][1] == int(np.floor(duration * 100 + 1e-6))
    assert all(a[1] == b[0] and a[2] != b[2] for a, b in zip(rows, rows[1:]))
    assert all(a < b for a, b, _ in rows)


def test_cues_refuse_unknown_shapes_and_empty_time(tmp_path):
    from faceanim.errors import FaceAnimError

    with pytest.raises(FaceAnimError, match="not a Rhubarb mouth shape"):
        tidy_cues([(0.1, "Q")], 1.0)
    with pytest.raises(FaceAnimError, match="less than 0.01 s"):
        tidy_cues([], 0.004)


def test_phone_cues_follow_the_documented_shapes():
    phones = [Phone("SIL", 0, 0.1), Phone("M", 0.1, 0.2), Phone("AA", 0.2, 0.4), Phone("F", 0.4, 0.5),
              Phone("UW", 0.5, 0.7), Phone("AY", 0.7, 1.0), Phone("L", 1.0, 1.1)]
    assert phone_cues(phones) == [(0, "X"), (0.1, "A"), (0.2, "D"), (0.4, "G"), (0.5, "F"), (0.7, "D"),
                                  (pytest.approx(0.88), "B"), (1.0, "H")]
    assert all(set(v) <= set(SHAPES) for v in PHONE_SHAPES.values())


def test_arkit_cues_read_the_mouth_off_the_curves():
    fps = 10.0
    frames = {"shut": {}, "wide": {"jawOpen": 0.6}, "open": {"jawOpen": 0.25}, "pucker": {"mouthPucker": 0.7,
              "jawOpen": 0.1}, "round": {"mouthFunnel": 0.7, "jawOpen": 0.4}, "teeth": {"jawOpen": 0.1}}
    order = ["shut"] * 5 + ["wide", "shut", "open", "pucker", "round", "teeth"] + ["shut"] * 5
    curves = np.zeros((len(order), len(APPLE)))
    for k, f in enumerate(order):
        for name, w in frames[f].items():
            curves[k, APPLE.index(name)] = w
    got = "".join(s for _, s in arkit_cues(curves, APPLE, fps))
    assert got == "XXXXX" + "DACFEB" + "XXXXX"  # a pause rests (X), a short closure is a closure (A)
    from faceanim.errors import FaceAnimError

    with pytest.raises(FaceAnimError, match="mouthfunnel"):
        arkit_cues(curves[:, :3], APPLE[:3], fps)


@has_espeak
def test_say_writes_rhubarb_cues_with_the_sound_beside(tmp_path, capsys):
    out = tmp_path / "cues.json"
    assert main(["say", "Peter Piper picked a peck", "-o", str(out)]) == 0
    doc = read_rhubarb_json(out.read_text())
    sound = tmp_path / doc["metadata"]["soundFile"]
    from faceanim.io.audio import read_audio

    x, rate = read_audio(sound)
    assert doc["metadata"]["duration"] == np.floor(len(x) / rate * 100) / 100
    assert sum(c["value"] == "A" for c in doc["mouthCues"]) >= 5  # p, p, p, p, p: each its own closure
    assert main(["say", "Peter Piper", "-o", str(out)]) == 0  # again: the same sound file is replaced
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cues.json", "cues.wav"]
    (tmp_path / "keep.wav").write_bytes(b"mine")
    tsv = tmp_path / "keep.tsv"
    assert main(["say", "hello", "-o", str(tsv)]) == 0
    assert (tmp_path / "keep.wav").read_bytes() == b"mine" and (tmp_path / "keep-1.wav").is_file()
    rows = read_rhubarb_tsv(tsv.read_text())
    assert rows[-1][1] == "X" and {s for _, s in rows} <= set("BCDEFHX")  # hello: no closure, no f/v
    assert main(["say", "hello", "--expression", "joy", "-o", str(tmp_path / "x.tsv")]) == 2
    assert "leave out --emotion" in capsys.readouterr().err and not (tmp_path / "x.tsv").exists()


def test_perform_writes_rhubarb_cues_of_the_performers_mouth(tmp_path):
    clip = need(DATA / "talking-head-videos" / "d0.mp4")
    out = tmp_path / "d0.json"
    assert main(["perform", str(clip), "-o", str(out), "--quiet"]) == 0
    doc = read_rhubarb_json(out.read_text())
    assert doc["metadata"]["soundFile"] == str(clip.resolve())
    assert 2.9 <= doc["metadata"]["duration"] <= 3.2
    assert len({c["value"] for c in doc["mouthCues"]}) >= 3  # the mouth moves through several shapes


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=300) | st.text(max_size=200).map(str.encode) |
       st.sampled_from([b'{"metadata": {"soundFile": "x.wav"}}', b'{"metadata": {"soundFile": "../x.wav"}}',
                        b'{"metadata": {"soundFile": "link.wav"}}', b'{"metadata": {"soundFile": 7}}']))
def test_the_cue_sound_never_names_a_file_faceanim_did_not_write(content):
    """Whatever an existing cues.json holds, the sound goes beside it under a new name, or replaces
    only a plain .wav file that JSON names in the same folder (faceanim's own, from before)."""
    import os
    import tempfile
    from pathlib import Path

    from faceanim.io.rhubarb import cue_sound

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "cues.json").write_bytes(content)
        (folder / "x.wav").write_bytes(b"RIFF")
        os.symlink("/etc/hostname", folder / "link.wav")
        got = cue_sound(folder / "cues.json")
        assert got.parent == folder and got.suffix == ".wav"
        named_x = got.name == "x.wav" and b'"soundFile": "x.wav"' in content
        assert not os.path.lexists(got) or named_x


@has_espeak
def test_a_transcript_word_outside_the_dictionary_is_aligned_by_espeaks_pronunciation():
    """'amiable' spelt as the dictionary does not know it ('aymiabul'): espeak-ng's pronunciation is
    added, and its closures (m, b) land where the dictionary word's do, within 30 ms."""
    from faceanim.drivers.speech.phonemes import align, espeak_pronunciations

    wav = need(DATA / "speech-librivox" / "clip-0930.wav")
    assert espeak_pronunciations(["aymiabul", "--help"]) == {"aymiabul": "AY M IH AE B AH L"}  # an option: never run
    known = align(wav, "he might even have been made amiable himself")
    new = align(wav, "he might even have been made aymiabul himself")
    for phone in ("M", "B"):
        (a,) = [p for p in known if p.word == "amiable" and p.phone == phone]
        (b,) = [p for p in new if p.word == "aymiabul" and p.phone == phone]
        assert abs(a.start - b.start) < 0.03 and abs(a.end - b.end) < 0.03, phone
