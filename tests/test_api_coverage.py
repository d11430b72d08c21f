"""The fast tier touches every public function: each function in the public modules' ``__all__``
appears in a test that is not marked ``slow`` (its body or decorators, the module-level
helpers and fixtures of its file, or a ``_helpers`` function it calls).  A static check on
the test sources: no JAX work, and it fails when a change leaves a public name to the
slow tier alone."""

from __future__ import annotations

import ast
import pathlib

import jaxsim
from jaxsim import anim, cloth, curves, ik, optim, viz

HERE = pathlib.Path(__file__).parent
MODULES = {"jaxsim": jaxsim, "ik": ik, "cloth": cloth, "anim": anim, "curves": curves, "viz": viz,
           "cloth.reference": cloth.reference}


def _public():
    names = {f"{m}.{n}" for m, mod in MODULES.items() for n in mod.__all__ if _is_function(getattr(mod, n))}
    names |= {f"optim.{n}" for n in ("adam", "levenberg_marquardt") if _is_function(getattr(optim, n))}
    return names


def _is_function(obj) -> bool:
    """A public function (jitted or not); not a class, a module or a constant."""
    return callable(obj) and not isinstance(obj, type)


def _is_slow(node) -> bool:
    return any("slow" in ast.unparse(d) for d in node.decorator_list)


def _words(nodes) -> set[str]:
    out = set()
    for node in nodes:
        for sub in ast.walk(node):
            if isinstance(sub, ast.Name):
                out.add(sub.id)
            elif isinstance(sub, ast.Attribute):
                out.add(sub.attr)
            elif isinstance(sub, ast.Constant) and isinstance(sub.value, str) and sub.value.isidentifier():
                out.add(sub.value)  # getattr(ik, "solve"), parametrised names
    return out


def _fast_tier_words() -> set[str]:
    helpers = {n.name: n for n in ast.parse((HERE / "_helpers.py").read_text()).body
               if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    words: set[str] = set()
    for path in sorted(HERE.glob("test_*.py")):
        if path.name == pathlib.Path(__file__).name:
            continue
        tree = ast.parse(path.read_text())
        fast, rest = [], []
        for node in tree.body:
            if isinstance(node, ast.FunctionDef) and node.name.startswith("test_"):
                (rest if _is_slow(node) else fast).append(node)
            elif isinstance(node, ast.ClassDef) and node.name.startswith("Test"):
                (rest if _is_slow(node) else fast).extend(
                    n for n in node.body if not (isinstance(n, ast.FunctionDef) and _is_slow(n)))
            else:
                rest.append(node)
        if not fast:
            continue
        module_level = [n for n in tree.body if not (isinstance(n, ast.FunctionDef) and n.name.startswith("test_"))
                        and not isinstance(n, (ast.Import, ast.ImportFrom))]
        used = _words(fast) | _words(module_level)
        words |= used | _words([helpers[n] for n in used & set(helpers)])
    return words


def test_every_public_function_is_touched_by_the_fast_tier():
    words = _fast_tier_words()
    missing = sorted(n for n in _public() if n.rsplit(".", 1)[1] not in words)
    assert not missing, f"public names no fast-tier test touches: {missing}"


def test_the_check_sees_a_missing_name():
    """The check can fail: a made-up public name is reported missing."""
    assert "no_such_public_function_anywhere" not in _fast_tier_words()
