"""docs/python.md: its worked example is run, every ```python block in order, in one
namespace, in a scratch directory."""

import os
import re

from conftest import ROOT


def test_the_worked_example_of_docs_python_md_runs(tmp_path, capsys):
    text = (ROOT / "docs" / "python.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 5
    here = os.getcwd()
    os.chdir(tmp_path)
    try:
        ns = {}
        for k, code in enumerate(blocks):
            exec(compile(code, f"docs/python.md block {k + 1}", "exec"), ns)
    finally:
        os.chdir(here)
    assert (tmp_path / "a3.json").exists()
    out = capsys.readouterr().out
    assert "reference must be a 2-D array" in out
