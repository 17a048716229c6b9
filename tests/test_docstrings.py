"""The numpydoc sections of the public API's docstrings (what ``help(stepterrain.X)`` shows) agree with the code:
every parameter of the signature is documented under Parameters and nothing else is, and every exception a Raises
section names exists. A parameter added to a signature without a line in its docstring shows here, not only to a
reader of ``help()`` who never learns of it.
"""

from __future__ import annotations

import builtins
import importlib
import inspect
import re

import pytest

import stepterrain as st
from stepterrain import errors

HEADING = re.compile(r"^(\w[\w ]*)\n-{3,}$", re.M)
# a parameter line: names (``a``, ``a, b``, ``*args``) and an optional `` : type``; prose lines inside the section
# (Terrain.coarsen's ```crs``, ... stay``) are not parameters
NAMES = re.compile(r"^(\*{0,2}[A-Za-z_]\w*(?:, \*{0,2}[A-Za-z_]\w*)*)(?: : .*)?$")
# a Raises entry may name its exception with its module (``stepterrain.errors.InvalidInputError``)
EXCEPTIONS = re.compile(r"^([A-Za-z_][\w.]*(?:, [A-Za-z_][\w.]*)*)$")


MODULES = ("camera", "closeup", "export", "globe", "mesh", "pyvista_accessor", "render", "texture", "texture_lod",
           "io", "terrain", "stepped", "batch")


def public_callables() -> list[tuple[str, object]]:
    """The exports of ``stepterrain`` (a callable module as its entry point) and of its modules (``__all__``), and
    the public methods of the exported classes (a class's own Parameters section documents its constructor)."""
    found, seen = [], set()
    exports = [(name, getattr(st, name)) for name in st.__all__]
    for module in MODULES:
        mod = importlib.import_module(f"stepterrain.{module}")
        exports += [(f"{module}.{name}", getattr(mod, name)) for name in mod.__all__]
    for name, obj in exports:
        if inspect.ismodule(obj):  # st.stepped, st.batch: modules callable as their function of the same name
            obj = getattr(obj, name.rsplit(".", 1)[-1])
        if not callable(obj) or id(obj) in seen:
            continue
        seen.add(id(obj))
        found.append((name, obj))
        if inspect.isclass(obj):
            for attr, value in vars(obj).items():
                if not attr.startswith("_") and inspect.isfunction(getattr(value, "__func__", value)):
                    found.append((f"{name}.{attr}", getattr(obj, attr)))
    return found


def sections(doc: str) -> dict[str, list[str]]:
    """A numpydoc docstring's sections by heading, each as its lines."""
    doc = inspect.cleandoc(doc)
    heads = list(HEADING.finditer(doc))
    return {m.group(1): doc[m.end():heads[k + 1].start() if k + 1 < len(heads) else len(doc)].splitlines()
            for k, m in enumerate(heads)}


def entry_names(lines: list[str], pattern: re.Pattern[str] = NAMES) -> list[str]:
    """The names of a Parameters or Raises section's entries (its unindented lines)."""
    names = []
    for line in lines:
        match = pattern.match(line) if line and not line[0].isspace() else None
        if match:
            names += [n.lstrip("*") for n in match.group(1).split(", ")]
    return names


def signature_names(obj: object) -> list[str]:
    return [p.name for p in inspect.signature(obj).parameters.values()
            if p.name not in ("self", "cls") and not p.name.startswith("_")
            and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]


CASES = [(name, obj) for name, obj in public_callables() if "Parameters" in sections(obj.__doc__ or "")]


def test_the_check_sees_parameter_sections():
    names = {name for name, _ in CASES}
    assert {"stepped", "batch", "heightfield_mesh", "hillshade", "CloseUp", "render_closeups"} <= names, names
    assert len(CASES) >= 20, len(CASES)
    assert entry_names(["a, b : float", "    text", "``crs`` and ``source`` stay.", "*args"]) == ["a", "b", "args"]
    assert entry_names(["stepterrain.errors.InvalidInputError, OSError", "    text"], EXCEPTIONS) == [
        "stepterrain.errors.InvalidInputError", "OSError"]
    assert documented_parameters("f\n\nParameters\n----------\na : int\n\nOther Parameters\n----------------\nb\n"
                                 ) == ["a", "b"]
    assert is_exception("stepterrain.errors.InvalidInputError") and is_exception("OSError")
    assert not is_exception("InvalidInputErorr") and not is_exception("stepterrain.errors.NoSuchError")


def documented_parameters(doc: str) -> list[str]:
    """The entries of Parameters and (numpydoc's rarely used keyword part) Other Parameters."""
    found = sections(doc)
    return entry_names(found["Parameters"]) + entry_names(found.get("Other Parameters", []))


def is_exception(name: str) -> bool:
    """Whether ``name`` (bare, as stepterrain.errors or builtins hold it, or dotted with its module) is a class."""
    module, _, attr = name.rpartition(".")
    if module:
        try:
            found = getattr(importlib.import_module(module), attr, None)
        except ImportError:
            found = None
    else:
        found = getattr(errors, name, getattr(builtins, name, None))
    return isinstance(found, type)


@pytest.mark.parametrize(("name", "obj"), CASES, ids=[name for name, _ in CASES])
def test_documented_parameters_are_the_signatures(name, obj):
    documented = documented_parameters(obj.__doc__)
    real = signature_names(obj)
    assert len(documented) == len(set(documented)), f"{name}: a parameter documented twice: {documented}"
    missing = [p for p in real if p not in documented]
    extra = [p for p in documented if p not in real and p not in ("args", "kwargs")]
    assert not missing and not extra, f"{name}: undocumented {missing}, documented but not in the signature {extra}"


RAISING = [(name, obj) for name, obj in public_callables() if "Raises" in sections(obj.__doc__ or "")]


@pytest.mark.parametrize(("name", "obj"), RAISING, ids=[name for name, _ in RAISING])
def test_raised_exceptions_exist(name, obj):
    named = entry_names(sections(obj.__doc__)["Raises"], EXCEPTIONS)
    assert named, name
    unknown = [e for e in named if not is_exception(e)]
    assert not unknown, f"{name}: Raises names no such exception: {unknown}"


REFERENCE = re.compile(r":(?:func|class|meth|data|mod|attr|exc):`~?([\w.]+)`")


def reference_resolves(ref: str, obj: object) -> bool:
    """Whether ``ref`` names something from ``obj``'s module, its class (a method's), or the package."""
    module = importlib.import_module(obj.__module__)
    owner = getattr(module, obj.__qualname__.split(".")[0], None) if "." in obj.__qualname__ else None
    for base in (module, obj if inspect.isclass(obj) else None, owner, st):
        found = base
        for part in ref.removeprefix("stepterrain.").split(".") if base is not None else ():
            found = getattr(found, part, None)
        if base is not None and found is not None:
            return True
    try:
        importlib.import_module(ref)
    except ImportError:
        return False
    return True


def test_cross_references_name_what_exists():
    """The ``:func:`...``` / ``:class:`...``` / ``:data:`...``` references of the public docstrings name functions,
    classes and constants that exist (a renamed one shows here)."""
    assert not reference_resolves("no_such_function", st.heightfield_mesh)
    assert reference_resolves("Terrain.mesh", st.heightfield_mesh)
    assert reference_resolves("stepterrain.render", st.batch.batch)
    unknown, checked = [], 0
    for name, obj in public_callables():
        for ref in REFERENCE.findall(obj.__doc__ or ""):
            checked += 1
            if not reference_resolves(ref, obj):
                unknown.append((name, ref))
    assert not unknown, unknown
    assert checked >= 200, checked
