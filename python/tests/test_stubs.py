"""The type stubs (python/ukdyn/__init__.pyi) against the module: every public class, function,
method, property and attribute of ukdyn is in the stubs and every name in the stubs exists, and
each function's parameter names match pybind11's signature, so the stubs cannot drift."""
import ast
import pathlib
import re

import pytest

import ukdyn

STUB = pathlib.Path(ukdyn.__file__).with_name("__init__.pyi")
# stub-only helpers (type aliases, protocols), not module attributes
STUB_ONLY = {"Expr", "ArrayLike", "FloatArray", "Callback", "ControlLawObject", "ControlLaw"}


def stub_tree():
    return ast.parse(STUB.read_text())


def stub_members(cls):
    """name -> list of ast.FunctionDef (one per @overload) or None for an annotated attribute."""
    out = {}
    for node in cls.body:
        if isinstance(node, ast.FunctionDef):
            out.setdefault(node.name, []).append(node)
        elif isinstance(node, ast.AnnAssign):
            out[node.target.id] = None
    return out


def stub_params(fn):
    a = fn.args
    names = [p.arg for p in a.posonlyargs + a.args + a.kwonlyargs]
    return [n for n in names if n != "self"]


def module_params(doc_line):
    """Parameter names of one pybind11 signature line 'name(self: T, a: T = ..., *, b: T) -> R'."""
    inner = doc_line[doc_line.index("(") + 1: doc_line.rindex(")")]
    depth, cur, parts = 0, "", []
    for ch in inner:
        depth += ch in "([{"
        depth -= ch in ")]}"
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    parts.append(cur)
    names = [p.split(":")[0].split("=")[0].strip() for p in parts if p.strip()]
    return [n for n in names if n not in ("self", "*", "")]


def signatures(obj, name):
    doc = getattr(obj, "__doc__", "") or ""
    return [line for line in doc.splitlines()
            if re.match(r"^\s*(\d+\. )?%s\(" % name, line) and "*args, **kwargs" not in line]


def public(names):
    return {n for n in names if not n.startswith("_")}


def test_every_module_name_is_in_the_stubs_and_back():
    tree = stub_tree()
    top = {n.name for n in tree.body if isinstance(n, (ast.ClassDef, ast.FunctionDef))}
    top |= {n.target.id for n in tree.body if isinstance(n, ast.AnnAssign)}
    top |= {t.id for n in tree.body if isinstance(n, ast.Assign) for t in n.targets}
    assert public(top) - STUB_ONLY == set(ukdyn.__all__) - {"__version__"}


@pytest.mark.parametrize("cls", [n for n in ast.parse(STUB.read_text()).body
                                 if isinstance(n, ast.ClassDef)], ids=lambda c: c.name)
def test_every_class_member_matches(cls):
    if cls.name in STUB_ONLY:
        return
    real = getattr(ukdyn, cls.name)
    members = stub_members(cls)
    if issubclass(real, Exception):
        return
    have = public(dir(real))
    assert public(members) == have, (cls.name, sorted(public(members) ^ have))
    for name, fns in members.items():
        if not fns or name.startswith("_"):
            continue
        attr = getattr(real, name)
        if isinstance(attr, property):
            continue
        sigs = signatures(attr, name)
        assert len(sigs) == len(fns), (cls.name, name, sigs)
        for fn, sig in zip(fns, sigs):
            assert stub_params(fn) == module_params(sig), (cls.name, name, sig)


def test_module_functions_match():
    tree = stub_tree()
    for fn in (n for n in tree.body if isinstance(n, ast.FunctionDef)):
        real = getattr(ukdyn, fn.name)
        sigs = signatures(real, fn.name)
        if not sigs:  # a Python function (load_scenario): compare with inspect
            import inspect
            assert stub_params(fn) == list(inspect.signature(real).parameters), fn.name
            continue
        assert stub_params(fn) == module_params(sigs[0]), (fn.name, sigs[0])
