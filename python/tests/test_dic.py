"""cellinject.dic: a real photograph shifted by a known sub-pixel amount, the CLI's
numbers on the same images, dtypes, errors, and the GIL released during a field."""

import threading
import time

import numpy as np
import pytest

import cellinject
from cellinject import dic
from conftest import PHOTOS, fourier_shift, read_png, write_png

SHIFT = (0.37, -0.21)


@pytest.fixture(scope="module")
def photo_pair():
    """scikit-image's `gravel` (CC0, crops/README in crates/dic/tests/data/photos) and
    its exact Fourier shift by SHIFT, rounded to 8 bits like a camera frame.

    Measured (this textured-point rule, SHIFT): median |error| u, v 0.0068, 0.0091 px on
    gravel; on the other photographs 0.005-0.019 px (brick 0.0097, 0.0114; grass 0.0091,
    0.0187): the 0.01 px median holds on gravel, not on every photograph."""
    ref = read_png(PHOTOS / "gravel.png")
    cur = np.round(fourier_shift(ref, *SHIFT)).clip(0, 255).astype(np.uint8)
    return ref, cur


def textured_points(img, subset=31, step=20, limit=0.01):
    """Grid points whose subset's noise limit (Pan et al. 2008: sqrt(2)·σ/sqrt(Σ(∇f −
    mean ∇f)²), σ the 8-bit rounding's 1/sqrt(12)) is at most `limit` px in x and y,
    and whose shifted subset stays 3 px inside the image. Independent of the DIC."""
    f = img.astype(float)
    gy, gx = np.gradient(f)
    h, w = f.shape
    r = subset // 2
    sigma = 1 / np.sqrt(12)
    pts = []
    for y in range(r + 4, h - r - 4, step):
        for x in range(r + 4, w - r - 4, step):
            sx = gx[y - r : y + r + 1, x - r : x + r + 1]
            sy = gy[y - r : y + r + 1, x - r : x + r + 1]
            lx = np.sqrt(2) * sigma / np.sqrt(((sx - sx.mean()) ** 2).sum())
            ly = np.sqrt(2) * sigma / np.sqrt(((sy - sy.mean()) ** 2).sum())
            if lx <= limit and ly <= limit:
                pts.append((float(x), float(y)))
    return pts


def test_a_real_photograph_shifted_by_a_known_subpixel_amount(photo_pair, cli, tmp_path):
    ref, cur = photo_pair
    at = textured_points(ref)
    assert len(at) >= 40, len(at)
    r = dic.points(ref, cur, at)
    ok = r["converged"]
    # Most textured points are measurements (the acceptance rule may still find a
    # subset too uncertain); the error is judged over those.
    assert ok.mean() >= 0.8, ok.mean()
    eu = np.abs(r["u"][ok] - SHIFT[0])
    ev = np.abs(r["v"][ok] - SHIFT[1])
    assert np.median(eu) <= 0.01 and np.median(ev) <= 0.01, (np.median(eu), np.median(ev))
    # The CLI on the same images, as 8-bit PNG files: the same numbers.
    write_png(tmp_path / "ref.png", ref)
    write_png(tmp_path / "cur.png", cur)
    args = ["dic", "--reference", "ref.png", "--current", "cur.png", "--format", "json"]
    for x, y in at:
        args += ["--at", f"{x},{y}"]
    c = cli(*args, cwd=tmp_path)
    assert [p["x"] for p in c] == [p[0] for p in at]
    for k, p in enumerate(c):
        if p["u"] is None:
            assert not r["converged"][k] and r["error"][k] == p["error"]
            continue
        for key in ["u", "v", "du_dx", "dv_dy", "zncc", "sigma_u", "sigma_v"]:
            assert r[key][k] == p[key], (key, k, r[key][k], p[key])
        assert r["iterations"][k] == p["iterations"] and r["subset"][k] == p["subset"]


def test_dtypes_give_the_same_numbers_and_others_are_refused(photo_pair):
    ref, cur = photo_pair
    at = [(128.0, 128.0), (80.0, 170.0)]
    base = dic.points(ref, cur, at)
    assert base["u"].dtype == np.float64 and base["converged"].dtype == np.bool_
    assert base["iterations"].dtype == np.int64
    for dt in [np.uint16, np.float32, np.float64]:
        r = dic.points(ref.astype(dt), cur.astype(dt), np.array(at, dtype=np.float32))
        np.testing.assert_array_equal(r["u"], base["u"])
        np.testing.assert_array_equal(r["v"], base["v"])
    # Not a copy-free view either: a Fortran-ordered or strided image reads the same.
    r = dic.points(np.asfortranarray(ref), cur[:, :], at)
    np.testing.assert_array_equal(r["u"], base["u"])
    with pytest.raises(cellinject.InputError, match="reference.*dtype int64"):
        dic.points(ref.astype(np.int64), cur, at)
    with pytest.raises(cellinject.InputError, match="current.*complex128"):
        dic.points(ref, cur.astype(complex), at)


def test_bad_images_and_settings_are_input_errors_naming_the_argument(photo_pair):
    ref, cur = photo_pair
    cases = [
        (dict(reference=ref[None]), "reference must be a 2-D array"),
        (dict(current=cur.ravel()), "current must be a 2-D array"),
        (dict(current=cur[:100]), "the images must have the same size"),
        (dict(at=[(float("nan"), 3.0)]), r"at\[0\]"),
        (dict(at=[(1.0, 2.0, 3.0)]), "at must be"),
        (dict(at=[(2.0, 2.0)]), "at: "),
        (dict(subset=-31), "subset must be at least 1"),
        (dict(subset=30), "subset"),
        (dict(search=-1), "search"),
        (dict(prefilter=float("nan")), "prefilter"),
        (dict(min_zncc=2.0), "min_zncc must lie in"),
        (dict(max_sigma=-1.0), "max_sigma must be a positive"),
        (dict(shape="warp"), "shape must be affine or rigid"),
        (dict(reference="ref.png"), "reference must be a 2-D NumPy array"),
    ]
    for kw, msg in cases:
        args = dict(reference=ref, current=cur, at=[(128.0, 128.0)])
        args.update(kw)
        with pytest.raises(cellinject.InputError, match=msg):
            dic.points(**args)
    # Nothing to correlate: a uniform image matches nowhere.
    flat = np.full((64, 64), 100, np.uint8)
    with pytest.raises(cellinject.NotConverged):
        dic.points(flat, flat, [(32.0, 32.0)])
    with pytest.raises(cellinject.InputError, match="step must be at least 1"):
        dic.field(ref, cur, step=0)


def test_field_track_and_synth():
    ref, cur = dic.synth(size=(160, 128), shift=(0.75, 0.25), noise=0.5, seed=3)
    assert ref.shape == (128, 160) and ref.dtype == np.float64
    f = dic.field(ref, cur, step=8)
    assert f["points"] == f["nx"] * f["ny"] == len(f["u"]) == len(f["x"])
    ok = f["converged"]
    assert ok.sum() == f["found"] > 0.8 * f["points"]
    assert np.abs(f["u"][ok] - 0.75).max() < 0.05 and np.abs(f["v"][ok] - 0.25).max() < 0.05
    assert np.isnan(f["u"][~ok]).all()
    frames = [ref] + [dic.synth(size=(160, 128), shift=(k * 0.5, 0.0), noise=0.5, seed=3)[1] for k in (1, 2, 3)]
    t = dic.track(np.stack(frames), roi=(50, 40, 40, 40))
    assert t["frames"] == 4 and t["measured"] == 4 and t["status"][0] == "tracked"
    np.testing.assert_allclose(t["u"], [0.0, 0.5, 1.0, 1.5], atol=0.05)
    with pytest.raises(cellinject.InputError, match="size takes WIDTH,HEIGHT between 16 and 20000"):
        dic.synth(size=(8, 8))
    with pytest.raises(cellinject.InputError, match="roi"):
        dic.track(frames, roi=(-1, 0, 10, 10))


def test_a_long_field_releases_the_gil():
    ref, cur = dic.synth(size=(256, 256), shift=(0.3, 0.1), noise=1.0)
    ticks = []
    done = threading.Event()
    span = {}

    def work():
        # Fields one after the other for half a second at least, however fast one is:
        # long enough to tell a released GIL from a held one.
        span["start"] = time.perf_counter()
        while time.perf_counter() - span["start"] < 0.5:
            dic.field(ref, cur, step=3)
        span["end"] = time.perf_counter()
        done.set()

    t = threading.Thread(target=work)
    t.start()
    while not done.is_set():
        ticks.append(time.perf_counter())
    t.join()
    during = [x for x in ticks if span["start"] + 0.05 < x < span["end"] - 0.05]
    took = span["end"] - span["start"]
    assert took > 0.3, f"the field took {took:.3f} s: too short to tell"
    # With the GIL held, this thread could not tick while the field ran (at most a
    # switch interval's worth at its ends); released, it ticks all along.
    assert len(during) > 10000, (len(during), took)
    gaps = np.diff([span["start"]] + during + [span["end"]])
    assert gaps.max() < 0.25 * took, gaps.max()
