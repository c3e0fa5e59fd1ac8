"""The layout: subpackages import each other in one direction (library -> study -> cli),
with no circle, counting imports inside functions too; no module is over 800 lines."""

import ast
import pathlib

import sklearn_psf

ROOT = pathlib.Path(sklearn_psf.__file__).parent
LIBRARY = {"interpolate", "preprocessing", "measure", "model", "metrics", "simulate",
           "datasets", "io", "exposure", "validation"}


def _edges():
    edges = {}
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT).parts
        src = rel[0].removesuffix(".py")
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                base = list(rel[:-1])[: len(rel) - 1 - (node.level - 1)]
                target = base + [m for m in (node.module or "").split(".") if m]
                if target and target[0].removesuffix(".py") != src:
                    edges.setdefault(src, set()).add(target[0].removesuffix(".py"))
    return edges


def test_no_import_circle_between_subpackages():
    edges = _edges()

    def reaches(start, goal, seen=()):
        return any(n == goal or (n not in seen and reaches(n, goal, (*seen, n)))
                   for n in edges.get(start, ()))

    circles = [name for name in edges if reaches(name, name)]
    assert not circles, f"import circles through {sorted(circles)}: {edges}"


def test_library_imports_neither_study_nor_cli():
    edges = _edges()
    upward = {name: sorted(edges.get(name, set()) & {"study", "cli"}) for name in LIBRARY}
    assert not any(upward.values()), upward
    assert "cli" not in edges.get("study", set())


#: What ``io`` must not import: it reads and writes files, nothing more (issue 50); the path
#: from files to a model is ``exposure``'s.
NOT_FOR_IO = {"model", "validation", "preprocessing", "measure", "interpolate", "exposure",
              "study", "cli"}


def test_io_reads_and_writes_files_only():
    edges = _edges()
    assert "io" in edges  # it imports _files at least: the walk found it
    assert not edges["io"] & NOT_FOR_IO, sorted(edges["io"] & NOT_FOR_IO)


#: The longest a module of the package may be (issue 50: a module a reader can hold).
MAX_MODULE_LINES = 800


def test_no_module_over_max_lines():
    lines = {str(path.relative_to(ROOT)): len(path.read_text().splitlines())
             for path in sorted(ROOT.rglob("*.py"))}
    long = {name: n for name, n in lines.items() if n > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


#: The longest a function or method of the package may be, and the most parameters a public
#: callable may take (issue 50: a function a reader can hold, a call one can write).
MAX_FUNCTION_LINES = 200
MAX_PUBLIC_PARAMETERS = 20


def _functions():
    """``{"path:qualname": (lines, node)}`` of every function and method of the package."""
    found = {}

    def visit(node, prefix, path):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    found[f"{path}:{name}"] = child.end_lineno - child.lineno + 1
                visit(child, f"{name}.", path)
            else:
                visit(child, prefix, path)

    for path in sorted(ROOT.rglob("*.py")):
        visit(ast.parse(path.read_text()), "", path.relative_to(ROOT).as_posix())
    return found


def _public_callables():
    """``{"path:qualname": number of parameters}`` of the functions and classes (their
    ``__init__``, ``self`` left out) named in the ``__all__`` of a public module."""
    import importlib
    import inspect
    import pkgutil

    modules = [sklearn_psf] + [
        importlib.import_module(info.name)
        for info in pkgutil.walk_packages(sklearn_psf.__path__, "sklearn_psf.")
        if not any(part.startswith("_") for part in info.name.split("."))]
    found = {}
    for module in modules:
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if not callable(obj) or not (inspect.isfunction(obj) or inspect.isclass(obj)):
                continue
            func = obj.__init__ if inspect.isclass(obj) else obj
            try:
                source = pathlib.Path(inspect.getsourcefile(func))
                params = inspect.signature(func).parameters
            except (TypeError, ValueError):  # a C or inherited-from-object __init__
                continue
            if ROOT not in source.parents:
                continue  # inherited from a dependency
            key = f"{source.relative_to(ROOT).as_posix()}:{func.__qualname__}"
            found[key] = len([p for p in params if p != "self"])
    return found


def test_no_function_over_max_lines_and_no_public_call_over_max_parameters():
    long = {k: n for k, n in _functions().items() if n > MAX_FUNCTION_LINES}
    wide = {k: n for k, n in _public_callables().items() if n > MAX_PUBLIC_PARAMETERS}
    over = {f"{k} ({n} lines)" for k, n in long.items()}
    over |= {f"{k} ({n} parameters)" for k, n in wide.items()}
    assert not over, (f"functions over {MAX_FUNCTION_LINES} lines or public callables over "
                      f"{MAX_PUBLIC_PARAMETERS} parameters: {sorted(over)}; split them")


def test_every_stage_the_speed_profile_times_exists():
    # benchmarks/_stages.py wraps functions by "module:attribute path"; a function moved
    # without updating it stops every profiled run (save_model after its move to model)
    import importlib
    import importlib.util

    path = ROOT.parent / "benchmarks" / "_stages.py"
    if not path.exists():  # an installed package without the repository's benchmarks
        return
    spec = importlib.util.spec_from_file_location("_stages", path)
    stages = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(stages)
    missing = []
    for name, target in stages.STAGES:
        module, attrs = target.split(":")
        owner = importlib.import_module(module)
        for part in attrs.split("."):
            owner = getattr(owner, part, None)
        if owner is None:
            missing.append(f"{name.strip()}: {target}")
    assert not missing, f"stages of benchmarks/_stages.py that no longer exist: {missing}"
