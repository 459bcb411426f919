"""The user cache (faceanim.io.cache): what comes back is what was computed, bit for bit; it is
used; a damaged entry or an edited faceanim is never read; it can be turned off."""

import numpy as np
import pytest

from faceanim.io import cache
from faceanim.io.cache import cached_arrays, content_key


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.setenv("FACEANIM_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _work(calls):
    def compute():
        calls.append(1)
        rng = np.random.default_rng(3)
        sparse = np.zeros((500, 3))
        sparse[[4, 77, 400]] = rng.normal(size=(3, 3))
        return {"dense": rng.normal(size=(100, 3)), "sparse": sparse, "ints": np.arange(5)}, {"why": "made"}
    return compute


def test_cached_arrays_come_back_exactly_and_are_reused(folder):
    calls = []
    first = cached_arrays("k", "abc", _work(calls))
    second = cached_arrays("k", "abc", _work(calls))
    assert len(calls) == 1 and list(second[0]) == ["dense", "sparse", "ints"] and second[1] == {"why": "made"}
    for name in first[0]:
        assert second[0][name].dtype == first[0][name].dtype
        np.testing.assert_array_equal(second[0][name], first[0][name])
    (entry,) = (folder / "k").glob("*.npz")
    entry.write_bytes(b"not an npz")  # damaged: computed again, and mended
    cached_arrays("k", "abc", _work(calls))
    assert len(calls) == 2 and len(cached_arrays("k", "abc", _work(calls))[0]) == 3 and len(calls) == 2


def test_the_cache_can_be_off_and_keeps_few_entries(folder, monkeypatch):
    calls = []
    for k in range(cache.KEEP + 3):
        cached_arrays("k", f"key{k}", _work(calls))
    assert len(list((folder / "k").glob("*.npz"))) == cache.KEEP
    monkeypatch.setenv("FACEANIM_CACHE", "off")
    cached_arrays("k", "key0", _work(calls))
    cached_arrays("k", "key0", _work(calls))
    assert len(calls) == cache.KEEP + 5


def test_keys_change_with_the_input_and_with_faceanim_itself(monkeypatch):
    a = content_key(np.zeros(3), "x")
    assert a == content_key(np.zeros(3), "x") and a != content_key(np.zeros(3), "y")
    assert a != content_key(np.zeros(3, dtype=np.float32), "x") and a != content_key(np.zeros(4), "x")
    monkeypatch.setattr(cache, "code_fingerprint", lambda: "another faceanim")
    assert content_key(np.zeros(3), "x") != a


def test_the_default_faces_arkit_shapes_from_the_cache_equal_the_computed(folder, monkeypatch):
    from faceanim.face.face import Face
    from faceanim.rig import arkit

    face = Face.default()
    calls = []
    real = arkit._arkit_shapes

    def counted(f, eyes, style):
        calls.append(style)
        return real(f, eyes, style)

    monkeypatch.setattr(arkit, "_arkit_shapes", counted)
    made, why = arkit.arkit_shapes(face)
    again, why2 = arkit.arkit_shapes(face)
    assert calls == ["realistic"] and why == why2 and list(again) == list(made)
    for name in made:
        np.testing.assert_array_equal(again[name], made[name])
    stylised, _ = arkit.arkit_shapes(face, style="stylised")  # a style of its own in the cache
    assert calls == ["realistic", "stylised"]
    assert not np.array_equal(stylised["eyeBlinkLeft"], made["eyeBlinkLeft"])
