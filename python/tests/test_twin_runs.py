"""cellinject.twin and cellinject.runs: the twin driven through its envelope, a run on
it equal to the CLI's, the run database read back as the CLI reads it."""

import json

import numpy as np
import pytest

import cellinject
from cellinject import rig, runs, twin


@pytest.fixture(scope="module")
def t():
    return twin.Twin(seed=4)


def test_the_twin_is_driven_sensed_and_seen(t):
    t0 = t.time
    assert t.set_voltages(0.0, 0.0, 0.0) == [0.0, 0.0, 0.0]
    t.advance(0.1)
    assert t.time == pytest.approx(t0 + 0.1, abs=1e-9)
    rest = np.array(t.sensors())
    applied = t.set_voltages(np.float32(40.0), 40.0, 10.0)
    assert applied[2] == 10.0 and 0 < applied[0] <= 40.0
    t.advance(0.3)
    moved = np.array(t.sensors()) - rest
    # Some 0.1 µm per volt for these stacks: tens of volts move them micrometres.
    assert (moved > 0.5e-6).all() and (moved < 20e-6).all(), moved
    for cam in ("top", "side"):
        f = t.grab(cam)
        img = f["image"]
        assert img.ndim == 2 and img.dtype == np.uint16 and img.max() > 0
        assert 0 < f["pixel_size"] < 1e-5 and f["timestamp"] <= t.time
    tip = t.tip()
    assert set(tip) == {"x", "z", "depth"}


def test_twin_frames_feed_the_dic(t):
    """A tilt of A1 moves the marker in the top camera: DIC on two frames as uint16."""
    t.set_voltages(20.0, 20.0, 0.0)
    t.advance(0.5)
    a = t.grab("top")["image"]
    h, w = a.shape
    r = cellinject.dic.points(a, a, [(w / 2, h / 2)])
    assert abs(r["u"][0]) < 1e-6 and r["converged"][0]


def test_bad_commands_are_input_errors(t):
    for args, msg in [((np.nan, 0.0, 0.0), "a1 must be a finite"), ((0.0, 0.0, np.inf), "a3 must be a finite"), ((0.0, 0.0, 1e6), "a3")]:
        with pytest.raises(cellinject.InputError, match=msg):
            t.set_voltages(*args)
    # Past a stack's travel: refused like `sim frame --volts 200,0,0`, nothing moved.
    t.set_voltages(10.0, 10.0, 0.0)
    for args, msg in [((200.0, 0.0, 0.0), "a1"), ((0.0, -50.0, 0.0), "a2")]:
        with pytest.raises(cellinject.InputError, match=msg):
            t.set_voltages(*args)
        assert t.voltages() == [10.0, 10.0, 0.0]
    with pytest.raises(cellinject.InputError, match="seconds must be a non-negative"):
        t.advance(-1.0)
    with pytest.raises(cellinject.InputError, match="camera must be top or side"):
        t.grab("bottom")
    with pytest.raises(cellinject.InputError, match="plate `/nonexistent.toml`: cannot read"):
        t.load_plate("/nonexistent.toml")
    with pytest.raises(cellinject.InputError, match="approach must be 1 or 2"):
        twin.Twin(approach=5)


@pytest.fixture(scope="module")
def small_plate(cli, tmp_path_factory):
    d = tmp_path_factory.mktemp("run")
    cli("plate", "generate", "--rows", 1, "--cols", 2, "--origin=-75e-6,-40e-6", "--seed", 3, "--out", "p.toml", "--format", "json", cwd=d)
    return d


def test_a_run_on_the_twin_equals_the_clis_and_reads_back(cli, small_plate):
    d = small_plate
    s = twin.run(plate=d / "p.toml", seed=2, db=d / "py.sqlite")
    c = cli("run", "--plate", "p.toml", "--seed", 2, "--db", "cli.sqlite", "--format", "json", cwd=d)
    assert s["status"] == "finished" and s["injected"] >= 1
    assert c.pop("files") == []  # the CLI's JSON lists the files it wrote
    assert s == c
    # The records, read back as `runs show` reads them.
    shown = runs.show(d / "py.sqlite")
    c_shown = cli("runs", "show", "--db", "py.sqlite", cwd=d)
    assert c_shown.pop("files") == []
    assert shown == c_shown
    assert shown["attempts"] == s["attempts"] == runs.attempts(str(d / "py.sqlite"), run=np.int64(1))
    listed = runs.list(d / "py.sqlite")
    assert [r["id"] for r in listed] == [1] and listed[0]["status"] == "finished"
    assert all(type(a["x_m"]) is float for a in shown["attempts"])
    try:
        import pandas  # noqa: F401
    except ImportError:
        return
    df = runs.dataframe(d / "py.sqlite")
    assert len(df) == len(s["attempts"]) and "tip_error_m" in df.columns


def test_runs_errors(tmp_path):
    with pytest.raises(cellinject.InputError, match="no such file"):
        runs.list(tmp_path / "missing.sqlite")
    (tmp_path / "junk.sqlite").write_text("not a database")
    with pytest.raises(cellinject.InputError, match="db "):
        runs.show(tmp_path / "junk.sqlite")
    with pytest.raises(cellinject.InputError, match="plate `.*`: cannot read"):
        twin.run(plate=tmp_path / "none.toml", db=tmp_path / "r.sqlite")
    assert not (tmp_path / "r.sqlite").exists()


def test_a_run_on_a_bench_opened_from_a_rig_file_equals_the_clis(cli, small_plate):
    """cellinject.rig: the same bench and the same run lifecycle as `cellinject run --rig`."""
    d = small_plate
    (d / "bench.toml").write_text('name = "the twin"\n[piezo]\ndriver = "twin"\n')
    b = rig.open(d / "bench.toml", seed=2)
    assert b.backend == "twin" and "twin" in repr(b)
    s = b.run(plate=d / "p.toml", db=d / "rig.sqlite")
    c = cli("run", "--rig", "bench.toml", "--plate", "p.toml", "--seed", 2, "--db", "cli-rig.sqlite", "--format", "json", cwd=d)
    assert c.pop("files") == []
    s["run"] = c["run"]
    assert s == c
    checked = rig.check(d / "bench.toml")
    c_checked = cli("rig", "check", "--rig", "bench.toml", "--format", "json", cwd=d)
    assert c_checked.pop("files") == []
    assert checked == c_checked
    assert checked["name"] == "the twin" and len(checked["devices"]) == 7
    assert all(x["answers"] for x in checked["devices"])


def test_a_bad_rig_file_names_the_file_and_the_key_and_opens_nothing(tmp_path):
    (tmp_path / "bad.toml").write_text('[piezo]\ndriver = "warp://x"\n')
    with pytest.raises(cellinject.InputError, match=r"bad\.toml.*piezo\.driver"):
        rig.open(tmp_path / "bad.toml")
    with pytest.raises(cellinject.InputError, match=r"bad\.toml.*piezo\.driver"):
        rig.check(tmp_path / "bad.toml")
    with pytest.raises(cellinject.InputError, match="cannot read"):
        rig.open(tmp_path / "missing.toml")
    bench = "".join(f'[{k}]\ndriver = "bench://127.0.0.1:2"\n' for k in ["camera.top", "camera.side", "stage.macro", "stage.feeder", "injector", "optics"])
    (tmp_path / "gcs.toml").write_text('[piezo]\ndriver = "gcs://127.0.0.1:1"\n' + bench)
    with pytest.raises(cellinject.InputError, match="seed seeds the twin"):
        rig.open(tmp_path / "gcs.toml", seed=3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml", "gcs.toml"]
