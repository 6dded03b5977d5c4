"""cellinject.model, .flexure and .fea: the CLI's JSON for the same inputs, dtypes,
errors."""

import math
from pathlib import Path

import numpy as np
import pytest

import cellinject
from cellinject import fea, flexure, model
from conftest import ROOT


def test_tension_and_model_equal_the_cli(cli):
    for a in (1, 2):
        assert model.tension(a) == cli("tension", "--approach", a, "--format", "json")
    assert model.model() == cli("model", "--format", "json")


def test_model_takes_numpy_integers_and_paths_and_refuses_bad_approaches(cli):
    config = ROOT / "configs" / "prototype.toml"
    r = model.tension(np.int64(2), config=config)
    assert r == model.tension(2, config=str(config))
    assert r == cli("--config", config, "tension", "--approach", 2, "--format", "json")
    assert all(type(x) is float for x in r["F10"])
    for bad in (0, 3, -1):
        with pytest.raises(cellinject.InputError, match=f"approach must be 1 or 2, got {bad}"):
            model.tension(bad)
    with pytest.raises(cellinject.InputError, match="config: cannot read"):
        model.model(config="/nonexistent/description.toml")
    with pytest.raises(TypeError):
        model.tension(1.5)


def test_reproduce_agrees_with_the_paper():
    r = model.reproduce()
    assert r["is_prototype"] and r["computed"] >= 20
    assert r["agree"] == r["computed"]


HINGES = [
    dict(profile="circular", thickness=0.5e-3, width=5e-3, radius=2e-3),
    dict(profile="corner", thickness=0.4e-3, width=6e-3, radius=1e-3, length=4e-3, angle=0.01),
    dict(profile="elliptic", thickness=0.3e-3, width=5e-3, radius=1.5e-3, length=6e-3, method="beam"),
    dict(profile="leaf", thickness=0.2e-3, width=5e-3, length=3e-3, youngs=70e9, poisson=0.33),
    dict(profile="circular", thickness=0.5e-3, width=5e-3, radius=1e-3, method="pw-simple"),
]


def test_hinge_equals_the_cli(cli):
    flags = {"youngs": "--youngs", "poisson": "--poisson", "angle": "--angle"}
    for h in HINGES:
        args = ["hinge", "--format", "json"]
        for k, v in h.items():
            args += [flags.get(k, "--" + k), v]
        assert flexure.hinge(**h) == cli(*args), h


def test_hinge_dtypes_and_errors():
    base = flexure.hinge(**HINGES[0])
    assert flexure.hinge("circular", np.float64(0.5e-3), np.float64(5e-3), radius=np.float64(2e-3)) == base
    assert len(base["compliance"]) == 6 and all(type(x) is float for x in base["compliance"][0])
    assert base["k_bend"] > 0 and math.isfinite(base["max_rotation"])
    cases = [
        (dict(thickness=float("nan")), "thickness NaN"),
        (dict(thickness=-1e-3), "thickness -0.001"),
        (dict(width=0.0), "width 0"),
        (dict(radius=None), "`radius` is required for a circular hinge"),
        (dict(radius=float("inf")), "radius inf"),
        (dict(profile="oval"), "profile must be circular, corner, elliptic or leaf"),
        (dict(method="magic"), "method must be beam"),
        (dict(youngs=-1.0), "youngs"),
        (dict(angle=float("nan")), "angle"),
    ]
    for kw, msg in cases:
        args = dict(HINGES[0])
        args.update(kw)
        with pytest.raises(cellinject.InputError, match=msg):
            flexure.hinge(**args)


def test_fea_equals_the_cli(cli):
    # The first call fills the joint cache (a "miss"), so both sides below read it.
    fea.run(1, (-100.0, -100.0))
    for a, f in [(1, (-100.0, -100.0)), (2, (-120.0, -95.0))]:
        py = fea.run(a, np.array(f, dtype=np.float32))
        c = cli("fea", "--approach", a, "--forces", f"{f[0]},{f[1]}", "--format", "json")
        assert py == c
        assert py["joint_convergence"]["J3"]["cache"] == "hit"
    assert fea.tables() == cli("fea", "tables", "--format", "json")
    assert fea.modes(approach=1, count=3) == cli("fea", "modes", "--approach", 1, "--count", 3, "--format", "json")


def test_fea_errors():
    cases = [
        (dict(forces=(100.0, -100.0)), "forces: F11 = 100 N would pull"),
        (dict(forces=(float("nan"), -100.0)), r"forces\[0\] = NaN"),
        (dict(forces=(-100.0,)), "forces takes"),
        (dict(forces=(-1e6, -100.0)), "push capacity"),
        (dict(level=0), "level must be 1, 2 or 3"),
        (dict(preload="push"), "preload must be"),
        (dict(approach=7), "approach must be 1 or 2"),
    ]
    for kw, msg in cases:
        args = dict(approach=1, forces=(-100.0, -100.0))
        args.update(kw)
        with pytest.raises(cellinject.InputError, match=msg):
            fea.run(**args)
    with pytest.raises(cellinject.InputError, match="count must lie in"):
        fea.modes(count=0)
