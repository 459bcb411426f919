"""Actions, visemes and speech: the blending formula, co-articulation, alignment, synthesis, say."""

import json
import shutil
import subprocess

import numpy as np
import pytest
from conftest import DATA, need

from faceanim.cli import main
from faceanim.drivers.mpeg4 import Action, blend_actions, expression_faps, fap_set
from faceanim.drivers.speech import Phone, phone_viseme, viseme_actions
from faceanim.drivers.speech.phonemes import SpeechError, check_text, words_of
from faceanim.standards.mpeg4 import FapError

SPEECH = DATA / "speech-librivox"
has_espeak = pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed (scripts/setup.sh installs it)")


def test_single_action_follows_its_envelope():
    a = Action("smile", {12: 200.0, 13: 200.0}, start=0.2, duration=1.0, intensity=0.5, envelope="linear",
               attack=0.2, release=0.2)
    s = blend_actions([a], 40, 25.0)
    t = np.arange(40) / 25.0
    want = 0.5 * 200.0 * a.envelope_at(t)
    np.testing.assert_allclose(s.column(12), want, atol=1e-12)
    assert s.column(12)[0] == 0 and s.mask[10, 11] and not s.mask[0, 11]
    np.testing.assert_allclose(a.envelope_at(np.array([0.3, 0.7, 1.1])), [0.5, 1.0, 0.5], atol=1e-12)


def test_an_additive_action_is_added_over_the_blend():
    """An additive action (a layer: the voice's head rise) is added to the weighted blend of the
    others where they overlap, is the value alone where it is alone, and linear hats at half their
    width apart sum to the straight line between their keys."""
    pitch = fap_set({"head_pitch": 1.0})
    nod = Action("nod", {k: 1000.0 for k in pitch}, 0.0, 1.0, 1.0, "linear", 0.0, 0.0)
    other = Action("other", {k: 3000.0 for k in pitch}, 0.0, 1.0, 1.0, "linear", 0.0, 0.0)
    layer = [Action("rise", {k: v for k in pitch}, at - 0.1, 0.2, 1.0, "linear", 0.5, 0.5, additive=True)
             for at, v in ((0.5, 100.0), (0.6, 200.0), (0.7, 300.0), (0.8, 400.0))]
    s = blend_actions([nod, other, *layer], 101, 100.0)
    col = s.column("head_pitch")
    assert col[20] == pytest.approx(2000.0)  # the blend alone: the two actions' mean
    assert col[60] == pytest.approx(2000.0 + 200.0) and col[65] == pytest.approx(2000.0 + 250.0)
    alone = blend_actions(layer, 101, 100.0).column("head_pitch")
    np.testing.assert_allclose(alone[50:81], np.linspace(100.0, 400.0, 31), atol=1e-9)


def test_blending_is_continuous_and_respects_weights():
    surprise = Action("surprise", {3: 500.0}, 0.0, 2.0, 1.0, "smooth", 0.2, 0.2, weight=0.3)
    b = Action("b", {3: 0.0}, 0.8, 0.3, 1.0, "smooth", 0.4, 0.4, weight=6.0)
    fps = 1000.0
    s = blend_actions([surprise, b], 1500, fps)
    jaw = s.column(3)
    # continuous: at 1 ms steps no change is large (a plain average would jump by ~250 where
    # 'b' starts and ends)
    assert np.abs(np.diff(jaw)).max() < 40
    assert jaw[int(0.95 * fps)] < 0.1 * 500  # the heavy plosive closes the jaw inside the surprise
    assert jaw[int(0.5 * fps)] == pytest.approx(500, rel=1e-6)  # surprise alone before 'b'


def test_action_and_fap_set_errors():
    with pytest.raises(FapError, match="envelope"):
        Action("x", {3: 1.0}, 0, 1, envelope="square")
    with pytest.raises(FapError, match="duration"):
        Action("x", {3: 1.0}, 0, 0)
    with pytest.raises(FapError, match="unknown FAP"):
        fap_set({"open_mouth": 100})
    with pytest.raises(FapError, match="expression"):
        expression_faps("boredom")
    assert expression_faps("surprise")[3] > 0


def test_phone_to_viseme_and_coarticulation():
    assert phone_viseme("P") == phone_viseme("b") == phone_viseme("M") == 1
    assert phone_viseme("AA1") == 10 and phone_viseme("UW") == 14 and phone_viseme("SIL") == 0
    with pytest.raises(FapError):
        phone_viseme("QQ")
    phones = [Phone("HH", 0.0, 0.05), Phone("AA", 0.05, 0.25), Phone("P", 0.25, 0.32), Phone("IY", 0.32, 0.5)]
    acts = viseme_actions(phones, lip_gap=100.0)
    assert [a.extra["viseme"] for a in acts] == [10, 1, 12]
    vowel, plosive = acts[0], acts[1]
    assert vowel.start < 0.05 and vowel.end > 0.25  # vowels spread into their neighbours
    assert plosive.weight > vowel.weight and plosive.faps[4] > 50  # closure outweighs, closes the gap


def test_words_and_text_without_words():
    assert words_of("Hello, how are you?") == ["hello", "how", "are", "you"]
    with pytest.raises(SpeechError, match="no words"):
        words_of(" ,.!? ")
    with pytest.raises(SpeechError) as err:
        words_of("... !!! ???", "the transcript")
    assert "the transcript" in str(err.value) and "!!!" not in str(err.value)  # the text is not echoed


def test_alignment_of_real_speech():
    from faceanim.drivers.speech import align
    from faceanim.io.audio import read_audio

    wav = need(SPEECH / "clip-0880.wav")
    phones = align(wav, (SPEECH / "clip-0880.txt").read_text())
    x, rate = read_audio(wav)
    starts = [p.start for p in phones]
    assert starts == sorted(starts) and phones[-1].end <= len(x) / rate + 0.02
    assert sum(p.phone != "SIL" for p in phones) > 15
    with pytest.raises(SpeechError, match="too short|match"):
        align(wav, (SPEECH / "clip-0880.txt").read_text() * 8)  # far more words than the audio holds
    with pytest.raises(SpeechError, match="match"):  # words espeak-ng pronounces, but not these
        align(wav, "zxqvbn wordz")
    from faceanim.drivers.speech import phonemes

    real_which = phonemes.shutil.which
    phonemes.shutil.which = lambda name: None  # without espeak-ng: words outside the dictionary are named
    try:
        with pytest.raises(SpeechError, match="does not know: zxqvbn, wordz"):
            align(wav, "zxqvbn wordz")
    finally:
        phonemes.shutil.which = real_which
    with pytest.raises(SpeechError, match="match"):
        align(wav, (SPEECH / "clip-0930.txt").read_text())  # another clip's words
    with pytest.raises(SpeechError, match="it is silent"):
        align(np.zeros(32000, np.float32), "hello world", 16000)  # silence with a transcript


@has_espeak
def test_say_writes_a_fap_file_and_glb(tmp_path, capsys):
    from faceanim.io.fapfile import read_fap

    out = tmp_path / "hello.fap"
    assert main(["say", "Hello, how are you?", "-o", str(out)]) == 0
    s = read_fap(out)
    assert s.n_frames > 20 and s.column("open_jaw").max() > 100
    # the voice's prosody is in the .fap too: a blink at the pause, nods and a lean per phrase
    assert main(["say", "Hello there. How are you today?", "-o", str(out)]) == 0
    s = read_fap(out)
    assert s.column("close_t_l_eyelid").max() > 900 and s.column("head_pitch").max() > 4000
    assert s.column("head_roll").max() > 2000 and s.column("head_roll").min() < -2000
    assert main(["say", "Hello", "--expression", "joy", "-o", str(tmp_path / "h.glb")]) == 0
    for flag in ("--emotion", "--expression"):  # --expression is --emotion's older name
        assert main(["say", "Hello", flag, "joy", "-o", str(tmp_path / f"h{flag}.fap")]) == 0
    joy = read_fap(tmp_path / "h--emotion.fap")
    assert np.array_equal(joy.values, read_fap(tmp_path / "h--expression.fap").values)
    from faceanim.drivers.mpeg4 import expression_faps

    assert main(["say", "Hello", "-o", str(tmp_path / "plain.fap")]) == 0
    plain = read_fap(tmp_path / "plain.fap")
    # joy's FAPs the visemes leave alone (the cheeks, the lower lids) all move joy's way
    alone = [(f, v) for f, v in expression_faps("joy").items() if not plain.values[:, f - 1].any()]
    assert len(alone) >= 4 and all(np.sign(v) * joy.values[:, f - 1].mean() > 0 for f, v in alone)
    assert main(["say", "...", "-o", str(tmp_path / "x.fap")]) == 2
    assert "no words" in capsys.readouterr().err
    assert not (tmp_path / "x.fap").exists()


def test_fap_play_renders_a_video(tmp_path):
    from faceanim.drivers.mpeg4 import FapStream
    from faceanim.io.fapfile import write_fap

    s = FapStream.empty(6, fps=10)
    s.set("open_jaw", [0, 100, 300, 500, 300, 0])
    s.set("head_yaw", 5000, frames=[3])
    write_fap(tmp_path / "a.fap", s)
    assert main(["fap", "play", str(tmp_path / "a.fap"), "--size", "96", "-o", str(tmp_path / "a.mp4")]) == 0
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(tmp_path / "a.mp4"))
    next(reader)
    assert sum(1 for _ in reader) == 6


def test_fap_write(tmp_path, capsys):
    from faceanim.io.fapfile import read_fap

    out = tmp_path / "s.fap"
    assert main(["fap", "write", "--expression", "surprise", "--fap", "head_yaw=5000", "--duration", "1",
                 "-o", str(out)]) == 0
    s = read_fap(out)
    assert s.column("open_jaw").max() > 0 and s.column("head_yaw").max() == 5000
    assert np.all(s.values == np.rint(s.values))  # whole FAPU units
    assert main(["fap", "write", "--fap", "open_mouth=3", "-o", str(tmp_path / "x.fap")]) == 2
    assert "unknown FAP" in capsys.readouterr().err and not (tmp_path / "x.fap").exists()


def test_say_with_recorded_speech_and_a_valid_glb(tmp_path):
    import imageio_ffmpeg
    from conftest import ROOT

    wav = need(SPEECH / "clip-0880.wav")
    out = tmp_path / "clip.mp4"
    assert main(["say", "--audio", str(wav), "--transcript", str(SPEECH / "clip-0880.txt"), "--size", "96",
                 "-o", str(out)]) == 0
    info = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-i", str(out)], capture_output=True, text=True,
                          check=False).stderr
    assert "Audio:" in info and "Video:" in info
    glb = tmp_path / "clip.glb"
    assert main(["say", "--audio", str(wav), "--transcript", str(SPEECH / "clip-0880.txt"), "-o", str(glb)]) == 0
    validator = ROOT / "tools" / "validate_gltf.js"
    if shutil.which("node") and (ROOT / "tools" / "node_modules" / "gltf-validator").exists():
        report = json.loads(subprocess.run(["node", str(validator), str(glb)], capture_output=True, text=True,
                                           check=False).stdout)
        assert report["numErrors"] == 0


# ----------------------------------------------------------------------------------- text and voices


def test_text_to_say_is_checked_before_any_process(monkeypatch, tmp_path):
    from faceanim.drivers.speech import say_timed, synthesize
    from faceanim.limits import MAX_TEXT

    monkeypatch.setenv("PATH", str(tmp_path))  # no espeak-ng: the text is refused first anyway
    for text, message in (("", "is empty"), ("   \n\t", "is empty"), ("?!", "no words"),
                          ("a " * (MAX_TEXT // 2 + 1), f"at most {MAX_TEXT}"), (None, "must be a string")):
        for fn in (say_timed, synthesize):
            with pytest.raises(SpeechError, match=message):
                fn(text, tmp_path / "x.wav")
    assert check_text("a" * MAX_TEXT) == "a" * MAX_TEXT
    with pytest.raises(SpeechError) as err:
        check_text("b" * (MAX_TEXT + 1))
    assert str(err.value) == (f"the text to say has {MAX_TEXT + 1} characters; faceanim speaks at most {MAX_TEXT} "
                              "at once: split it into several parts")
    with pytest.raises(SpeechError, match="not installed"):
        say_timed("hello", tmp_path / "x.wav")
    assert not (tmp_path / "x.wav").exists()


@has_espeak
def test_voices_are_checked_against_the_installed_list():
    from faceanim.drivers.speech import check_voice, espeak_voices

    listed = subprocess.run(["espeak-ng", "--voices"], capture_output=True, text=True, check=True).stdout
    languages = [line.split()[1] for line in listed.splitlines()[1:]]
    files = [line.split()[4] for line in listed.splitlines()[1:]]
    voices = espeak_voices()
    assert voices == sorted(voices) and "en-us" in voices and set(languages) <= set(voices)
    assert check_voice("en-us") == "en-us" and check_voice("EN-US") == "en-us"
    assert check_voice(files[languages.index("en-us")]) == files[languages.index("en-us")]  # gmw/en-US
    assert check_voice("en") == "en"  # a language a voice answers to ('(en 3)')
    assert check_voice("en-us+f3") == "en-us+f3"
    with pytest.raises(SpeechError) as err:
        check_voice("../../../../etc/passwd")
    assert str(err.value) == ("unknown espeak-ng voice '../../../../etc/passwd'; run `espeak-ng --voices` to list "
                              "them (e.g. en-us)")
    with pytest.raises(SpeechError) as err:
        check_voice("en-gbb")
    hint = str(err.value).split("(e.g. ")[1].rstrip(")").split(", ")
    assert "en-gb" in hint and len(hint) <= 3
    with pytest.raises(SpeechError, match="unknown espeak-ng voice variant 'nope'"):
        check_voice("en-us+nope")
    for bad in ("", "en-us\nroot:x:0:0", None, 3):
        with pytest.raises(SpeechError, match="unknown espeak-ng voice") as err:
            check_voice(bad)
        assert "\n" not in str(err.value)


def _fake_espeak(tmp_path, secret: str):
    """An espeak-ng that lists one voice and fails every synthesis, printing a secret."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    exe = bin_dir / "espeak-ng"
    exe.write_text(
        "#!/bin/sh\n"
        'case "$1" in\n'
        "  --voices) echo 'Pty Language Age/Gender VoiceName File Other Languages';"
        " echo ' 2  en-us --/M English_(America) gmw/en-US (en 3)'; exit 0;;\n"
        "  --voices=variant) echo 'Pty Language Age/Gender VoiceName File Other Languages'; exit 0;;\n"
        "esac\n"
        f"echo '{secret}' >&2\necho '{secret}'\nexit 1\n")
    exe.chmod(0o755)
    return bin_dir


def test_espeak_output_never_reaches_an_error(monkeypatch, tmp_path, caplog):
    import logging

    from faceanim.drivers.speech import synthesize
    from faceanim.drivers.speech.phonemes import say_word_by_word

    secret = "root:x:0:0:root:/root:/bin/bash"
    monkeypatch.setenv("PATH", str(_fake_espeak(tmp_path, secret)))
    with caplog.at_level(logging.DEBUG, logger="faceanim.drivers.speech.phonemes"):
        for fn in (synthesize, say_word_by_word):  # the espeak-ng program (say_timed uses it without the library)
            with pytest.raises(SpeechError) as err:
                fn("hello", tmp_path / "x.wav", voice="en-us")
            assert secret not in str(err.value) and "root" not in str(err.value)
            assert "espeak-ng could not synthesize speech with voice 'en-us'" in str(err.value)
    assert secret in caplog.text  # logged at debug level only
    with pytest.raises(SpeechError, match="unknown espeak-ng voice 'fr'"):
        synthesize("hello", tmp_path / "x.wav", voice="fr")  # this espeak-ng lists only en-us


@has_espeak
def test_synthesize_reads_the_text_from_stdin(tmp_path):
    """Text that looks like an option is spoken, not parsed as one."""
    from faceanim.drivers.speech import synthesize
    from faceanim.drivers.speech.phonemes import SENTENCE_WPM, WORD_WPM, check_speed
    from faceanim.io.audio import read_audio

    out = synthesize("--help -w /tmp/evil.wav hello", tmp_path / "s.wav")
    x, rate = read_audio(out)
    assert rate == 22050 and len(x) > rate and np.abs(x).max() > 0.1
    assert (WORD_WPM, SENTENCE_WPM) == (175, 160)
    with pytest.raises(Exception, match="speaking rate"):
        check_speed(1000)


@has_espeak
def test_say_timed_is_repeatable(tmp_path):
    from faceanim.drivers.speech import say_timed
    from faceanim.drivers.speech.phonemes import SAMPLE_RATE
    from faceanim.io.audio import read_audio

    a = say_timed("Hello, world.", tmp_path / "a.wav")
    b = say_timed("Hello, world.", tmp_path / "b.wav", voice="EN-US")
    assert a == b and [p.phone for p in a if p.phone != "SIL"][:4] == ["HH", "AH", "L", "OW"]
    xa, ra = read_audio(tmp_path / "a.wav")
    xb, rb = read_audio(tmp_path / "b.wav")
    assert ra == rb == SAMPLE_RATE
    np.testing.assert_array_equal(xa, xb)
    comma = [p for p in a if p.phone == "SIL" and 0 < p.start and p.end < a[-1].end]
    assert len(comma) == 1 and comma[0].end - comma[0].start > 0.1  # the pause at ','
    assert a[-1].end == pytest.approx(len(xa) / SAMPLE_RATE, abs=1e-3)  # phone times are the track's times
    assert all(p.end > p.start for p in a) and all(q.start == pytest.approx(p.end) for p, q in zip(a, a[1:]))


@has_espeak
def test_said_phones_take_espeaks_own_time(tmp_path):
    """The phones of a spoken sentence carry espeak-ng's own timing (not equal shares): the
    dictionary's phones of "Peter Piper picked a peck", the words named, the vowels longer than
    the stops on the whole, no two phones the same length throughout, and the sound as long as
    the phones; speaking it again gives the same."""
    from faceanim.drivers.speech import say_timed
    from faceanim.drivers.speech.phonemes import SAMPLE_RATE
    from faceanim.io.audio import read_audio

    phones = say_timed("Peter Piper picked a peck", tmp_path / "p.wav")
    spoken = [p for p in phones if p.phone != "SIL"]
    assert [p.phone for p in spoken] == "P IY T ER P AY P ER P IH K T AH P EH K".split()
    assert [p.word for p in spoken][:4] == ["peter"] * 4 and spoken[-1].word == "peck"
    length = {p: [q.end - q.start for q in spoken if q.phone == p] for p in ("P", "T", "K", "IY", "AY", "IH", "EH")}
    assert np.mean(length["AY"] + length["EH"] + length["IH"]) > 1.3 * np.mean(length["P"] + length["T"] + length["K"])
    assert len({round(p.end - p.start, 3) for p in spoken}) > len(spoken) // 2
    x, rate = read_audio(tmp_path / "p.wav")
    assert rate == SAMPLE_RATE and phones[-1].end == pytest.approx(len(x) / rate, abs=1e-3)
    assert say_timed("Peter Piper picked a peck", tmp_path / "q.wav") == phones


@has_espeak
def test_say_command_refuses_bad_voices_and_texts(tmp_path, capsys):
    from faceanim.limits import MAX_TEXT

    out = tmp_path / "x.fap"
    assert main(["say", "hello", "--voice", "../../../../../../etc/passwd", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith("unknown espeak-ng voice '../../../../../../etc/passwd'; run `espeak-ng --voices` to "
                        "list them (e.g. en-us)")
    assert main(["say", "", "-o", str(out)]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith("the text to say is empty; give the words to speak")
    assert main(["say", "x" * (MAX_TEXT + 1), "-o", str(out)]) == 2
    assert f"faceanim speaks at most {MAX_TEXT}" in capsys.readouterr().err
    assert not out.exists()
