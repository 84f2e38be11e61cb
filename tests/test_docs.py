"""Every public callable is documented: a numpy-style Parameters section when it takes
parameters, a Returns (or Yields) section when it returns something, and a runnable example
(``>>>``, run by the doctest collection of the suite).

The walk covers the ``__all__`` of each public module and the public methods of each public
class. A method is checked where it is defined: one inherited unchanged (from ``LieGroup``, for
example) is documented once, on the base class, and an override without a docstring inherits
the base class's text (``inspect.getdoc``)."""

from __future__ import annotations

import ast
import importlib
import inspect
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _reference_modules() -> list[str]:
    """The modules rendered by a ``::: module`` directive on a docs/api page."""
    names = []
    for page in sorted((ROOT / "docs" / "api").glob("*.md")):
        for line in page.read_text().splitlines():
            if line.startswith(":::"):
                name = line[3:].strip()
                try:
                    importlib.import_module(name)
                except ImportError:  # a class (``::: microlie.SO3``), walked through microlie
                    continue
                names.append(name)
    return names


# the public packages, and every module the API reference renders
PUBLIC_MODULES = list(dict.fromkeys(
    ["microlie", "microlie.traj", "microlie.optim", "microlie.imu", "microlie.uncertainty",
     "microlie.calibration", *_reference_modules()]))


def _sections(doc: str) -> set[str]:
    """Names of the numpy-style sections (a title line followed by a dashes line)."""
    lines = doc.splitlines()
    return {lines[i].strip() for i in range(len(lines) - 1)
            if lines[i].strip() and set(lines[i + 1].strip()) == {"-"}
            and len(lines[i + 1].strip()) >= len(lines[i].strip())}


def _takes_parameters(fn, *, bound: bool) -> bool:
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return False
    params = list(sig.parameters.values())
    if bound and params and params[0].name in ("self", "cls"):
        params = params[1:]
    return bool(params)


def _returns_something(fn) -> bool:
    fn = inspect.unwrap(fn)
    ann = getattr(fn, "__annotations__", {}).get("return", inspect.Signature.empty)
    if ann is not inspect.Signature.empty:
        return ann not in (None, "None", type(None))
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    except (OSError, TypeError, SyntaxError):
        return True
    return any(isinstance(n, ast.Return | ast.Yield | ast.YieldFrom) and
               getattr(n, "value", None) is not None for n in ast.walk(tree))


def _is_exception(cls) -> bool:
    return isinstance(cls, type) and issubclass(cls, BaseException | Warning)


def _own_init(cls):
    """The ``__init__`` whose parameters the class docstring documents (None if inherited
    from object or from an exception base)."""
    for klass in cls.__mro__:
        if "__init__" in vars(klass):
            if klass is object or klass.__module__ == "builtins":
                return None
            return vars(klass)["__init__"]
    return None


def _public_objects():
    """(label, object, kind, owner-class) for every public callable, each checked once."""
    seen: set[int] = set()
    out = []
    exported = {id(getattr(importlib.import_module(m), n)) for m in PUBLIC_MODULES
                for n in getattr(importlib.import_module(m), "__all__", [])}
    for modname in PUBLIC_MODULES:
        mod = importlib.import_module(modname)
        for name in getattr(mod, "__all__", []):
            obj = getattr(mod, name)
            if id(obj) in seen or inspect.ismodule(obj):
                continue
            if inspect.isclass(obj):
                seen.add(id(obj))
                out.append((f"{obj.__module__}.{obj.__qualname__}", obj, "class", None))
                if _is_exception(obj):
                    continue
                # methods defined on the class or inherited from a base that is not itself
                # public (a public base, e.g. LieGroup, is walked and checked on its own)
                own = [obj] + [k for k in obj.__mro__[1:] if id(k) not in exported
                               and k.__module__.startswith("microlie")]
                members = {a: r for k in reversed(own) for a, r in vars(k).items()}
                for attr, raw in members.items():
                    if attr.startswith("_"):
                        continue
                    fn = raw.__func__ if isinstance(raw, classmethod | staticmethod) else raw
                    if not inspect.isfunction(fn) or id(fn) in seen:
                        continue
                    seen.add(id(fn))
                    kind = "static" if isinstance(raw, staticmethod) else "method"
                    out.append((f"{obj.__module__}.{obj.__qualname__}.{attr}", fn, kind, obj))
            elif inspect.isfunction(obj) or callable(obj) and not isinstance(obj, type):
                if not inspect.isfunction(inspect.unwrap(obj)):
                    continue
                seen.add(id(obj))
                out.append((f"{obj.__module__}.{obj.__qualname__}", obj, "function", None))
    return out


def _problems(obj, kind: str, owner) -> list[str]:
    if kind == "method" and owner is not None:
        # an undocumented override inherits the base class's text
        doc = inspect.getdoc(getattr(owner, obj.__name__)) or ""
    else:
        doc = inspect.getdoc(obj) or ""
    if not doc:
        return ["no docstring"]
    sections = _sections(doc)
    missing = []
    if kind == "class":
        if _is_exception(obj):
            return []
        init = _own_init(obj)
        if init is not None and _takes_parameters(init, bound=True) \
                and not sections & {"Parameters", "Attributes"}:
            missing.append("Parameters")
    else:
        if _takes_parameters(obj, bound=kind == "method") and "Parameters" not in sections:
            missing.append("Parameters")
        if _returns_something(obj) and not sections & {"Returns", "Yields"}:
            missing.append("Returns")
    if ">>>" not in doc:
        missing.append("example")
    return missing


PUBLIC = _public_objects()


def test_public_api_is_large():
    """The walk found the API (a broken walk would pass everything)."""
    assert len(PUBLIC) > 150


@pytest.mark.parametrize("label,obj,kind,owner", PUBLIC, ids=[p[0] for p in PUBLIC])
def test_documented(label, obj, kind, owner):
    missing = _problems(obj, kind, owner)
    assert not missing, f"{label}: missing {', '.join(missing)}"


def test_every_public_module_has_a_reference_page():
    """Each public object is rendered by a ``::: name`` directive on an API reference page:
    one naming the object, its defining module or the public package exporting it (a package
    directive renders the package's ``__all__``)."""
    directives = set()
    for page in (ROOT / "docs" / "api").glob("*.md"):
        for line in page.read_text().splitlines():
            if line.startswith(":::"):
                directives.add(line[3:].strip())
    missing = []
    for modname in PUBLIC_MODULES:
        mod = importlib.import_module(modname)
        for name in getattr(mod, "__all__", []):
            obj = getattr(mod, name)
            if inspect.ismodule(obj) or not (inspect.isclass(obj) or inspect.isfunction(obj)):
                continue
            where = {modname, obj.__module__, f"{obj.__module__}.{obj.__name__}",
                     f"{modname}.{name}"}
            if not where & directives:
                missing.append(f"{modname}.{name}")
    assert not missing, f"not on any docs/api page: {missing}"


def test_sections_parser():
    doc = "Summary.\n\nParameters\n----------\nx : int\n\nReturns\n-------\nint\n"
    assert _sections(doc) == {"Parameters", "Returns"}
    assert _sections("Summary.\n\nParameters\n---\n") == set()
