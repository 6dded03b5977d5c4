"""cellinject.vision.cells: the same answer as `cellinject vision cells --format json`
on the same image, a phase-contrast disc (bright body, dark halo) found at its
outline in either polarity, bad arguments named."""

import numpy as np
import pytest

import cellinject
from cellinject import vision
from conftest import write_png


def phase_disc(w=240, h=200, c=(131.4, 97.8), r=40.0):
    y, x = np.mgrid[0:h, 0:w]
    d = np.hypot(x - c[0], y - c[1])
    s = lambda e: 0.5 * (1.0 + np.tanh(e / 1.2))
    body = s(r - d)
    halo = s(1.3 * r - d) - body
    return np.round(70.0 + 130.0 * body - 60.0 * halo).astype(np.uint8)


def test_a_disc_is_found_at_its_outline_in_either_polarity():
    img = phase_disc()
    for grey, contrast in [(img, "bright"), (255 - img, "dark")]:
        r = vision.cells(grey, pixel_size=0.2e-6)
        assert r["pixel_size_m"] == 0.2e-6
        assert len(r["cells"]) == 1 and r["debris"] == []
        c = r["cells"][0]
        assert abs(c["x_px"] - 131.4) < 0.5 and abs(c["y_px"] - 97.8) < 0.5
        assert abs(c["diameter_px"] / 80.0 - 1.0) < 0.03
        assert c["diameter_m"] == pytest.approx(c["diameter_px"] * 0.2e-6)
        assert c["contrast"] == contrast
        assert 0.5 <= c["confidence"] <= 1.0
    # Only the other polarity asked for: nothing.
    assert vision.cells(img, contrast="dark")["cells"] == []
    # Without a pixel size: no sizes in m.
    assert vision.cells(img)["cells"][0]["diameter_m"] is None


def test_the_command_line_and_python_agree(tmp_path, cli):
    img = phase_disc()
    write_png(tmp_path / "c.png", img)
    got = cli("vision", "cells", "--image", "c.png", "--pixel-size", "0.2e-6", "--format", "json", cwd=tmp_path)
    assert got.pop("files") == []
    assert got == vision.cells(img, pixel_size=0.2e-6)


def test_bad_arguments_name_themselves():
    img = phase_disc()
    for kw, name in [
        (dict(pixel_size=float("nan")), "pixel_size"),
        (dict(pixel_size=1e300), "pixel_size"),
        (dict(diameter=(1e-5, 2e-5)), "diameter"),
        (dict(pixel_size=1e-6, diameter=(2e-5, 1e-5)), "diameter"),
        (dict(contrast="light"), "contrast"),
    ]:
        with pytest.raises(cellinject.InputError, match=name):
            vision.cells(img, **kw)
    with pytest.raises(cellinject.InputError, match="image"):
        vision.cells(img[:5, :5])


def pipette(w=200, h=150, tip=(80.0, 60.0), blur=0.7):
    """A dark tube entering from the left edge, tapering to its tip: walls darker
    than the lumen, every edge blurred (the physics of cellinject.cells' renderer,
    written again here)."""
    y, x = np.mgrid[0:h, 0:w].astype(float)
    s = lambda e: 0.5 * (1.0 + np.tanh(e / (1.7 * blur)))
    behind = tip[0] - x
    across = np.abs(y - tip[1])
    r = 1.5 + 0.12 * np.maximum(behind, 0.0)
    outer, inner = s(r - across), s(0.65 * r - across)
    dark = s(behind) * (0.12 * outer + 0.45 * (outer - inner))
    ramp = 1.0 + 0.1 * (x / w - 0.5)
    noise = np.random.default_rng(3).normal(0.0, 1.5, (h, w))
    return np.round(np.clip(180.0 * ramp * (1.0 - dark) + noise, 0, 255)).astype(np.uint8)


def test_the_tip_is_found_in_each_turn_of_the_image():
    img = pipette()
    h, w = img.shape
    # (image, where the tip then is, the axis towards the shank in degrees)
    views = [
        (img, (80.0, 60.0), 180.0),
        (img[:, ::-1], (w - 1 - 80.0, 60.0), 0.0),
        (img.T, (60.0, 80.0), -90.0),
        (img[::-1, ::-1], (w - 1 - 80.0, h - 1 - 60.0), 0.0),
    ]
    for grey, (tx, ty), axis in views:
        t = vision.tip(grey, pixel_size=0.5e-6)
        assert abs(t["tip_px"][0] - tx) < 1.5 and abs(t["tip_px"][1] - ty) < 1.5, t
        turn = (np.degrees(t["axis_rad"]) - axis + 180.0) % 360.0 - 180.0
        assert abs(turn) < 2.0, t
        assert t["width_m"] == pytest.approx(t["width_px"] * 0.5e-6)
        assert 0.6 <= t["confidence"] <= 1.0


def test_no_pipette_is_not_a_result_and_the_command_line_agrees(tmp_path, cli):
    bare = np.full((120, 160), 1500, dtype=np.uint16)
    with pytest.raises(cellinject.NotConverged, match="no pipette"):
        vision.tip(bare)
    img = pipette()
    write_png(tmp_path / "p.png", img)
    got = cli("vision", "tip", "--image", "p.png", "--pixel-size", "0.5e-6", "--format", "json", cwd=tmp_path)
    assert got.pop("files") == []
    assert got == vision.tip(img, pixel_size=0.5e-6)
    for kw, name in [(dict(pixel_size=float("nan")), "pixel_size"), (dict(pixel_size=-1.0), "pixel_size")]:
        with pytest.raises(cellinject.InputError, match=name):
            vision.tip(img, **kw)
    with pytest.raises(cellinject.InputError, match="image"):
        vision.tip(-1.0 * img.astype(float))
