"""Audio in and out through libsndfile: every sample format read back against the samples written
(the oracle), mixing to mono, resampling, and clean refusals of files that are not usable audio."""

import math
import shutil
import subprocess

import numpy as np
import pytest
import soundfile as sf
from conftest import DATA, need

from faceanim.errors import FaceAnimError, InputFileError
from faceanim.io.audio import AudioError, read_audio, resample, write_wav
from faceanim.limits import MAX_DURATION, MAX_SAMPLE_RATE

SPEECH = DATA / "speech-librivox"


def _tone(rate=16000, seconds=0.5, freqs=(220.0, 1250.0)):
    t = np.arange(round(rate * seconds)) / rate
    x = sum(0.3 * np.sin(2 * np.pi * f * t) for f in freqs)
    return x.astype(np.float32)


# libsndfile reads n-bit PCM as integer / 2^(n-1) and writes float * (2^(n-1) - 1): the round trip
# of a sample x is within |x| / 2^(n-1) (the scale) + 1 / 2^(n-1) (rounding)
@pytest.mark.parametrize("subtype, fmt, ext, bits", [
    ("PCM_16", "WAV", "wav", 16), ("PCM_24", "WAV", "wav", 24), ("PCM_32", "WAV", "wav", 32),
    ("FLOAT", "WAV", "wav", None), ("DOUBLE", "WAV", "wav", None), ("PCM_U8", "WAV", "wav", 8),
    ("PCM_16", "FLAC", "flac", 16), ("PCM_24", "FLAC", "flac", 24), ("PCM_16", "AIFF", "aiff", 16),
])
def test_read_every_format_against_the_samples_written(tmp_path, subtype, fmt, ext, bits):
    x = _tone()
    path = tmp_path / f"tone.{ext}"
    sf.write(path, x, 16000, subtype=subtype, format=fmt)
    y, rate = read_audio(path)
    assert rate == 16000 and y.dtype == np.float32 and y.shape == x.shape
    tol = 1e-7 if bits is None else 2.0 / 2 ** (bits - 1)
    np.testing.assert_allclose(y, x, atol=tol, rtol=0)
    if bits is not None and bits <= 24:  # and the values really are the quantised ones
        q = 2 ** (bits - 1)
        np.testing.assert_allclose(y * q, np.round(y * q), atol=1e-3)


def test_ogg_vorbis_is_read_close_to_the_original(tmp_path):
    x = _tone(seconds=1.0)
    sf.write(tmp_path / "tone.ogg", x, 16000, format="OGG", subtype="VORBIS")
    y, rate = read_audio(tmp_path / "tone.ogg")
    assert rate == 16000 and len(y) == len(x)
    # lossy: compare the spectra's peaks, not samples
    spectrum = np.abs(np.fft.rfft(y)) / len(y)
    peaks = sorted(np.argsort(spectrum)[-2:] * 16000 / len(y))
    assert peaks == pytest.approx([220.0, 1250.0], abs=2.0)
    assert np.sqrt(np.mean((y - x) ** 2)) < 0.02


def test_stereo_is_mixed_to_mono_and_44k_is_kept(tmp_path):
    left, right = _tone(44100, freqs=(300.0,)), _tone(44100, freqs=(700.0,))
    sf.write(tmp_path / "st.wav", np.stack([left, right], axis=1), 44100, subtype="PCM_24")
    y, rate = read_audio(tmp_path / "st.wav")
    assert rate == 44100 and y.shape == left.shape
    np.testing.assert_allclose(y, 0.5 * (left + right), atol=2.0 / 2**23)


def test_write_wav_round_trip_and_atomic(tmp_path):
    x = _tone(22050)
    out = write_wav(tmp_path / "out.wav", x, 22050)
    info = sf.info(out)
    assert (info.samplerate, info.channels, info.subtype, info.frames) == (22050, 1, "PCM_16", len(x))
    y, rate = read_audio(out)
    assert rate == 22050
    np.testing.assert_allclose(y, x, atol=2.0 / 2**15)
    write_wav(tmp_path / "f.wav", x, 22050, subtype="FLOAT")
    np.testing.assert_array_equal(read_audio(tmp_path / "f.wav")[0], x)  # float32: exact
    clipped = read_audio(write_wav(tmp_path / "c.wav", np.array([2.0, -3.0, 0.5]), 8000))[0]
    np.testing.assert_allclose(clipped, [32767 / 32768, -32767 / 32768, 0.5], atol=1 / 32768)
    for bad in (np.array([np.nan, 0.0]), np.zeros(0), np.zeros((4, 2))):
        with pytest.raises(AudioError):
            write_wav(tmp_path / "bad.wav", bad, 16000)
    with pytest.raises(AudioError, match="sample rate"):
        write_wav(tmp_path / "bad.wav", x, 0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.wav", "f.wav", "out.wav"]  # no partial files


def test_resample_keeps_the_length_and_a_tone():
    x = _tone(44100, seconds=1.0, freqs=(440.0,))
    y = resample(x, 44100, 16000)
    assert y.dtype == np.float32 and len(y) == 16000  # 44100 * 160 / 441
    spectrum = np.abs(np.fft.rfft(y[2000:-2000]))
    assert np.argmax(spectrum) * 16000 / len(y[2000:-2000]) == pytest.approx(440.0, abs=1.5)
    t = np.arange(16000) / 16000
    np.testing.assert_allclose(y[2000:-2000], (0.3 * np.sin(2 * np.pi * 440 * t))[2000:-2000], atol=2e-3)
    np.testing.assert_array_equal(resample(x, 44100, 44100), x)
    assert len(resample(_tone(48000, 0.25), 48000, 16000)) == 4000
    for rate, to in ((0, 16000), (16000, MAX_SAMPLE_RATE + 1), (16000.5, 16000), (True, 16000)):
        with pytest.raises(AudioError, match="sample rate"):
            resample(x, rate, to)


def test_refusals_are_one_clean_line(tmp_path):
    x = _tone()
    cases = {}
    cases["missing.wav"] = None
    (tmp_path / "empty.wav").write_bytes(b"")
    cases["empty.wav"] = "is empty"
    (tmp_path / "text.wav").write_text("root:x:0:0:root:/root:/bin/bash\n" * 20)
    cases["text.wav"] = "is not audio"
    sf.write(tmp_path / "zero.wav", np.zeros(0, np.float32), 16000)
    cases["zero.wav"] = "holds no audio"
    for ext, fmt in (("wav", "WAV"), ("flac", "FLAC"), ("ogg", "OGG")):
        sf.write(tmp_path / f"full.{ext}", np.tile(x, 4), 16000, format=fmt)
        data = (tmp_path / f"full.{ext}").read_bytes()
        (tmp_path / f"cut.{ext}").write_bytes(data[: len(data) // 2])
        cases[f"cut.{ext}"] = "truncated"
    sf.write(tmp_path / "nan.wav", np.array([0.0, np.nan, 0.1], np.float32), 16000, subtype="FLOAT")
    cases["nan.wav"] = "NaN or infinite"
    for name, message in cases.items():
        with pytest.raises(AudioError) as err:
            read_audio(tmp_path / name)
        text = str(err.value)
        assert isinstance(err.value, InputFileError) and isinstance(err.value, FaceAnimError)
        assert "\n" not in text and name in text and (message is None or message in text), text
        assert "root:" not in text and "libsndfile" not in text.lower()


def test_a_streamed_wav_of_unknown_length_is_read(tmp_path):
    """A WAV written to a pipe (espeak-ng --stdout, ffmpeg) declares ~2^31 bytes of data: that is
    'length unknown', not 'truncated'."""
    x = _tone()
    sf.write(tmp_path / "s.wav", x, 16000, subtype="PCM_16")
    data = bytearray((tmp_path / "s.wav").read_bytes())
    at = data.index(b"data") + 4
    data[at:at + 4] = (0x7FFFF000).to_bytes(4, "little")
    data[4:8] = (0x7FFFF024).to_bytes(4, "little")
    (tmp_path / "s.wav").write_bytes(bytes(data))
    y, _ = read_audio(tmp_path / "s.wav")
    np.testing.assert_allclose(y, x, atol=2.0 / 2**15)


def test_too_long_or_too_fast_is_refused_from_the_header(tmp_path):
    """The duration and rate come from the header: refused before a sample is read or allocated."""
    rate = 8000
    frames = int(MAX_DURATION * rate) + rate
    path = tmp_path / "long.wav"
    with sf.SoundFile(path, "w", rate, 1, "PCM_U8", format="WAV") as f:  # an hour and a bit: ~29 MB
        block = np.zeros(rate * 60, np.float32)
        for _ in range(math.ceil(frames / len(block))):
            f.write(block)
    with pytest.raises(AudioError, match=f"at most {MAX_DURATION:g} s"):
        read_audio(path)
    sf.write(tmp_path / "fast.wav", np.zeros(10, np.float32), 384000)
    with pytest.raises(AudioError, match="sample rate of 384000 Hz"):
        read_audio(tmp_path / "fast.wav")


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed (scripts/setup.sh installs it)")
def test_espeak_output_reads_like_the_samples_in_it(tmp_path):
    wav = tmp_path / "e.wav"
    subprocess.run(["espeak-ng", "-w", str(wav), "hello there"], check=True, capture_output=True)
    raw, rate = sf.read(wav, dtype="int16")
    y, r = read_audio(wav)
    assert r == rate == 22050
    np.testing.assert_array_equal(y, raw.astype(np.float32) / 32768)


def test_alignment_from_a_24_bit_flac_of_real_speech(tmp_path):
    from faceanim.drivers.speech import align

    wav = need(SPEECH / "clip-0880.wav")
    transcript = (SPEECH / "clip-0880.txt").read_text()
    x, rate = sf.read(wav, dtype="float32")
    flac = tmp_path / "clip.flac"
    sf.write(flac, np.stack([x, x], axis=1), rate, subtype="PCM_24", format="FLAC")  # 24-bit stereo FLAC
    y, r = read_audio(flac)
    assert r == rate == 16000
    np.testing.assert_allclose(y, x, atol=2.0 / 2**23)
    from_wav = align(wav, transcript)
    from_flac = align(flac, transcript)
    spoken = [p.phone for p in from_flac if p.phone != "SIL"]
    assert len(spoken) > 15 and spoken == [p.phone for p in from_wav if p.phone != "SIL"]
    for a, b in zip(from_wav, from_flac, strict=True):
        assert abs(a.start - b.start) <= 0.011 and abs(a.end - b.end) <= 0.011
    assert from_flac[-1].end <= len(y) / r + 0.02


def test_a_folder_or_device_is_not_an_audio_file(tmp_path):
    from faceanim.io.audio import AudioError, read_audio

    for path in (tmp_path, "/dev/zero"):
        with pytest.raises(AudioError, match="not a regular file"):
            read_audio(path)
    with pytest.raises(AudioError, match="does not exist"):
        read_audio(tmp_path / "none.wav")
