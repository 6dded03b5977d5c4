"""A sweep of bad arguments over every function: each is a cellinject.InputError (a
ValueError) naming the argument, never a panic (pyo3 would raise PanicException, a
BaseException) nor a crash."""

import math

import numpy as np
import pytest

import cellinject
from cellinject import dic, fea, flexure, hysteresis, model, runs, twin, vision

# Random grey levels: texture along both axes (a ramp along x alone has none along y,
# and the tracker rightly refuses it).
IMG = np.random.default_rng(7).integers(0, 251, (64, 64), dtype=np.uint8)
GOOD = {
    "points": (dic.points, dict(reference=IMG, current=IMG, at=[(32.0, 32.0)])),
    "field": (dic.field, dict(reference=IMG, current=IMG)),
    "track": (dic.track, dict(frames=[IMG, IMG], roi=(10, 10, 20, 20))),
    "synth": (dic.synth, dict(size=(32, 32))),
    "cells": (vision.cells, dict(image=IMG, pixel_size=0.5e-6)),
    "tip": (vision.tip, dict(image=IMG, pixel_size=0.5e-6)),
    "hinge": (flexure.hinge, dict(profile="circular", thickness=5e-4, width=5e-3, radius=2e-3)),
    "tension": (model.tension, dict(approach=1)),
    "fea": (fea.run, dict(approach=1, forces=(-100.0, -100.0))),
    "modes": (fea.modes, dict(count=2)),
    "fit": (hysteresis.fit, dict(voltage=[0.0, 50.0, 10.0, 40.0, 0.0], displacement=[0.0, 5e-6, 1e-6, 4e-6, 0.0], size=4)),
}

BAD_NUMBERS = [float("nan"), float("inf"), -float("inf"), -1.0, 0.0, 1e300]
BAD_SIZES = [-1, 0, -(2**40), 2**40]

SWEEP = [
    ("points", "subset", BAD_SIZES),
    ("points", "search", [-1, -(2**40)]),
    ("points", "prefilter", BAD_NUMBERS[:3] + [-1.0, 1e300]),
    ("points", "min_zncc", BAD_NUMBERS[:3] + [1e300]),
    ("points", "max_sigma", BAD_NUMBERS[:1] + [-1.0, 0.0]),
    ("points", "at", [[(math.nan, 1.0)], [(1e300, 1e300)], [], [(-5.0, -5.0)], "xy", [(1.0,)]]),
    ("points", "reference", [IMG[None], IMG.ravel(), IMG.astype(np.int64), IMG.astype(complex), np.zeros((0, 0), np.uint8), np.full((64, 64), np.nan), None, "img.png"]),
    ("points", "current", [IMG[:10], IMG.astype(bool)]),
    ("field", "step", BAD_SIZES),
    ("field", "subset", BAD_SIZES + [2]),
    ("track", "roi", [(-1, 0, 10, 10), (0, 0, 0, 0), (60, 60, 20, 20), (0, 0, 2**40, 1)]),
    ("track", "frames", [[], [IMG[None]], [IMG, IMG[:5]]]),
    ("synth", "size", [(0, 0), (-5, 32), (2**40, 32)]),
    ("synth", "noise", BAD_NUMBERS[:4]),
    ("synth", "shift", [(math.nan, 0.0), (0.0, math.inf)]),
    ("synth", "rotation", [math.nan]),
    ("cells", "pixel_size", BAD_NUMBERS[:5]),
    ("cells", "diameter", [(2e-5, 1e-5), (math.nan, 1e-5), (0.0, 1e-5), (-1.0, 1e-5)]),
    ("cells", "contrast", ["light", ""]),
    ("cells", "image", [IMG[None], IMG.astype(np.int64), np.zeros((0, 0), np.uint8), np.full((64, 64), np.nan), np.zeros((4, 4), np.uint8), None]),
    ("tip", "pixel_size", BAD_NUMBERS),
    ("tip", "image", [IMG[None], IMG.ravel(), IMG.astype(complex), np.zeros((0, 0), np.uint8), np.full((64, 64), np.nan), -1.0 * IMG, None, "img.png"]),
    ("hinge", "thickness", BAD_NUMBERS[:5]),
    ("hinge", "width", BAD_NUMBERS[:5]),
    ("hinge", "radius", BAD_NUMBERS[:5]),
    ("hinge", "youngs", BAD_NUMBERS[:5]),
    ("hinge", "poisson", [math.nan, 0.5, -1.5]),
    ("hinge", "yield_strength", BAD_NUMBERS[:5]),
    ("hinge", "angle", BAD_NUMBERS[:3]),
    ("tension", "approach", [0, 3, -1, 2**40]),
    ("fea", "forces", [(math.nan, -100.0), (100.0, -100.0), (-1e300, -100.0), (), (-1.0, -1.0, -1.0)]),
    ("fea", "level", [0, 4, -1]),
    ("modes", "count", [0, 17, -1]),
    ("fit", "voltage", [[math.nan] * 5, [0.0] * 5, [0.0, 1.0], np.zeros((5, 1))]),
    ("fit", "displacement", [[math.inf] * 5, [0.0] * 4]),
    ("fit", "size", [0, 1, 61, -3]),
    ("fit", "v_max", BAD_NUMBERS[:5] + [10.0]),
]


@pytest.mark.parametrize("fn,arg,values", SWEEP, ids=[f"{f}-{a}" for f, a, _ in SWEEP])
def test_bad_arguments_are_input_errors_naming_them(fn, arg, values):
    f, good = GOOD[fn]
    for v in values:
        kw = dict(good)
        kw[arg] = v
        try:
            f(**kw)
        except cellinject.InputError as e:
            assert isinstance(e, ValueError)
            msg = str(e)
            assert arg in msg, (fn, arg, v, msg)
        except cellinject.NotConverged:
            # A legal setting that gives nothing usable (a far point) is not a panic.
            pass
        else:
            pytest.fail(f"{fn}({arg}={v!r}) was accepted")


def test_wrong_types_are_type_errors_not_panics():
    for f, kw in [(flexure.hinge, dict(profile=1, thickness=1e-3, width=1e-3)), (model.tension, dict(approach="one")), (runs.list, dict(db=3.5))]:
        with pytest.raises(TypeError):
            f(**kw)
    t = twin.Twin(seed=1)
    with pytest.raises(TypeError):
        t.set_voltages("a", 0.0, 0.0)
