"""Every public function's docstring has an example, and the examples run (doctest)."""

import doctest

import numpy as np

import cellinject
from cellinject import design, dic, fea, flexure, hysteresis, model, rig, runs, twin, vision

MODULES = [design, dic, fea, flexure, hysteresis, model, rig, runs, twin, vision]


def objects():
    for mod in MODULES:
        for name in mod.__all__:
            obj = getattr(mod, name)
            yield f"{mod.__name__}.{name}", obj
            if isinstance(obj, type):
                for attr in ["apply", "invert"]:
                    if hasattr(obj, attr):
                        yield f"{mod.__name__}.{name}.{attr}", getattr(obj, attr)


def test_every_public_function_has_a_docstring_with_units_or_an_example():
    for name, obj in objects():
        doc = obj.__doc__ or ""
        assert len(doc) > 80, name
        if not name.endswith("dataframe") and not isinstance(obj, type):
            assert "Example" in doc or ">>>" in doc, name


def test_the_docstring_examples_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    v = np.concatenate([np.linspace(0, 100, 50), np.linspace(100, 20, 40), np.linspace(20, 80, 30), np.linspace(80, 0, 40)])
    m = hysteresis.fit(v, 1e-7 * v + 1e-8 * np.sqrt(v), size=8)
    globs = {"np": np, "cellinject": cellinject, "m": m}
    finder = doctest.DocTestFinder(recurse=False)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    ran = 0
    for name, obj in objects():
        for test in finder.find(obj, name, globs=dict(globs)):
            runner.run(test)
            ran += len(test.examples)
    assert ran > 20
    assert runner.failures == 0, runner.summarize()
