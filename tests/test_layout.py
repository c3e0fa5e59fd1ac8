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
