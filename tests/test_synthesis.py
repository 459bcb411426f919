"""Data-driven filtering and synthesis (Chai et al. 2003, 4.2-4.3): analytic cases, noise
removal, held-out synthesis on the real take against direct mapping and per-frame K-NN."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from faceanim.drivers.video.synthesis import Synthesiser, segments
from faceanim.errors import FaceAnimError

TAKE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "arkit-curves" / "alex_rom_3.csv"


def smooth_database(n=600, seed=0):
    """Controls: smooth random curves; markers: a fixed linear function of the controls."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 30.0
    z = np.stack([np.sin(t * f + p) for f, p in zip(rng.uniform(0.3, 2.0, 15), rng.uniform(0, 6, 15))], axis=1)
    a = rng.normal(size=(15, 8 * 3))
    return z, (z @ a).reshape(n, 8, 3), a


def test_segments_stack_windows_inside_each_take():
    z = np.arange(30, dtype=float).reshape(10, 3)
    s = segments(z, 4, take_starts=(0, 6))
    np.testing.assert_array_equal(s.ends, [3, 4, 5, 9])  # no segment across the take boundary at 6
    np.testing.assert_array_equal(s.controls[0], z[0:4].reshape(-1))
    np.testing.assert_array_equal(s.controls[-1], z[6:10].reshape(-1))
    with pytest.raises(FaceAnimError, match="window must be"):
        segments(z, 11)


def test_a_query_from_the_database_gives_its_own_markers():
    z, m, _ = smooth_database()
    s = Synthesiser(z, m, window=10, k=1, overlap=1)
    out = s.synthesise(z[100:160])
    np.testing.assert_allclose(out[10:], m[110:160], atol=1e-9)  # K = 1: the segment itself


def test_synthesis_follows_a_linear_database_and_filtering_removes_noise():
    z, m, a = smooth_database(seed=1)
    s = Synthesiser(z, m, window=10, k=20, overlap=5)
    rng = np.random.default_rng(2)
    clean = z[200:300]
    noisy = clean + 0.1 * rng.normal(size=clean.shape)
    filtered = s.filter(noisy)
    assert np.abs(filtered - clean).mean() < 0.5 * np.abs(noisy - clean).mean()
    out = s.synthesise(noisy)
    err = np.linalg.norm(out - m[200:300], axis=2).mean()
    direct = np.linalg.norm((noisy @ a).reshape(-1, 8, 3) - m[200:300], axis=2).mean()
    assert err < 0.6 * direct  # better than mapping the noisy controls directly


def test_bad_settings_are_refused():
    z, m, _ = smooth_database(n=50)
    for kw, match in [({"window": 60}, "window must be"), ({"k": 500}, "K must be"),
                      ({"overlap": 30, "window": 10}, "overlap must be"), ({"variance": 0.0}, "variance kept")]:
        with pytest.raises(FaceAnimError, match=match):
            Synthesiser(z, m, **kw)
    with pytest.raises(FaceAnimError, match="query controls must be finite"):
        Synthesiser(z, m, window=5, k=3).synthesise(np.full((4, 15), np.nan))


@pytest.mark.skipif(not TAKE.is_file(), reason="../shared/data/arkit-curves is not here")
def test_held_out_synthesis_on_the_real_take():
    """The database from the first 70% of the take, driven by the controls of the last 30% with
    tracking-like noise: the synthesised markers are nearer the real ones than direct mapping
    (the nearest single frame) and per-frame K-NN averages."""
    from scipy.spatial import cKDTree

    from faceanim.build.motion import build_database
    from faceanim.io.arkit_csv import read_arkit_csv

    db = build_database([("take", read_arkit_csv(TAKE))], fps=15.0)
    cut = int(0.7 * db.n_frames)
    ztr, mtr, zte, mte = db.controls[:cut], db.markers[:cut], db.controls[cut:], db.markers[cut:]
    rng = np.random.default_rng(0)
    query = zte + 0.15 * ztr.std(axis=0) * rng.normal(size=zte.shape)
    out = Synthesiser(ztr, mtr, window=5, k=20, overlap=5).synthesise(query)
    err = np.linalg.norm(out - mte, axis=2).mean()
    tree = cKDTree(ztr)
    _, nn = tree.query(query, k=1)
    direct = np.linalg.norm(mtr[nn] - mte, axis=2).mean()
    _, nnk = tree.query(query, k=10)
    knn = np.linalg.norm(mtr[nnk].mean(axis=1) - mte, axis=2).mean()
    assert err < direct and err < knn


def test_neighbourhood_graph_finds_the_nearest_segments_of_a_coherent_query():
    """The graph walk from the previous query's neighbours finds (nearly) the exact K nearest
    segments of a slowly moving query (the k-d tree as the oracle), and synthesis through it
    matches synthesis through the k-d tree."""
    from scipy.spatial import cKDTree

    from faceanim.drivers.video.synthesis import NeighbourhoodGraph

    z, m, _ = smooth_database(n=900, seed=3)
    seg = segments(z, 5)
    graph = NeighbourhoodGraph(seg.controls)
    tree = cKDTree(seg.controls)
    rng = np.random.default_rng(4)
    query = segments(z[300:500] + 0.02 * rng.normal(size=(200, 15)), 5).controls
    recall = []
    for x in query:
        got = graph.query(x, 10)
        want = tree.query(x, k=10)[1]
        recall.append(len(set(got.tolist()) & set(want.tolist())) / 10)
    assert np.mean(recall) > 0.95
    a = Synthesiser(z, m, window=5, k=10, search="graph").synthesise(z[300:400])
    b = Synthesiser(z, m, window=5, k=10, search="kdtree").synthesise(z[300:400])
    assert np.abs(a - b).max() < 0.05 * np.abs(m).max()
    with pytest.raises(FaceAnimError, match="unknown search"):
        Synthesiser(z, m, window=5, k=3, search="ball")
