"""Griffe extension for the API reference (mkdocs.yml: ``extensions: [tools/docs_griffe.py]``).

The docstrings are written for ``help()`` and Sphinx habits; three things are adapted when the
site is built, never in the source:

1. Sphinx roles (``:class:`X```, ``:func:``, ``:meth:``, ``:attr:``, ``:mod:``, ``:data:``,
   ``:exc:``, ``:obj:``) become code spans. A target found in microlie (by absolute path, or by
   name from the docstring's own scopes: the object, its classes, its module and the module's
   imports) becomes an optional cross-reference: a link when the object is rendered on the
   site, plain code otherwise (``~a.b.C`` shows ``C``, as in Sphinx).
2. A public class lists the public members it inherits from a private base (``Pose`` in
   ``microlie.groups._pose``, ``_ImuFilter``), and names that base's own bases as its bases:
   the private base has no page of its own. Members of a public base (``LieGroup``) stay
   documented once, on the base.
3. An override without a docstring shows its base's text, as ``inspect.getdoc`` does.
"""

from __future__ import annotations

import re
from typing import Any

from griffe import Alias, Class, Docstring, Extension, Module, Object

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|attr|mod|data|exc|obj):`([^`]+)`")


def _private(path: str) -> bool:
    return any(part.startswith("_") for part in path.split("."))


def _target(obj: Object | Alias) -> Object | None:
    """The object an alias points to (None when it leaves the loaded packages)."""
    try:
        return obj.final_target if isinstance(obj, Alias) else obj  # type: ignore[return-value]
    except Exception:  # an alias to numpy, scipy, ...: not in the collection
        return None


def _walk(start: Object | Alias, parts: list[str]) -> Object | None:
    cur = _target(start)
    for part in parts:
        if cur is None or part not in cur.members:
            return None
        cur = _target(cur.members[part])
    return cur


def resolve(context: Object, name: str) -> str | None:
    """The canonical path of ``name`` as written in ``context``'s docstring, or None."""
    parts = name.split(".")
    collection = context.modules_collection
    if parts[0] in collection.members:  # an absolute path
        found = _walk(collection.members[parts[0]], parts[1:])
        if found is not None:
            return found.path
    scope: Object | None = context
    while scope is not None:
        if scope.is_module or scope.is_class:
            members = scope.all_members if scope.is_class else scope.members  # inherited too
            if parts[0] in members:
                found = _walk(members[parts[0]], parts[1:])
                if found is not None:
                    return found.path
            if scope.is_module and parts[0] in scope.imports:  # TYPE_CHECKING imports too
                head = scope.imports[parts[0]].split(".")
                if head[0] in collection.members:
                    found = _walk(collection.members[head[0]], head[1:] + parts[1:])
                    if found is not None:
                        return found.path
        scope = scope.parent
    return None


def convert_roles(context: Object, text: str) -> str:
    """``text`` with every Sphinx role replaced by a code span or an optional cross-reference."""

    def sub(match: re.Match[str]) -> str:
        raw = match.group(1).strip()
        short = raw.startswith("~")
        name = raw.lstrip("~!.").removesuffix("()")
        shown = name.rsplit(".", 1)[-1] if short else name
        path = resolve(context, name)
        if path is None:
            return f"`{shown}`"
        return f'<autoref identifier="{path}" optional>`{shown}`</autoref>'

    return ROLE.sub(sub, text)


def _objects(obj: Object) -> list[Object]:
    """``obj`` and every object defined in it (aliases excluded)."""
    out = [obj]
    for member in obj.members.values():
        if not member.is_alias:
            out.extend(_objects(member))  # type: ignore[arg-type]
    return out


def _inherit_from_private_bases(cls: Class) -> None:
    try:
        mro = cls.mro()
    except Exception:  # a base outside the loaded packages
        return
    for base in mro:
        if not _private(base.path):
            continue
        for name, member in base.members.items():
            if name.startswith("_") or name in cls.members:
                continue
            owner = next(k for k in [cls, *mro] if name in k.members)
            if owner is base:
                cls.set_member(name, Alias(name, member, parent=cls))
    cls.bases = _public_bases(cls)


def _public_bases(cls: Class) -> list:
    """``cls``'s bases with each private base replaced by its own bases (recursively)."""
    out = []
    for expr in cls.bases:
        path = getattr(expr, "canonical_path", str(expr))
        head, *rest = path.split(".")
        collection = cls.modules_collection
        base = _walk(collection.members[head], rest) if head in collection.members else None
        if isinstance(base, Class) and _private(base.path):
            out.extend(_public_bases(base))
        else:
            out.append(expr)
    return out


def _inherit_docstring(obj: Object) -> None:
    cls = obj.parent
    if obj.docstring is not None or not isinstance(cls, Class):
        return
    try:
        mro = cls.mro()
    except Exception:
        return
    for base in mro:
        member = base.members.get(obj.name)
        doc = member.docstring if member is not None else None
        if doc is not None:
            obj.docstring = Docstring(doc.value, parent=obj, parser=doc.parser,
                                      parser_options=doc.parser_options)
            return


class MicrolieDocs(Extension):
    """The three adaptations above, applied once the package is loaded."""

    def on_package(self, *, pkg: Module, **kwargs: Any) -> None:
        objects = _objects(pkg)
        for obj in objects:
            if not _private(obj.path):
                _inherit_docstring(obj)
        for obj in objects:
            if obj.docstring is not None:
                obj.docstring.value = convert_roles(obj, obj.docstring.value)
        for obj in objects:
            if isinstance(obj, Class) and not _private(obj.path):
                _inherit_from_private_bases(obj)
