"""faceanim's optional parts (faceanim/extras.py): a command that needs one that is missing says
which extra to install, in one line, exit 2, before any work; the core never imports them."""

import subprocess
import sys

import pytest
from conftest import DATA, need

from faceanim.cli import main
from faceanim.extras import MissingExtra, require


@pytest.fixture
def without(monkeypatch):
    def hide(*modules):
        for m in modules:
            monkeypatch.setitem(sys.modules, m, None)  # `import m` now raises ImportError
    return hide


def test_require_names_the_extra(without):
    without("distributed")
    with pytest.raises(MissingExtra, match=r"faceanim batch needs faceanim's 'batch' extra.*faceanim\[batch\]"):
        require("distributed", "faceanim batch")
    assert require("json", "x").dumps([1]) == "[1]"


def test_say_audio_without_the_speech_extra(without, tmp_path, capsys):
    clip = need(DATA / "speech-librivox" / "clip-0880.wav")
    without("pocketsphinx")
    out = tmp_path / "x.csv"
    assert main(["say", "--audio", str(clip), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'speech' extra" in err[0] and "pip install 'faceanim[speech]'" in err[0]
    assert not out.exists()


def test_live_sinks_and_sound_without_the_live_extra(without, tmp_path, capsys):
    without("pythonosc", "pocketsphinx")
    assert main(["live", "--audio", str(tmp_path / "none.wav"), "--to", "csv:" + str(tmp_path / "t.csv")]) == 2
    assert "'speech' extra" in capsys.readouterr().err  # pocketsphinx: the speech extra (live has it too)
    from faceanim.live.sinks import VmcSink

    with pytest.raises(MissingExtra, match="'live' extra"):
        VmcSink("vmc://127.0.0.1:39539")


def test_batch_without_the_batch_extra(without):
    from faceanim.batch import runner

    without("distributed")
    with pytest.raises(MissingExtra, match="'batch' extra"):
        runner._client(None, 1)


def test_the_core_does_not_import_the_extras():
    """Rigging, the default face and glTF writing import none of the optional packages."""
    code = ("import sys\nfrom faceanim.autorig import auto_rig\nfrom faceanim.io.gltf import write_gltf\n"
            "from faceanim.cli import build_parser\nbuild_parser()\n"
            "print(sorted(m for m in ('pocketsphinx', 'pythonosc', 'websockets', 'distributed', 'dask', 'bokeh')"
            " if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
