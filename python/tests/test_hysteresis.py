"""cellinject.hysteresis: a model fitted to the output of an independent play-operator
model written here, applied and inverted; the CLI's file format and numbers."""

import json

import numpy as np
import pytest

import cellinject
from cellinject import hysteresis


def plays(v, r=(0.0, 8.0, 16.0, 28.0, 40.0), w=(6e-8, 2e-8, 1.5e-8, 1e-8, 0.5e-8)):
    """A Prandtl-Ishlinskii actuator in numpy: play operators of thresholds r (V) and
    weights w (m/V), all relaxed at 0 V."""
    out = np.zeros(len(v))
    for ri, wi in zip(r, w):
        y = 0.0
        for k, x in enumerate(v):
            y = min(max(y, x - ri), x + ri)
            out[k] += wi * y
    return out


def excitation():
    """Reversals of every size inside 0-100 V, 0.25 V steps."""
    turns = [0, 100, 10, 90, 25, 75, 40, 60, 45, 100, 0, 70, 30, 50, 0]
    v = [0.0]
    for a, b in zip(turns, turns[1:]):
        n = int(abs(b - a) / 0.25)
        v.extend(np.linspace(a, b, n + 1)[1:])
    return np.array(v)


@pytest.fixture(scope="module")
def data():
    v = excitation()
    return v, plays(v)


def test_a_fitted_model_reproduces_and_inverts_an_independent_actuator(data):
    v, d = data
    m = hysteresis.fit(v, d, model="pi", size=12)
    rep = m.report
    assert rep["model"]["model"] == "pi" and rep["samples"] == len(v)
    span = d.max() - d.min()
    assert rep["rms"] < 0.01 * span and rep["rms_relative"] < 0.01
    y = m.apply(v)
    assert y.dtype == np.float64 and y.shape == v.shape
    assert np.sqrt(np.mean((y - d) ** 2)) == pytest.approx(rep["rms"], rel=1e-6)
    # Inversion: the voltages that make the *true* actuator follow a new trajectory.
    target = 3e-6 * (1 - np.cos(np.linspace(0, 3 * np.pi, 300))) / 2 + 1.5e-6
    inv = m.invert(target)
    assert inv["samples"] == 300 and inv["residual"] < 1e-9
    np.testing.assert_allclose(inv["predicted"], m.apply(inv["voltage"]), atol=1e-15)
    achieved = plays(inv["voltage"])
    assert np.abs(achieved - target).max() < 0.03 * target.max()
    # The Preisach model too, on float32 and integer inputs alike.
    p = hysteresis.fit(v.astype(np.float32), d, size=10)
    assert p.kind == "preisach" and p.report["rms_relative"] < 0.02
    assert hysteresis.fit(np.round(v).astype(np.int32), d, size=10).report["samples"] > 0


def test_model_files_and_numbers_equal_the_cli(data, cli, tmp_path):
    v, d = data
    t = np.arange(len(v)) * 1e-3
    with open(tmp_path / "ident.csv", "w") as f:
        f.write("time_s,voltage_v,displacement_m\n")
        for row in zip(t, v, d):
            f.write("%r,%r,%r\n" % tuple(float(x) for x in row))
    c = cli("hysteresis", "fit", "--data", "ident.csv", "--model", "pi-asym", "--size", 8, "--out", "m.json", "--format", "json", cwd=tmp_path)
    m = hysteresis.fit(v, d, model="pi-asym", size=8)
    for k in ["model", "rms", "max", "rms_relative", "samples", "data"]:
        assert m.report[k] == c[k], k
    assert m.to_json() == (tmp_path / "m.json").read_text()
    back = hysteresis.Model.from_json((tmp_path / "m.json").read_text())
    assert back.report is None
    # The file's decimal weights read back within an ulp (serde_json's parser).
    np.testing.assert_allclose(back.apply(v), m.apply(v), rtol=1e-14, atol=1e-22)
    target = np.linspace(0.5e-6, 5e-6, 50)
    with open(tmp_path / "want.csv", "w") as f:
        f.write("time_s,displacement_m\n")
        for k, x in enumerate(target):
            f.write("%r,%r\n" % (k * 1e-3, float(x)))
    ci = cli("hysteresis", "invert", "--model", "m.json", "--trajectory", "want.csv", "--out", "cmd.csv", "--format", "json", cwd=tmp_path)
    pi = back.invert(target)
    for k in ["samples", "voltage_range", "residual"]:
        assert pi[k] == ci[k], k
    cmd = np.loadtxt(tmp_path / "cmd.csv", delimiter=",", skiprows=1)[:, 1]
    np.testing.assert_allclose(pi["voltage"], cmd, atol=5e-7)


def test_bad_data_is_an_input_error_naming_it(data):
    v, d = data
    bad = v.copy()
    bad[3] = np.nan
    cases = [
        (dict(voltage=bad), r"voltage\[3\] = NaN"),
        (dict(displacement=d[:-1]), "differ in length"),
        (dict(voltage=v.reshape(-1, 1)), "voltage must be a 1-D array"),
        (dict(voltage=np.linspace(0, 100, len(v))), "voltage: "),
        (dict(model="bouc-wen"), "model must be preisach, pi or pi-asym"),
        (dict(size=1), "size must lie in 2..=60"),
        (dict(v_max=-5.0), "v_max must be a positive number"),
        (dict(v_max=50.0), "voltage: sample .* outside the model's range"),
        (dict(voltage=["a"] * len(v)), "voltage must be"),
    ]
    for kw, msg in cases:
        args = dict(voltage=v, displacement=d, size=6)
        args.update(kw)
        with pytest.raises(cellinject.InputError, match=msg):
            hysteresis.fit(**args)
    m = hysteresis.fit(v, d, model="pi", size=6)
    with pytest.raises(cellinject.InputError, match="displacements"):
        m.invert([1.0])  # a metre: out of reach
    with pytest.raises(cellinject.InputError, match=r"voltages\[0\] = inf"):
        m.apply([np.inf])
    with pytest.raises(cellinject.InputError, match="not a model"):
        hysteresis.Model.from_json(json.dumps({"model": "spring"}))
