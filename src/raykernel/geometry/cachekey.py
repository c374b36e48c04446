"""When a cached kernel is stale: keyed on the code it is made of, not on the text of its files.

    stamp = code_stamp(path)          # changes when the code of path, or of a module it imports, changes
    cache = KernelCache(py_func)      # numba's FunctionCache for raykernel's kernels (config.njit sets it)

numba keeps each compiled function in an index file stamped with its source
file: by default the hash of the file's bytes, so a docstring or a comment
edit drops every kernel of the file, and a kernel that inlines a helper from
another file never sees that file change. raykernel's kernels are looked up
with a locator of their own instead:

* the stamp of a kernel is a hash of the *code* of its file and of every
  package file it imports from, directly or not (relative imports anywhere in
  the file, in-function ones included): each file's syntax tree with its
  docstrings taken out and without line numbers, so comments, docstrings,
  blank lines and line wrapping change nothing, while any change to a
  statement, a name or a constant (a counter column, a stack size that a
  kernel freezes when it compiles) gives a new stamp for that file and for
  every file that imports it;
* the file name of its cache entry is its qualified name and a hash of its
  own code (numba's default, the first line number, moves with every line
  added above it).

numba checks the rest as it always does: each entry is keyed on the
signature, the CPU and the function's bytecode, and the index on numba's
version. The entries live in one folder per checkout (see config.CACHE_DIR);
an entry whose stamp no longer matches is overwritten by the next compile.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import inspect
import os
from pathlib import Path

from numba.core.caching import CompileResultCacheImpl, FunctionCache, _CacheLocator

PACKAGE = Path(__file__).resolve().parents[1]   # raykernel/


def _strip_docstrings(tree: ast.AST) -> ast.AST:
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body
                and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return tree


def code_of(source: str) -> str:
    """The code of a module's source: its syntax tree without docstrings, comments or positions."""
    return ast.dump(_strip_docstrings(ast.parse(source)))


def _imports(path: Path, tree: ast.AST, package: Path) -> set[Path]:
    """The package files `path` imports from by relative imports (`from .a import b`, `from . import c`)."""
    found = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.ImportFrom) or not node.level:
            continue
        base = path.parent
        for _ in range(node.level - 1):
            base = base.parent
        target = base.joinpath(*node.module.split(".")) if node.module else base
        candidates = [target.with_suffix(".py"), target / "__init__.py"]
        candidates += [target / f"{alias.name}.py" for alias in node.names]
        candidates += [target / alias.name / "__init__.py" for alias in node.names]
        found.update(c for c in candidates if c.is_file() and package in c.parents)
    return found


@functools.lru_cache(maxsize=None)
def _file(path: Path, package: Path, mtime_ns: int, size: int) -> tuple[str, frozenset]:
    """(hash of the file's code, the package files it imports), memoised on the file's state."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    imports = frozenset(_imports(path, tree, package))
    return hashlib.sha256(ast.dump(_strip_docstrings(tree)).encode()).hexdigest(), imports


def _read(path: Path, package: Path) -> tuple[str, frozenset]:
    st = path.stat()
    return _file(path, package, st.st_mtime_ns, st.st_size)


def dependencies(path, package: Path = PACKAGE) -> list[Path]:
    """`path` and every file of `package` it imports from, directly or not, sorted."""
    path = Path(path).resolve()
    seen, todo = {path}, [path]
    while todo:
        for dep in _read(todo.pop(), package)[1]:
            if dep not in seen:
                seen.add(dep)
                todo.append(dep)
    return sorted(seen)


def code_stamp(path, package: Path = PACKAGE) -> str:
    """The stamp of the kernels defined in `path`: a hash of its code and of its dependencies'
    (files of `package`, raykernel's by default)."""
    package, path = Path(package).resolve(), Path(path).resolve()
    if package not in path.parents:         # a kernel of another folder (a test's): its own folder
        package = path.parent
    digest = hashlib.sha256()
    for dep in dependencies(path, package):
        digest.update(str(dep.relative_to(package)).encode() + b"\0" + _read(dep, package)[0].encode() + b"\0")
    return digest.hexdigest()


def function_key(py_func) -> str:
    """A short hash of a function's own code (its source's syntax tree less docstrings), else of
    its bytecode: the cache entry's name, which does not move with the lines above it."""
    try:
        source = inspect.getsource(py_func)
        text = code_of(_dedent(source))
    except (OSError, TypeError, SyntaxError):
        text = py_func.__code__.co_code.hex()
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _dedent(source: str) -> str:
    """A nested function's source, made parseable on its own."""
    lines = source.splitlines()
    indent = len(lines[0]) - len(lines[0].lstrip())
    return "\n".join(line[indent:] for line in lines)


class _CodeLocator(_CacheLocator):
    """numba's cache locator for raykernel's kernels: the folder of `cache_dir()`, the stamp of
    code_stamp, the entry name of function_key."""

    cache_dir = None        # set by config: a callable giving the folder of this checkout's kernels

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._key = function_key(py_func)
        self._cache_path = os.path.join(self.cache_dir(), self.get_suitable_cache_subpath(py_file))

    def get_cache_path(self):
        return self._cache_path

    def get_source_stamp(self):
        return code_stamp(self._py_file)

    def get_disambiguator(self):
        return self._key

    @classmethod
    def from_function(cls, py_func, py_file):
        if not os.path.exists(py_file):
            return None
        locator = cls(py_func, py_file)
        try:
            locator.ensure_cache_path()
        except OSError:
            return None
        return locator


class _CodeCacheImpl(CompileResultCacheImpl):
    _locator_classes = [_CodeLocator]


class KernelCache(FunctionCache):
    """numba's function cache with the locator above; other numba code keeps numba's own."""
    _impl_class = _CodeCacheImpl
