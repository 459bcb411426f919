import atexit
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
# faceanim's user cache (faceanim.io.cache) in a folder of this test run, not the user's ~/.cache
os.environ["FACEANIM_CACHE"] = tempfile.mkdtemp(prefix="faceanim-test-cache-")
atexit.register(shutil.rmtree, os.environ["FACEANIM_CACHE"], ignore_errors=True)

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
FACEWAREHOUSE = DATA / "facewarehouse-tester1"
ICT = DATA / "ict-facekit"


def need(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"real data not available: {path} (it lives in ../shared/data beside the project)")
    return path


@pytest.fixture(scope="session")
def face():
    from faceanim.face.default import default_face

    return default_face()


@pytest.fixture(scope="session")
def base_face():
    from faceanim.face.default import default_face

    return default_face()


@pytest.fixture(scope="session")
def face_landmarks(face):
    from faceanim.face.default import default_landmarks

    return default_landmarks(face)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture(scope="module")
def browser():
    """Debian's Chromium, headless, driven by Playwright (tests/test_viewer.py says with what flags
    and when it is skipped)."""
    from test_viewer import CHROMIUM, CHROMIUM_FLAGS, _browser_skip_reason

    reason = _browser_skip_reason()
    if reason:
        pytest.skip(reason)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS)
        yield b
        b.close()



def rendered_identity(seed: int):
    """(generic head, one sampled ICT identity's vertices, its front + profile renders loaded as
    photo views): a person whose head is known exactly, seen as faceanim photo sees photos."""
    from faceanim.build import photo
    from faceanim.face.generic_head import generic_head
    from faceanim.face.mesh import Mesh
    from faceanim.render import OffscreenRenderer

    head = generic_head()
    truth = head.identity(np.random.default_rng(seed).standard_normal(head.n_identity))
    skin_faces = head.mesh.faces[np.isin(head.mesh.faces, head.parts["skin"]).all(axis=1)]
    mesh = Mesh(truth, skin_faces)
    renders = []
    for yaw in (0.0, 90.0):
        with OffscreenRenderer(mesh, size=(512, 512), yaw=yaw, parallel=True, background=(0.5, 0.5, 0.5)) as r:
            renders.append(r.render())
    return head, truth, photo.load_views(("front", renders[0]), [("profile", renders[1])])
