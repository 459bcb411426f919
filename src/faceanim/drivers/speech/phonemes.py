"""Timed phonemes: forced alignment of speech audio with its transcript, and speech synthesis.

Alignment uses pocketsphinx (its wheel ships a US English acoustic model and dictionary): the
transcript's words are looked up (a word the dictionary lacks gets espeak-ng's pronunciation,
:func:`espeak_pronunciations`; without espeak-ng it is refused by name), the audio is aligned at
10 ms frames, and the ARPAbet phones come back with their start and end times. Synthesis
(:func:`say_timed`) runs espeak-ng (installed by ``scripts/setup.sh``) through its library and
takes each phone and its time from espeak-ng's own phoneme events, read through their IPA
(:mod:`faceanim.standards.ipa`): any word, any voice. Without the library, the words are spoken one
by one by the espeak-ng program and aligned (:func:`say_word_by_word`).

Audio is read, written and resampled by :mod:`faceanim.io.audio` (libsndfile, libsoxr). espeak-ng's voice
is checked against the voices it lists before it runs, and its own output is never shown in an
error (it is logged at debug level): a voice "name" can be any path, and espeak-ng prints the
lines of a file it cannot parse as a voice.
"""

from __future__ import annotations

import bisect
import difflib
import logging
import re
import shutil
import subprocess
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from faceanim.errors import FaceAnimError
from faceanim.errors import shown as _shown
from faceanim.extras import require
from faceanim.io.audio import check_rate, read_audio, resample, write_wav
from faceanim.limits import MAX_DURATION, MAX_TEXT
from faceanim.standards.ipa import arpabet as ipa_arpabet

log = logging.getLogger(__name__)

SAMPLE_RATE = 16000  # what the pocketsphinx model expects
FRAME = 0.01  # pocketsphinx frame length, seconds
SILENT_RMS = 1e-3  # audio quieter than this (RMS, full scale 1) holds no speech to recognise

# espeak-ng speaking rates, words per minute. say_timed speaks one word per espeak-ng call and adds
# its own gaps and pauses, so it uses espeak-ng's own default rate (175); synthesize speaks a whole
# sentence in one call that is then aligned as a whole, and a slightly slower rate gives the aligner
# longer phones to find on the robotic voice.
WORD_WPM = 175
SENTENCE_WPM = 160
MIN_WPM, MAX_WPM = 80, 450  # the range espeak-ng's -s accepts
DEFAULT_VOICE = "en-us"
ESPEAK_TIMEOUT = 600.0  # seconds for one espeak-ng call (MAX_TEXT characters take well under that)


class SpeechError(FaceAnimError):
    """Text with nothing to say, audio that does not match its transcript, a missing synthesizer."""


@dataclass(frozen=True)
class Phone:
    phone: str  # ARPAbet without stress, or SIL
    start: float  # seconds
    end: float
    word: str = ""

    @property
    def centre(self) -> float:
        return 0.5 * (self.start + self.end)


def check_text(text, what: str = "the text to say") -> str:
    """``text`` if it is a string of 1 to :data:`~faceanim.limits.MAX_TEXT` characters with a word
    in it; else a :class:`SpeechError` saying what to do. Checked before any process starts."""
    if not isinstance(text, str):
        raise SpeechError(f"{what} must be a string of words, got {type(text).__name__}")
    if not text.strip():
        raise SpeechError(f"{what} is empty; give the words to speak")
    if len(text) > MAX_TEXT:
        raise SpeechError(f"{what} has {len(text)} characters; faceanim speaks at most {MAX_TEXT} at once: "
                          "split it into several parts")
    if not re.search(r"[^\W_]", text):  # a letter or digit of any script
        raise SpeechError(f"there are no words to speak in {what} (only spaces or punctuation); "
                          "give words made of letters or digits")
    return text


def words_of(text: str, what: str = "the text") -> list[str]:
    """The words of an English transcript, lower case (letters, digits spelled as written,
    apostrophes), as the pronunciation dictionary spells them."""
    words = re.findall(r"[a-z0-9']+", str(text).lower())
    words = [w.strip("'") for w in words if w.strip("'")]
    if not words:
        raise SpeechError(f"there are no words to speak in {what} (only spaces or punctuation); "
                          "give words made of letters or digits")
    return words




# ----------------------------------------------------------------------------------- espeak-ng


def _espeak() -> str:
    exe = shutil.which("espeak-ng")
    if exe is None:
        raise SpeechError("espeak-ng is not installed; run scripts/setup.sh (it installs Debian's espeak-ng)")
    return exe


def _parse_voices(listing: str) -> dict[str, str]:
    """``espeak-ng --voices`` output -> {lower-case name: name as listed}: each voice's language
    code, its file name (e.g. gmw/en-US) and the other language codes it answers to ('(en 3)')."""
    names: dict[str, str] = {}
    others: dict[str, str] = {}
    for line in listing.splitlines()[1:]:  # the first line is the header
        fields = line.split()
        if len(fields) < 5 or not fields[0].isdigit():
            continue
        language, file = fields[1], fields[4]
        names.setdefault(language.lower(), language)
        names.setdefault(file.lower(), file)
        for other in re.findall(r"\(([^\s()]+)\s+\d+\)", " ".join(fields[5:])):
            others.setdefault(other.lower(), other)
    for key, value in others.items():
        names.setdefault(key, value)
    return names


def _parse_variants(listing: str) -> dict[str, str]:
    """``espeak-ng --voices=variant`` output -> {lower-case variant: variant} (e.g. 'f3', 'Alex')."""
    out: dict[str, str] = {}
    for line in listing.splitlines()[1:]:
        fields = line.split()
        if len(fields) >= 5 and fields[4].startswith("!v/"):
            out.setdefault(fields[4][3:].lower(), fields[4][3:])
    return out


def _run_listing(exe: str, option: str) -> str:
    try:
        result = subprocess.run([exe, option], capture_output=True, text=True, check=False, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as exc:
        log.debug("espeak-ng %s failed: %s", option, exc)
        raise SpeechError("espeak-ng could not list its voices; check the installation with "
                          "`espeak-ng --voices`") from None
    if result.returncode != 0:
        log.debug("espeak-ng %s exited %s: %s", option, result.returncode, result.stderr)
        raise SpeechError(f"espeak-ng could not list its voices (exit code {result.returncode}); check the "
                          "installation with `espeak-ng --voices`")
    return result.stdout


@lru_cache(maxsize=4)
def _voice_tables(exe: str) -> tuple[dict[str, str], dict[str, str]]:
    voices = _parse_voices(_run_listing(exe, "--voices"))
    if not voices:
        raise SpeechError("espeak-ng lists no voices; check the installation with `espeak-ng --voices`")
    try:
        variants = _parse_variants(_run_listing(exe, "--voices=variant"))
    except SpeechError:
        variants = {}
    return voices, variants


def espeak_voices() -> list[str]:
    """The voice names espeak-ng accepts here (language codes and voice files as it lists them),
    sorted; read once per process."""
    return sorted(set(_voice_tables(_espeak())[0].values()))


def check_voice(voice) -> str:
    """The espeak-ng voice ``voice`` as espeak-ng lists it (``en-us``, ``EN-US`` -> ``en-us``;
    ``gmw/en-US``; a variant after '+', ``en-us+f3``), or a :class:`SpeechError` naming it with a
    few close matches. Nothing but listed names ever reaches espeak-ng."""
    voices, variants = _voice_tables(_espeak())
    name = voice if isinstance(voice, str) else ""
    base, plus, variant = name.partition("+")
    canonical = voices.get(base.lower())
    if canonical is not None and plus:
        v = variants.get(variant.lower())
        if v is None:
            close = difflib.get_close_matches(variant.lower(), sorted(variants), n=3, cutoff=0.6)
            hint = ", ".join(f"{canonical}+{variants[c]}" for c in close) or f"{canonical}+f3"
            raise SpeechError(f"unknown espeak-ng voice variant '{_shown(variant)}'; run "
                              f"`espeak-ng --voices=variant` to list them (e.g. {hint})")
        return f"{canonical}+{v}"
    if canonical is None:
        codes = sorted({v for v in voices.values() if "/" not in v})
        close = difflib.get_close_matches(base.lower(), [c.lower() for c in codes], n=3, cutoff=0.6)
        hint = ", ".join(voices[c] for c in close) or DEFAULT_VOICE
        raise SpeechError(f"unknown espeak-ng voice '{_shown(voice)}'; run `espeak-ng --voices` to list them "
                          f"(e.g. {hint})")
    return canonical


def check_speed(speed) -> int:
    """An espeak-ng speaking rate in words per minute (80-450)."""
    from faceanim.limits import check_range

    return check_range(speed, "the speaking rate (words per minute)", MIN_WPM, MAX_WPM, integer=True)


def _espeak_wav(exe: str, text: str, out: Path, voice: str, speed: int) -> None:
    """Run espeak-ng on ``text`` (given on stdin, so no text is ever read as an option) into ``out``."""
    try:
        result = subprocess.run([exe, "-v", voice, "-s", str(speed), "-w", str(out), "--stdin"], input=text,
                                capture_output=True, text=True, check=False, timeout=ESPEAK_TIMEOUT)
    except (OSError, subprocess.TimeoutExpired) as exc:
        log.debug("espeak-ng failed to run: %s", exc)
        raise SpeechError("espeak-ng could not be run; check it with `espeak-ng -v en-us hello`") from None
    if result.stderr.strip() or result.stdout.strip():
        log.debug("espeak-ng said: %s %s", result.stdout.strip(), result.stderr.strip())
    if result.returncode != 0 or not out.is_file() or out.stat().st_size == 0:
        raise SpeechError(f"espeak-ng could not synthesize speech with voice '{voice}' (exit code "
                          f"{result.returncode}); check it with `espeak-ng -v {voice} hello`")


# ----------------------------------------------------------------------------------- alignment


def _decoder():
    Decoder = require("pocketsphinx", "aligning speech with its transcript").Decoder

    return Decoder(samprate=SAMPLE_RATE, loglevel="FATAL")


def _pcm16_bytes(x: np.ndarray) -> bytes:
    """16 kHz float samples as the signed 16-bit little-endian bytes pocketsphinx reads."""
    return (np.clip(x, -1, 1) * 32767).astype("<i2").tobytes()


def _samples(audio, rate) -> tuple[np.ndarray, int]:
    """Samples and rate of ``audio``: an audio file (WAV, FLAC, OGG, ...) or samples with ``rate``."""
    if isinstance(audio, (str, Path)):
        return read_audio(audio)
    if rate is None:
        raise SpeechError("give the sample rate of the audio samples")
    rate = check_rate(rate)
    x = np.asarray(audio, dtype=np.float32)
    if x.ndim != 1 or x.size == 0 or not np.all(np.isfinite(x)):
        raise SpeechError("audio samples must be a non-empty 1-D array of finite numbers")
    if x.size / rate > MAX_DURATION:
        raise SpeechError(f"the audio is longer than {MAX_DURATION:g} s; give it in shorter pieces")
    return x, rate


MAX_NEW_WORDS = 200  # words outside the dictionary a transcript may have (each asks espeak-ng once)


def espeak_pronunciations(words: list[str], voice: str = DEFAULT_VOICE) -> dict[str, str]:
    """ARPAbet pronunciations (space-separated, as the pocketsphinx dictionary has them) that
    espeak-ng gives words the dictionary lacks: its IPA (``espeak-ng --ipa``) read phone by phone
    through :func:`faceanim.standards.ipa.arpabet`. Words espeak-ng cannot say, or when it is not
    installed, are left out (the caller refuses them by name)."""
    exe = shutil.which("espeak-ng")
    out: dict[str, str] = {}
    if exe is None or not words:
        return out
    for word in words[:MAX_NEW_WORDS]:
        if not re.fullmatch(r"[a-z0-9']+", word):  # transcript words only (words_of): never an option
            continue
        try:
            result = subprocess.run([exe, "-q", "-v", voice, "--ipa", "--sep=_", word], capture_output=True,
                                    text=True, timeout=30, check=False)
        except (OSError, subprocess.TimeoutExpired):
            return out
        phones = []
        for ipa in result.stdout.replace(" ", "_").split("_"):
            names = ipa_arpabet(ipa) if ipa.strip() else []
            if names is None:
                phones = []
                break
            phones += [n for n in names if n != "SIL"]
        if result.returncode == 0 and phones:
            out[word] = " ".join(phones)
    return out


def align(audio, transcript: str, rate: int | None = None, decoder=None) -> list[Phone]:
    """Timed phones of ``transcript`` in ``audio`` (an audio file - WAV, FLAC, OGG, ... - or samples
    with their ``rate``); ``decoder`` reuses a pocketsphinx decoder (loading the model takes ~0.3 s)."""
    x, rate = _samples(audio, rate)
    words = words_of(transcript, "the transcript")
    if not len(x) or float(np.sqrt(np.mean(np.square(x, dtype=np.float64)))) < SILENT_RMS:
        raise SpeechError("no speech was heard in the audio (it is silent); give a recording of the transcript spoken")
    dec = decoder or _decoder()
    unknown = [w for w in dict.fromkeys(words) if dec.lookup_word(w) is None]
    for word, pron in espeak_pronunciations(unknown).items():  # names, rare and new words
        dec.add_word(word, pron, True)
    unknown = [w for w in unknown if dec.lookup_word(w) is None]
    if unknown:
        raise SpeechError(f"the pronunciation dictionary does not know: {', '.join(map(_shown, unknown[:8]))}; "
                          "spell numbers and abbreviations out as words")
    raw = _pcm16_bytes(resample(x, rate, SAMPLE_RATE))
    duration = len(raw) / 2 / SAMPLE_RATE
    if duration < 0.1 * len(words):
        raise SpeechError(f"{duration:.2f} s of audio is too short for {len(words)} words; "
                          "does the audio match its transcript?")
    try:
        dec.set_align_text(" ".join(words))
        dec.start_utt()
        dec.process_raw(raw, full_utt=True)
        dec.end_utt()
        dec.set_alignment()
        dec.start_utt()
        dec.process_raw(raw, full_utt=True)
        dec.end_utt()
        alignment = dec.get_alignment()
    except (RuntimeError, ValueError) as exc:
        log.debug("pocketsphinx failed: %s", exc)
        raise SpeechError("the audio could not be aligned with its transcript; "
                          "does the audio match its transcript?") from None
    phones = []
    for word in alignment or []:
        for p in word:
            phones.append(Phone(p.name, p.start * FRAME, (p.start + p.duration) * FRAME,
                                "" if word.name.startswith("<") else word.name))
    spoken = [p for p in phones if p.phone != "SIL"]
    if not spoken:
        raise SpeechError("the audio could not be aligned with its transcript; does the audio match it?")
    # a transcript forced onto audio that says something else squeezes most phones to the
    # aligner's minimum of 3 frames
    squeezed = np.mean([p.end - p.start <= 3.01 * FRAME for p in spoken])
    if len(spoken) >= 8 and squeezed > 0.5:
        raise SpeechError(f"{squeezed:.0%} of the phones got the shortest possible duration: the audio "
                          "does not seem to match its transcript")
    return phones


def recognise_phones(audio, rate: int | None = None) -> list[Phone]:
    """Timed phones heard in ``audio`` with no transcript (what Rhubarb Lip Sync does): the
    pocketsphinx model decoded in its all-phone mode with the phone-bigram model that ships with it
    (``en-us-phone.lm.bin``). Less exact than :func:`align` (the words are not known), but the
    mouth needs only the phone classes and their times."""
    import os

    pocketsphinx = require("pocketsphinx", "hearing phones in speech without a transcript")
    Decoder = pocketsphinx.Decoder
    x, rate = _samples(audio, rate)
    if float(np.sqrt(np.mean(np.square(x, dtype=np.float64)))) < SILENT_RMS:
        raise SpeechError("no speech was heard in the audio (it is silent); give a recording of someone speaking")
    model = Path(os.path.dirname(pocketsphinx.__file__)) / "model" / "en-us"
    raw = _pcm16_bytes(resample(x, rate, SAMPLE_RATE))
    try:
        dec = Decoder(allphone=str(model / "en-us-phone.lm.bin"), lm=None, samprate=SAMPLE_RATE, loglevel="FATAL",
                      beam=1e-20, pbeam=1e-20, lw=2.0)
        dec.start_utt()
        dec.process_raw(raw, full_utt=True)
        dec.end_utt()
        segments = list(dec.seg())
    except (RuntimeError, ValueError) as exc:
        log.debug("pocketsphinx failed: %s", exc)
        raise SpeechError("no speech could be recognised in the audio") from None
    phones = [Phone(seg.word, seg.start_frame * FRAME, (seg.end_frame + 1) * FRAME, "")
              for seg in segments if seg.word not in ("<s>", "</s>")]
    phones = [Phone("SIL" if p.phone in ("+NSN+", "+SPN+", "+BREATH+", "+NOISE+") else p.phone, p.start, p.end, "")
              for p in phones]
    if not any(p.phone != "SIL" for p in phones):
        raise SpeechError("no speech was heard in the audio; give a recording of someone speaking")
    return phones


def synthesize(text: str, wav_path, voice: str = DEFAULT_VOICE, speed: int = SENTENCE_WPM) -> Path:
    """Speak ``text`` with espeak-ng into a WAV file (espeak-ng's own rate, 22.05 kHz)."""
    check_text(text)  # refuse text with nothing to say before starting a process
    speed = check_speed(speed)
    exe = _espeak()
    voice = check_voice(voice)
    out = Path(wav_path)
    _espeak_wav(exe, text, out, voice, speed)
    return out


# inherent phone durations (ms) after Klatt's duration rules (J. Acoust. Soc. Am. 1979; the MITalk
# system): a word the aligner cannot time is shared among its phones in these proportions, so a
# vowel outlasts the plosive before it instead of each phone taking an equal part
INHERENT_MS = {
    "AA": 240, "AE": 230, "AH": 140, "AO": 240, "AW": 260, "AY": 250, "EH": 150, "ER": 180, "EY": 190,
    "IH": 135, "IY": 155, "OW": 220, "OY": 280, "UH": 160, "UW": 210,
    "B": 85, "CH": 70, "D": 75, "DH": 50, "F": 100, "G": 80, "HH": 80, "JH": 70, "K": 80, "L": 80, "M": 70,
    "N": 60, "NG": 95, "P": 85, "R": 80, "S": 105, "SH": 105, "T": 75, "TH": 90, "V": 60, "W": 80, "Y": 80,
    "Z": 75, "ZH": 70,
}


def share_by_inherent_duration(pron: list[str], start: float, end: float, word: str = "") -> list[Phone]:
    """Timed phones for ``pron`` (ARPAbet, stress digits allowed) spread over [start, end] in
    proportion to their :data:`INHERENT_MS` (80 ms for a phone not in the table)."""
    ms = np.array([INHERENT_MS.get(p.upper().rstrip("012"), 80) for p in pron], dtype=np.float64)
    edges = start + (end - start) * np.r_[0.0, np.cumsum(ms)] / ms.sum()
    return [Phone(p.upper().rstrip("012"), float(a), float(b), word) for p, a, b in zip(pron, edges[:-1], edges[1:])]


PAUSES = {",": 0.2, ";": 0.25, ":": 0.25, ".": 0.4, "?": 0.4, "!": 0.4}
WORD_GAP = 0.02


def _silence(seconds: float) -> np.ndarray:
    return np.zeros(round(seconds * SAMPLE_RATE), dtype=np.float32)


# espeak-ng's phoneme mnemonics (English voices) as ARPAbet; a mnemonic with its marks (#, :, -,
# digits) stripped is looked up again; one that is still unknown adds its time to the phone before
ESPEAK_ARPABET = {
    "p": "P", "b": "B", "t": "T", "d": "D", "k": "K", "g": "G", "f": "F", "v": "V", "T": "TH", "D": "DH",
    "s": "S", "z": "Z", "S": "SH", "Z": "ZH", "tS": "CH", "dZ": "JH", "h": "HH", "x": "HH", "m": "M", "n": "N",
    "N": "NG", "l": "L", "r": "R", "w": "W", "j": "Y", "?": "T", "t#": "T", "d#": "D",
    "a": "AE", "a#": "AH", "A": "AA", "A:": "AA", "A@": "AA R", "0": "AA", "O": "AO", "O:": "AO", "O@": "AO R",
    "o@": "AO R", "@": "AH", "@L": "AH L", "3": "ER", "3:": "ER", "V": "AH", "E": "EH", "e@": "EH R", "I": "IH",
    "i": "IY", "i:": "IY", "i@": "IH R", "i@3": "IH R", "U": "UH", "u:": "UW", "U@": "UH R", "aI": "AY",
    "aU": "AW", "OI": "OY", "eI": "EY", "oU": "OW", "aI@": "AY ER", "aI3": "AY ER", "aU@": "AW ER",
    "e": "EH", "o": "OW", "u": "UW", "y": "UW",
}
STOPS = ("P", "B", "T", "D", "K", "G", "CH", "JH")
CLOSURE = 0.045  # seconds of a stop's closure before its burst (espeak-ng times a stop from its burst)


def _arpabet(mnemonic: str) -> list[str] | None:
    if mnemonic.startswith("_") or mnemonic in ("", "||", "|"):
        return ["SIL"]
    for key in (mnemonic, mnemonic.strip("#:-;/,'!0123456789") or mnemonic):
        if key in ESPEAK_ARPABET:
            return ESPEAK_ARPABET[key].split()
    return None


def _library_speech(text: str, voice: str, speed: int) -> tuple[np.ndarray, int, list]:
    """Run :mod:`faceanim.drivers.speech.espeak_lib` in two fresh processes side by side, one with
    espeak-ng's phoneme mnemonics, one with IPA (the same synthesis, so the same events at the same
    samples): the sound (float32) and rate, and espeak-ng's events, each phoneme event as
    ``["phoneme", mnemonic, ms, ipa]`` (``ipa`` "" where the two runs disagree). OSError when
    espeak-ng's library is not there; espeak-ng's own messages are never shown (logged at debug
    level)."""
    import json
    import sys
    import tempfile

    from faceanim.drivers.speech import espeak_lib

    failed = SpeechError(f"espeak-ng could not synthesize speech with voice '{_shown(voice)}'; "
                         f"check it with `espeak-ng -v {_shown(voice)} hello`")
    with tempfile.TemporaryDirectory() as tmp:
        runs = []
        try:
            for ipa in (False, True):
                raw = str(Path(tmp) / f"speech{int(ipa)}.raw")
                proc = subprocess.Popen([sys.executable, espeak_lib.__file__, raw], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                runs.append((proc, json.dumps({"text": text, "voice": voice, "rate": speed, "ipa": ipa})))
            answers = [proc.communicate(request, timeout=ESPEAK_TIMEOUT) + (proc.returncode,) for proc, request in runs]
        except (OSError, subprocess.TimeoutExpired) as exc:
            for proc, _ in runs:
                proc.kill()
                proc.wait()
            log.debug("espeak-ng's library could not be run: %s", exc)
            raise SpeechError("espeak-ng could not be run; check it with `espeak-ng -v en-us hello`") from None
        if any(code == 3 for *_, code in answers):
            raise OSError("espeak-ng's library is not available")
        parsed = []
        for out, err, code in answers:
            if err.strip():
                log.debug("espeak-ng's library said: %s", err.strip())
            try:
                if code != 0:
                    raise ValueError(f"exit code {code}")
                answer = json.loads(out)
                parsed.append((int(answer["rate"]), list(answer["events"])))
            except (ValueError, KeyError, TypeError) as exc:
                log.debug("espeak-ng's library failed: %s", exc)
                raise failed from None
        try:
            x = np.fromfile(Path(tmp) / "speech0.raw", dtype="<i2").astype(np.float32) / 32768.0
        except OSError:
            raise failed from None
    (rate, events), (_, ipa_events) = parsed
    marks = [e for e in events if e[0] == "phoneme"]
    ipa = [e for e in ipa_events if e[0] == "phoneme"]
    same = len(marks) == len(ipa) and all(a[2] == b[2] for a, b in zip(marks, ipa))
    if not same:
        log.debug("espeak-ng's IPA and mnemonic runs differ; reading the mnemonics alone")
    names = iter(ipa)
    events = [e + [str(next(names)[1]) if same else ""] if e[0] == "phoneme" else e for e in events]
    return x, rate, events


def espeak_phones(text: str, voice: str = DEFAULT_VOICE, speed: int = WORD_WPM) -> tuple[np.ndarray, int, list[Phone]]:
    """Speak ``text`` with espeak-ng's library in one go (:mod:`~faceanim.drivers.speech.espeak_lib`)
    and return the sound (float32, mono), its rate and the phones with espeak-ng's own timing: each
    phoneme from where its sound starts to where the next one's does (a stop from :data:`CLOSURE`
    before its burst, as its lips or tongue close before), as the ARPAbet phones of the same mouth
    (its IPA through :func:`faceanim.standards.ipa.arpabet`, so any language and any word espeak-ng
    speaks; where espeak-ng gives no IPA, its mnemonic through :data:`ESPEAK_ARPABET`; a phone that
    is two, such as a diphthong before r, shared by :data:`INHERENT_MS`), pauses as ``SIL``, each
    with its word. Raises OSError when the library cannot be loaded."""
    check_text(text)
    x, rate, events = _library_speech(text, check_voice(voice), check_speed(speed))
    total = len(x) / rate
    marks = [e for e in events if e[0] == "phoneme"]
    starts = [e[2] / 1000.0 for e in marks] + [total]
    data = text.encode("utf-8")
    word_at, word_names = [], []
    for _, (position, length), ms in (e for e in events if e[0] == "word"):
        first = max(int(position) - 1, 0)  # espeak-ng counts from 1
        word_at.append(ms / 1000.0)
        word_names.append(data[first:first + int(length)].decode("utf-8", "replace").lower())
    phones: list[Phone] = []
    for k, (_, mnemonic, _, ipa) in enumerate(marks):
        a, b = starts[k], max(starts[k + 1], starts[k])
        if b <= a:
            continue
        names = _arpabet(mnemonic)
        if names != ["SIL"]:
            names = ipa_arpabet(ipa) or names
        if names is None:
            if phones:
                last = phones[-1]
                phones[-1] = Phone(last.phone, last.start, b, last.word)
            continue
        w = bisect.bisect_right(word_at, a + 1e-9)  # the last word begun by now
        word = word_names[w - 1] if w and names != ["SIL"] else ""
        phones += share_by_inherent_duration(names, a, b, word) if len(names) > 1 else [Phone(names[0], a, b, word)]
    out: list[Phone] = []
    for p in phones:  # a stop's closure: taken from the phone before it
        if p.phone in STOPS and not out:
            p = Phone(p.phone, max(0.0, p.start - CLOSURE), p.end, p.word)
        elif p.phone in STOPS:
            prev = out[-1]
            # a pause gives the whole closure; a sound before it at most 40% of its length
            cut = max(p.start - CLOSURE, prev.start + (0.0 if prev.phone == "SIL" else 0.6) * (p.start - prev.start))
            out[-1] = Phone(prev.phone, prev.start, cut, prev.word)
            p = Phone(p.phone, cut, p.end, p.word)
        if out and out[-1].phone == "SIL" and p.phone == "SIL":
            out[-1] = Phone("SIL", out[-1].start, p.end)
            continue
        out.append(p)
    if not any(p.phone != "SIL" for p in out):
        raise SpeechError("espeak-ng made no speech of the text; give words it can say")
    return x, rate, out


def say_timed(text: str, wav_path, voice: str = DEFAULT_VOICE, speed: int = WORD_WPM) -> list[Phone]:
    """Speak ``text`` with espeak-ng into one 16 kHz WAV and return its timed phones.

    The whole text is spoken in one go by espeak-ng's library with its own phoneme timing
    (:func:`espeak_phones`): one flowing utterance, each phone as long as espeak-ng makes it. Where
    the library cannot be loaded, the words are spoken one by one by the espeak-ng program and each
    is aligned (:func:`say_word_by_word`).
    """
    check_text(text)
    speed = check_speed(speed)
    exe = _espeak()
    voice = check_voice(voice)
    try:
        x, rate, phones = espeak_phones(text, voice, speed)
    except OSError:
        return say_word_by_word(text, wav_path, voice, speed, exe)
    write_wav(wav_path, resample(x, rate, SAMPLE_RATE), SAMPLE_RATE)
    return phones


def say_word_by_word(text: str, wav_path, voice: str = DEFAULT_VOICE, speed: int = WORD_WPM,
                     exe: str | None = None) -> list[Phone]:
    """Speak ``text`` word by word with the espeak-ng program into one 16 kHz WAV and return its
    timed phones (without espeak-ng's library).

    Each word is synthesized alone and aligned alone (short and therefore robust: aligning a whole
    synthesized sentence fails on the robotic voice), then the words are joined with short gaps and
    pauses at punctuation, so every phone's time is known by construction.
    """
    import tempfile

    check_text(text)
    speed = check_speed(speed)
    exe = exe or _espeak()
    voice = check_voice(voice)
    tokens = re.findall(r"[A-Za-z0-9']+|[,;:.?!]", text)
    tokens = [t for t in tokens if t in PAUSES or t.strip("'")]
    dec = _decoder()
    new = [t.lower().strip("'") for t in tokens if t not in PAUSES and dec.lookup_word(t.lower().strip("'")) is None]
    for word, pron in espeak_pronunciations(list(dict.fromkeys(new)), voice).items():
        dec.add_word(word, pron, True)
    for token in tokens:  # every word known before any synthesis
        word = token.lower().strip("'")
        if token not in PAUSES and dec.lookup_word(word) is None:
            raise SpeechError(f"the pronunciation dictionary does not know '{_shown(word)}'; "
                              "spell numbers and abbreviations out as words")
    pieces, phones, clock = [], [], 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for token in tokens:
            if token in PAUSES:
                pieces.append(_silence(PAUSES[token]))
                phones.append(Phone("SIL", clock, clock + PAUSES[token]))
                clock += PAUSES[token]
                continue
            word = token.lower().strip("'")
            path = Path(tmp) / "w.wav"
            _espeak_wav(exe, token, path, voice, speed)
            x, rate = read_audio(path, "espeak-ng output")
            x = resample(x, rate, SAMPLE_RATE)
            loud = np.flatnonzero(np.abs(x) > 0.02)
            x = x[max(loud[0] - 160, 0):loud[-1] + 160] if len(loud) else x
            try:
                word_phones = [p for p in align(x, word, SAMPLE_RATE, dec) if p.phone != "SIL"]
            except SpeechError:
                word_phones = []
            if not word_phones:  # the dictionary pronunciation over the word by inherent durations
                word_phones = share_by_inherent_duration(dec.lookup_word(word).split(), 0.0, len(x) / SAMPLE_RATE, word)
            phones += [Phone(p.phone, clock + p.start, clock + p.end, word) for p in word_phones]
            pieces.append(x)
            clock += len(x) / SAMPLE_RATE
            pieces.append(_silence(WORD_GAP))
            clock += WORD_GAP
    write_wav(wav_path, np.concatenate(pieces), SAMPLE_RATE)
    return phones
