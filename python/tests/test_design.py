"""cellinject.design: the CLI's figures, bad arguments, and the same front serially
and on a real Dask LocalCluster with two worker processes."""

import os

import pytest

import cellinject
from cellinject import design

SPACE = """
[variables]
"geometry.b2" = [0.12, 0.26]
"structure.throat_J3" = [1.6e-3, 2.6e-3]
[objectives]
maximise = ["range_min_m", "first_mode_hz"]
[constraints]
min_safety_factor = 1.1
"""


def test_evaluate_equals_the_cli(cli, tmp_path):
    assert design.evaluate() == cli("design", "evaluate", "--format", "json")
    f = design.evaluate({"geometry.b2": 0.2, "structure.throat_J3": 2.2e-3}, approach=1)
    config = tmp_path / "d.toml"
    text = open(os.path.join(os.path.dirname(__file__), "..", "..", "configs", "prototype.toml")).read()
    text = text.replace("b2 = 0.180", "b2 = 0.2").replace("throat_J3 = 2.0e-3", "throat_J3 = 2.2e-3")
    config.write_text(text)
    assert f == cli("--config", config, "design", "evaluate", "--approach", "1", "--format", "json")
    assert f["approach"] == 1 and f["feasible"] in (True, False)


@pytest.mark.parametrize(
    "kwargs, says",
    [
        (dict(variables={"geometry.b9": 0.2}), "geometry.b9"),
        (dict(variables={"geometry.b2": float("nan")}), "geometry.b2"),
        (dict(variables={"geometry.b2": -0.2}), "geometry.b2"),
        (dict(variables={"geometry.b2": "long"}), "geometry.b2"),
        (dict(fidelity="cad"), "fidelity"),
        (dict(level=3), "level"),
        (dict(approach=3), "approach"),
        (dict(config="/nonexistent.toml"), "config"),
    ],
)
def test_bad_arguments_raise_input_error_naming_them(kwargs, says):
    with pytest.raises(cellinject.InputError, match=says):
        design.evaluate(**kwargs)


def test_bad_spaces_are_refused_naming_the_key():
    with pytest.raises(cellinject.InputError, match="geometry.b9"):
        design.Study('[variables]\n"geometry.b9" = [0.1, 0.2]\n[objectives]\nmaximise = ["range_min_m"]\n')
    with pytest.raises(cellinject.InputError, match="constraints.speed"):
        design.optimise(SPACE + "speed = 3\n", population=4, generations=1)
    with pytest.raises(cellinject.InputError, match="population"):
        design.optimise(SPACE, population=2)


def test_the_same_seed_gives_the_same_front_serially_and_on_a_dask_cluster():
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        if os.environ.get("CELLINJECT_PYTEST") == "required":
            pytest.fail("dask.distributed is not installed (pip install 'dask[distributed]')")
        pytest.skip("dask.distributed is not installed")
    serial = design.optimise(SPACE, population=12, generations=6, seed=3)
    assert len(serial["front"]) >= 2
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            assert len(client.scheduler_info()["workers"]) == 2
            on_dask = design.optimise(SPACE, population=12, generations=6, seed=3, map=client.map)
            # The points really ran in the worker processes.
            pids = set(client.run(os.getpid).values())
            assert os.getpid() not in pids and len(pids) == 2
    assert on_dask == serial
    assert serial["evaluations"] == 12 * 6
    for e in serial["front"]:
        assert e["figures"]["min_safety_factor"] >= 1.1
