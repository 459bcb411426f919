"""scripts/setup.sh: which Debian packages it asks apt-get for, decided one need at a time.

Each test runs a copy of the script with FACEANIM_SETUP_SYSTEM_ONLY=1 (stop after the system
packages) and a PATH holding only stub commands: an apt-get that logs its arguments (and can be
told to fail for a package as apt does on a conflict), an ldconfig that lists the libraries the
test says are there, node/npm/espeak-ng/python3 present or absent, and links to the few real
tools the script needs. Nothing is installed and nothing touches the network.
"""

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "setup.sh"
BASH = shutil.which("bash")

pytestmark = pytest.mark.skipif(BASH is None, reason="bash is needed to run scripts/setup.sh")

REAL_TOOLS = ["bash", "dirname", "id", "readlink"]
# soname -> whether it belongs to the Mesa/GL need (all of them: "all libraries present")
LIBS = [
    "libEGL.so.1",
    "libGL.so.1",
    "libEGL_mesa.so.0",
    "libGLX_mesa.so.0",
    "libgbm.so.1",
    "libglapi.so.0",
    "libglib-2.0.so.0",
    "libgthread-2.0.so.0",
    "libportaudio.so.2",
    "libasound.so.2",
]
MESA_PKGS = ["libegl1", "libgl1", "libegl-mesa0", "libglx-mesa0", "libgbm1", "libgl1-mesa-dri"]
HELD = "E: Unable to correct problems, you have held broken packages."
ESPEAK_NOTE = (
    "setup: note: could not install espeak-ng; speech synthesis (faceanim say TEXT) and its tests will be skipped"
)

FAKE_APT = """#!{bash}
# Log the call; fail like apt on a conflict for a package named in FAKE_APT_FAIL; else "install"
# the commands that the packages carry.
echo "$*" >> "$FAKE_APT_LOG"
for a in "$@"; do
  for bad in $FAKE_APT_FAIL; do
    if [ "$a" = "$bad" ]; then
      echo "Some packages could not be installed."
      echo " $bad : Conflicts: something"
      echo "{held}" >&2
      exit 100
    fi
  done
done
if [ "$1" = install ]; then
  for a in "$@"; do
    case $a in
      espeak-ng) cmd=espeak-ng ;;
      nodejs) cmd=node ;;
      npm) cmd=npm ;;
      chromium) cmd=chromium ;;
      pulseaudio) cmd=pulseaudio ;;
      pulseaudio-utils) cmd="pactl pacat" ;;
      *) continue ;;
    esac
    for c in $cmd; do
      printf '#!{bash}\\nexit 0\\n' > "$FAKE_BIN/$c"
      chmod +x "$FAKE_BIN/$c"
    done
  done
fi
exit 0
"""

FAKE_LDCONFIG = """#!{bash}
[ "$1" = -p ] || exit 1
echo "$(<"$FAKE_LDCONFIG_LIST")"
"""

FAKE_SUDO = """#!{bash}
echo "sudo $*" >> "$FAKE_SUDO_LOG"
while [ $# -gt 0 ]; do
  case $1 in
    -*) shift ;;
    *=*) export "$1"; shift ;;
    *) break ;;
  esac
done
exec "$@"
"""

OK = "#!{bash}\nexit 0\n"


class Sandbox:
    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.repo = tmp / "repo"
        (self.repo / "scripts").mkdir(parents=True)
        shutil.copy(SCRIPT, self.repo / "scripts" / "setup.sh")
        self.bin = tmp / "bin"
        self.bin.mkdir()
        self.libdir = tmp / "lib"
        (self.libdir / "dri").mkdir(parents=True)
        self.apt_log = tmp / "apt.log"
        self.sudo_log = tmp / "sudo.log"
        self.ldlist = tmp / "ldconfig.txt"
        for tool in REAL_TOOLS:
            real = shutil.which(tool)
            assert real, f"{tool} not found"
            (self.bin / tool).symlink_to(real)
        self.stub("apt-get", FAKE_APT.format(bash=BASH, held=HELD))
        self.stub("ldconfig", FAKE_LDCONFIG.format(bash=BASH))
        self.stub("python3", OK.format(bash=BASH))
        self.stub("chromium")  # present unless a test removes it
        for tool in ("pulseaudio", "pactl", "pacat"):  # present unless a test removes them
            self.stub(tool)
        self.libs(LIBS, dri=True)

    def stub(self, name: str, text: str | None = None) -> None:
        path = self.bin / name
        path.unlink(missing_ok=True)  # never write through a link to a real tool
        path.write_text(text or OK.format(bash=BASH))
        path.chmod(0o755)

    def remove(self, *names: str) -> None:
        for name in names:
            (self.bin / name).unlink(missing_ok=True)

    def libs(self, names, dri: bool, pulse_plugin: bool = True) -> None:
        """What `ldconfig -p` lists, and whether Mesa's swrast DRI driver and ALSA's pulse plugin
        lie beside the libraries."""
        lines = [f"{len(names)} libs found in cache `/etc/ld.so.cache'"]
        lines += [f"\t{n} (libc6,x86-64) => {self.libdir / n}" for n in names]
        self.ldlist.write_text("\n".join(lines) + "\n")
        for path, present in ((self.libdir / "dri" / "swrast_dri.so", dri),
                              (self.libdir / "alsa-lib" / "libasound_module_pcm_pulse.so", pulse_plugin)):
            path.parent.mkdir(exist_ok=True)
            if present:
                path.write_text("")
            else:
                path.unlink(missing_ok=True)

    def run(self, fail: str = "", uid: int | None = None, args: tuple = ()) -> subprocess.CompletedProcess:
        if uid is not None:
            self.stub("id", f"#!{BASH}\necho {uid}\n")
        env = {
            "PATH": str(self.bin),
            "HOME": str(self.tmp),
            "LC_ALL": "C",
            "FACEANIM_SETUP_SYSTEM_ONLY": "1",
            "FAKE_APT_LOG": str(self.apt_log),
            "FAKE_APT_FAIL": fail,
            "FAKE_BIN": str(self.bin),
            "FAKE_LDCONFIG_LIST": str(self.ldlist),
            "FAKE_SUDO_LOG": str(self.sudo_log),
        }
        return subprocess.run(
            [BASH, str(self.repo / "scripts" / "setup.sh"), *args],
            env=env,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=30,
        )

    @property
    def apt_calls(self) -> list[list[str]]:
        if not self.apt_log.exists():
            return []
        return [line.split() for line in self.apt_log.read_text().splitlines()]

    def installs(self) -> list[list[str]]:
        """The packages of each `apt-get install` call, in order."""
        return [[a for a in c[1:] if not a.startswith("-")] for c in self.apt_calls if c[0] == "install"]

    def installed_packages(self) -> set[str]:
        return {p for call in self.installs() for p in call}


@pytest.fixture
def box(tmp_path):
    return Sandbox(tmp_path)


def assert_update_once_first(box):
    calls = box.apt_calls
    assert calls[0][0] == "update"
    assert [c[0] for c in calls].count("update") == 1


def test_nodesource_node_present_installs_espeak_and_never_debian_npm(box):
    """(a) This machine: NodeSource's nodejs (node and npm), no espeak-ng."""
    box.stub("node")
    box.stub("npm")
    box.remove("espeak-ng")
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert_update_once_first(box)
    assert box.installs() == [["espeak-ng"]]
    logged = box.apt_log.read_text().split()
    assert "npm" not in logged and "nodejs" not in logged
    assert "setup: installing espeak-ng (espeak-ng)" in r.stdout


def test_nothing_present_asks_for_everything(box):
    """(b) A bare machine: Mesa, GLib, espeak-ng, chromium and Debian's nodejs with npm, each its own call."""
    box.remove("node", "npm", "espeak-ng", "chromium")
    box.libs([], dri=False)
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert_update_once_first(box)
    installs = box.installs()
    assert ["nodejs", "npm"] in installs
    assert ["espeak-ng"] in installs
    assert ["chromium"] in installs
    assert ["libglib2.0-0"] in installs
    assert ["libportaudio2"] in installs
    assert sorted(next(c for c in installs if "libegl1" in c)) == sorted(MESA_PKGS)
    assert len(installs) == 6
    assert "note:" not in r.stderr


def test_espeak_conflict_is_a_note_and_the_rest_still_installs(box):
    """(c) apt-get fails for espeak-ng ("held broken packages"): exit 0, one note, others installed."""
    box.remove("node", "npm", "espeak-ng")
    box.libs([], dri=False)
    r = box.run(fail="espeak-ng")
    assert r.returncode == 0, r.stderr
    assert ESPEAK_NOTE in r.stderr.splitlines()
    assert r.stderr.count("setup: note:") == 1
    assert "held broken packages" in r.stderr
    installed = box.installed_packages()
    assert {"nodejs", "npm", "libglib2.0-0", *MESA_PKGS} <= installed
    # the failure did not stop the calls after it
    order = [c for c in box.installs()]
    assert order.index(["espeak-ng"]) < order.index(["nodejs", "npm"])


def test_chromium_missing_gets_its_own_call_and_a_conflict_is_a_note(box):
    """Debian's chromium (the viewer's browser tests) is optional: its own apt-get call; if apt
    refuses it, one note says which tests will be skipped and the rest still installs."""
    box.stub("node")
    box.stub("npm")
    box.remove("chromium", "espeak-ng")
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert box.installs() == [["espeak-ng"], ["chromium"]]
    assert "setup: installing chromium (chromium)" in r.stdout
    box.apt_log.unlink()
    box.remove("chromium")
    r = box.run(fail="chromium")
    assert r.returncode == 0, r.stderr
    assert box.installs() == [["chromium"]]
    notes = [line for line in r.stderr.splitlines() if line.startswith("setup: note:")]
    assert notes == ["setup: note: could not install chromium; the browser viewer's tests (faceanim view in "
                     "headless Chromium) will be skipped"]


def test_everything_present_never_calls_apt_get(box):
    """(d) Nothing missing: no apt-get at all, not even update; quiet."""
    box.stub("node")
    box.stub("npm")
    box.stub("espeak-ng")
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert box.apt_calls == []
    assert r.stdout == "" and r.stderr == ""


def test_no_apt_get_lists_what_to_install(box):
    """(e) No apt-get: one note naming the packages, a note per optional part, exit 0."""
    box.remove("apt-get", "node", "npm", "espeak-ng")
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert box.apt_calls == []
    listing = next(line for line in r.stderr.splitlines() if "no apt-get" in line)
    assert "espeak-ng" in listing and "nodejs npm" in listing
    assert ESPEAK_NOTE in r.stderr.splitlines()
    assert "glTF validator" in r.stderr


def test_node_without_npm_does_not_install_debian_npm(box):
    """(f) node present, npm missing: Debian's npm would conflict; note the validator is skipped."""
    box.stub("node")
    box.remove("npm")
    box.stub("espeak-ng")
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert box.apt_calls == []
    assert "setup: note:" in r.stderr and "glTF validator" in r.stderr and "skipped" in r.stderr


def test_node_without_npm_while_other_things_install(box):
    """(f') node present, npm missing, espeak-ng missing: espeak-ng yes, npm/nodejs never."""
    box.stub("node")
    box.remove("npm", "espeak-ng")
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert box.installs() == [["espeak-ng"]]
    assert "glTF validator" in r.stderr


def test_npm_conflict_still_installs_nodejs(box):
    """Neither node nor npm, but Debian's npm conflicts: nodejs alone gets installed, validator noted."""
    box.remove("node", "npm")
    box.stub("espeak-ng")
    r = box.run(fail="npm")
    assert r.returncode == 0, r.stderr
    assert box.installs() == [["nodejs", "npm"], ["nodejs"], ["npm"]]
    assert "could not install npm; the glTF validator" in r.stderr


def test_one_mesa_package_failing_does_not_sink_the_others(box):
    box.stub("node")
    box.stub("npm")
    box.stub("espeak-ng")
    box.libs([n for n in LIBS if "EGL" not in n and "GL" not in n and "gbm" not in n], dri=False)
    r = box.run(fail="libgbm1")
    assert r.returncode == 0, r.stderr
    installs = box.installs()
    assert sorted(installs[0]) == sorted(MESA_PKGS)  # the whole need first, then one by one
    assert sorted(p for c in installs[1:] for p in c) == sorted(MESA_PKGS)
    assert "could not install libgbm1; offscreen rendering" in r.stderr
    assert "libegl1;" not in r.stderr


@pytest.mark.parametrize(
    "present, dri, expected",
    [
        (LIBS, False, ["libgl1-mesa-dri"]),  # swrast_dri.so is not in ldconfig's cache
        ([n for n in LIBS if n != "libgbm.so.1"], True, ["libgbm1"]),
        ([n for n in LIBS if n != "libEGL.so.1"], True, ["libegl1"]),
        ([n for n in LIBS if n != "libgthread-2.0.so.0"], True, ["libglib2.0-0"]),
    ],
)
def test_each_library_maps_to_its_own_package(box, present, dri, expected):
    box.stub("node")
    box.stub("npm")
    box.stub("espeak-ng")
    box.libs(present, dri=dri)
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert box.installs() == [expected]


def test_not_root_uses_sudo_without_a_password_prompt(box):
    box.stub("sudo", FAKE_SUDO.format(bash=BASH))
    box.stub("node")
    box.stub("npm")
    box.remove("espeak-ng")
    r = box.run(uid=1000)
    assert r.returncode == 0, r.stderr
    sudo = box.sudo_log.read_text().splitlines()
    assert len(sudo) == 2 and all(s.startswith("sudo -n DEBIAN_FRONTEND=noninteractive apt-get ") for s in sudo)
    assert box.installs() == [["espeak-ng"]]


def test_not_root_without_sudo_prints_what_to_install(box):
    box.remove("espeak-ng")
    box.stub("node")
    box.stub("npm")
    r = box.run(uid=1000)
    assert r.returncode == 0, r.stderr
    assert box.apt_calls == []
    assert "not root and there is no sudo; please install these Debian packages (or their equivalents): espeak-ng" in r.stderr
    assert ESPEAK_NOTE in r.stderr.splitlines()


def test_missing_python_is_required(box):
    """No python3 and no .venv: python3 python3-venv are asked for; if apt cannot, the script fails."""
    box.remove("python3")
    box.stub("node")
    box.stub("npm")
    box.stub("espeak-ng")
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert box.installs() == [["python3", "python3-venv"]]
    box.apt_log.unlink()
    r = box.run(fail="python3-venv")
    assert r.returncode != 0
    assert "setup: error:" in r.stderr


def test_unknown_argument_is_an_error(box):
    r = subprocess.run([BASH, str(box.repo / "scripts" / "setup.sh"), "--bogus"], capture_output=True, text=True)
    assert r.returncode == 2 and "unknown argument" in r.stderr


def test_portaudio_missing_gets_its_own_call_and_a_conflict_is_a_note(box):
    """PortAudio (live --mic) is optional: libportaudio2 in its own call; refused, one note."""
    box.stub("node")
    box.stub("npm")
    box.stub("espeak-ng")
    box.libs([n for n in LIBS if n != "libportaudio.so.2"], dri=True)
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert box.installs() == [["libportaudio2"]]
    assert "setup: installing PortAudio (libportaudio2)" in r.stdout
    box.apt_log.unlink()
    r = box.run(fail="libportaudio2")
    assert r.returncode == 0, r.stderr
    notes = [line for line in r.stderr.splitlines() if line.startswith("setup: note:")]
    assert notes == ["setup: note: could not install libportaudio2; faceanim live --mic (a microphone) will not work"]


def test_the_virtual_microphone_is_asked_for_with_tests_only(box):
    """PulseAudio, its tools and ALSA's pulse plugin (the --mic tests' virtual microphone): with
    --tests, one call for what is missing; without --tests, never."""
    box.stub("node")
    box.stub("npm")
    box.stub("espeak-ng")
    box.remove("pulseaudio", "pactl", "pacat")
    box.libs(LIBS, dri=True, pulse_plugin=False)
    r = box.run()
    assert r.returncode == 0, r.stderr
    assert box.apt_calls == []
    r = box.run(args=("--tests",))
    assert r.returncode == 0, r.stderr
    assert box.installs() == [["pulseaudio", "pulseaudio-utils", "libasound2-plugins"]]
    box.apt_log.unlink()
    box.remove("pactl")  # pulseaudio is there (the fake apt made it), pactl gone; the plugin in place
    box.libs(LIBS, dri=True)
    r = box.run(args=("--tests",))
    assert box.installs() == [["pulseaudio-utils"]]
    box.apt_log.unlink()
    box.remove("pulseaudio")
    r = box.run(fail="pulseaudio", args=("--tests",))
    assert r.returncode == 0, r.stderr
    assert "could not install pulseaudio; the live --mic tests (a virtual microphone) will be skipped" in r.stderr
