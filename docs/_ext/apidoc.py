"""What the API reference documents, shared by ``conf.py`` and ``tests/test_docs_api.py``.

A public constant (``CUT_OK = 0``) has no docstring of its own: ``CUT_OK.__doc__`` is
``int``'s. Its description is the ``#:`` comment above its assignment in the module that
defines it (Sphinx's convention), usually a private module the public one re-exports, where
autodoc does not look. :func:`constant_doc` finds that comment.
"""

import ast
import functools
import importlib
import inspect
import pkgutil

PACKAGE = "sklearn_psf"


def public_modules():
    """Names of the package's public modules: no path component starts with ``_``."""
    package = importlib.import_module(PACKAGE)
    names = [PACKAGE]
    for info in pkgutil.walk_packages(package.__path__, PACKAGE + "."):
        if not any(part.startswith("_") for part in info.name.split(".")):
            names.append(info.name)
    return names


@functools.lru_cache(maxsize=None)
def _all_modules(root):
    path = getattr(importlib.import_module(root), "__path__", [])
    return [root] + [info.name for info in pkgutil.walk_packages(path, root + ".")
                     if not info.name.endswith("__main__")]


@functools.lru_cache(maxsize=None)
def _comments(module):
    """``{name: [comment lines]}`` of the module-level ``#:`` comments of a module."""
    try:
        source = inspect.getsource(module)
    except (OSError, TypeError):
        return {}
    lines = source.splitlines()
    found = {}
    for node in ast.parse(source).body:
        if isinstance(node, ast.Assign):
            targets = [t.id for t in node.targets if isinstance(t, ast.Name)]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            targets = [node.target.id]
        else:
            continue
        comment = []
        i = node.lineno - 2
        while i >= 0 and lines[i].lstrip().startswith("#:"):
            comment.insert(0, lines[i].lstrip()[2:].strip())
            i -= 1
        for target in targets:
            if comment:
                found[target] = comment
    return found


def constant_doc(module_name, name):
    """The ``#:`` comment documenting ``module_name.name``, searched in the module and the
    modules of its package that hold the same object; None if there is none."""
    obj = getattr(importlib.import_module(module_name), name)
    for candidate in [module_name, *_all_modules(module_name.split(".")[0])]:
        module = importlib.import_module(candidate)
        if getattr(module, name, None) is obj and name in (comments := _comments(module)):
            return comments[name]
    return None


def is_constant(obj):
    """True for data (numbers, strings, containers, tables), not classes, functions or
    modules."""
    return not (inspect.isclass(obj) or inspect.isroutine(obj) or inspect.ismodule(obj))
