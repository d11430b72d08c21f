"""The performance guide's tables are generated from the committed benchmark JSON."""

import importlib.util
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _tables():
    spec = importlib.util.spec_from_file_location("_tables", ROOT / "benchmarks" / "_tables.py")
    mod = importlib.util.module_from_spec(spec)
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    spec.loader.exec_module(mod)
    return mod


def test_generated_tables_match_the_json(tmp_path):
    T = _tables()
    text = (ROOT / "docs" / "performance.md").read_text(encoding="utf-8")
    names = sum((T.blocks(p) for p in T.GUIDES), [])
    assert sorted(names) == sorted(T.TABLES), names  # every table is a generated block, once
    assert T.stale() == [], "run: python benchmarks/_tables.py --write"
    # the check can fail: an edited number is caught
    edited = tmp_path / "performance.md"
    edited.write_text(text.replace("| fabrik | 10 sweeps | solve unroll=True early_exit=False | ",
                                   "| fabrik | 10 sweeps | solve unroll=True early_exit=False | 9", 1), encoding="utf-8")
    assert T.stale(str(edited)) == ["ik"]
