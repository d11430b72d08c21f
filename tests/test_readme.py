"""Every Python block of the README runs verbatim."""

import os
import re

import pytest

README = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "README.md")


def python_blocks():
    with open(README, encoding="utf-8") as f:
        text = f.read()
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_readme_has_python_blocks():
    assert len(python_blocks()) >= 3


@pytest.mark.slow
@pytest.mark.parametrize("k", range(len(python_blocks())))
def test_readme_block_runs(k, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a block may write files (the BVH one does)
    exec(compile(python_blocks()[k], f"README.md block {k}", "exec"), {"__name__": f"readme_block_{k}"})
