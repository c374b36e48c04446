"""When a cached kernel is stale: keyed on the code it is made of, function by function.

    stamp = kernel_stamp(py_func)     # changes when py_func's code, or code or a constant it uses, changes
    cache = KernelCache(py_func)      # numba's FunctionCache for raykernel's kernels (config.njit sets it)

numba keeps each compiled function in an index file stamped with its source
file: by default the hash of the file's bytes, so a docstring or a comment
edit drops every kernel of the file, and a kernel that inlines a helper from
another file never sees that file change. raykernel's kernels are looked up
with a locator of their own instead. The stamp of a kernel is made from the
live objects it is compiled from, when it is first compiled or loaded (never
at import):

* its own code: the bytecode, names and constants of the function and of the
  functions nested in it, without the docstring and without line numbers, so
  comments, docstrings, blank lines and moved code change nothing;
* for every global name that code reads, what the name holds: another
  kernel or helper of raykernel's (its stamp, recursively), the overloads and
  intrinsics numba compiles in its place, a constant (a counter column, a
  stack size that a kernel freezes when it compiles: its value), or a module
  or class of raykernel's (the members the code names); code of other
  packages (numpy, numba, math) by name, as numba's version is in the key.

So an edit recompiles the kernels that use what it changed and no others: an
error message or a builder that no walk calls leaves the walks cached. The
file name of a cache entry is the kernel's qualified name and a hash of its
own code (numba's default, the first line number, moves with every line
added above it). numba checks the rest as it always does: each entry is keyed
on the signature, the CPU and the function's bytecode, and the index on
numba's version. The entries live in one folder per checkout (see
config.CACHE_DIR); an entry whose stamp no longer matches is overwritten by
the next compile.
"""

from __future__ import annotations

import hashlib
import inspect
import os
import pickle
import threading
import types
from pathlib import Path

import llvmlite.binding as ll
import numpy as np
from numba.core.runtime import rtsys
from numba.core.caching import CompileResultCacheImpl, FunctionCache, IndexDataCacheFile, _CacheLocator
from numba.core.codegen import JITCodeLibrary

from .inlining import skip_inline_copies

PACKAGE = Path(__file__).resolve().parents[1]   # raykernel/
OURS = PACKAGE.name
_FUNCTION_FLAGS = inspect.CO_OPTIMIZED | inspect.CO_NEWLOCALS
_PLAIN = (int, float, complex, bool, str, bytes, type(None), np.number, np.bool_, np.dtype)

_lock = threading.RLock()
_stamps: dict = {}          # id(function) -> (function, stamp): each function stamped once a process
_overloads: tuple[int, dict] = (-1, {})     # (how many globals numba had registered, the table made from them)


def _ours(obj, home: str) -> bool:
    """Is obj (a function, class or module) raykernel's, or of the module the kernel is in (a test's)?"""
    module = obj.__name__ if isinstance(obj, types.ModuleType) else getattr(obj, "__module__", None) or ""
    return module == home or module == OURS or module.startswith(OURS + ".")


def _code_text(code: types.CodeType, out: list) -> None:
    """The code object's bytecode, names and constants, nested code objects included; a
    function's docstring (its first constant, None when it has none) left out."""
    out += [code.co_code.hex(), repr(code.co_names), repr(code.co_varnames), repr(code.co_freevars)]
    consts = code.co_consts
    if code.co_flags & _FUNCTION_FLAGS == _FUNCTION_FLAGS and not code.co_name.startswith("<") and consts:
        consts = consts[1:]
    for const in consts:
        if isinstance(const, types.CodeType):
            _code_text(const, out)
        else:
            out.append(repr(const))


def _names(code: types.CodeType, found: set) -> set:
    found.update(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            _names(const, found)
    return found


def own_code(func) -> str:
    """A hash of a function's own code (see _code_text): the same for the same code wherever it is."""
    out = []
    _code_text(func.__code__, out)
    return hashlib.sha256("\0".join(out).encode()).hexdigest()


def _overload_table() -> dict:
    """id(stub) -> the functions numba's @overload compiles in its place (read again when modules
    imported since have registered more)."""
    global _overloads
    from numba.core.typing.templates import builtin_registry
    registered = builtin_registry.globals
    if _overloads[0] != len(registered):
        table: dict = {}
        for func, typ in registered:
            for template in getattr(typ, "templates", ()):
                impl = getattr(template, "_overload_func", None)
                if impl is not None:
                    table.setdefault(id(func), []).append(impl)
        _overloads = (len(registered), table)
    return _overloads[1]


def _value(obj, names: frozenset, home: str, busy: dict) -> str:
    """What a global the kernel reads contributes to its stamp."""
    if isinstance(obj, _PLAIN):
        return f"{type(obj).__name__}:{obj!r}"
    if isinstance(obj, (tuple, list, frozenset)):
        items = sorted(obj, key=repr) if isinstance(obj, frozenset) else obj
        return f"{type(obj).__name__}(" + ",".join(_value(x, names, home, busy) for x in items) + ")"
    if isinstance(obj, np.ndarray):
        return f"array:{obj.dtype}:{obj.shape}:{hashlib.sha256(np.ascontiguousarray(obj).tobytes()).hexdigest()}"
    py_func = getattr(obj, "py_func", None) or getattr(obj, "_defn", None)     # a dispatcher, an intrinsic
    if isinstance(py_func, types.FunctionType):
        return _value(py_func, names, home, busy)
    if isinstance(obj, types.FunctionType):
        if not _ours(obj, home):
            return f"func:{obj.__module__}.{obj.__qualname__}"
        return "func:" + _stamp(obj, home, busy)
    if isinstance(obj, (types.ModuleType, type)):
        label = f"{type(obj).__name__}:{getattr(obj, '__module__', '')}.{getattr(obj, '__qualname__', obj.__name__)}"
        if not _ours(obj, home):
            return label
        members = sorted(n for n in names if n in vars(obj))
        label += repr(getattr(obj, "_fields", ""))          # a named tuple's fields
        return label + "{" + ",".join(f"{n}={_value(vars(obj)[n], names, home, busy)}" for n in members) + "}"
    text = repr(obj)
    return type(obj).__qualname__ + (":" + text if " at 0x" not in text else "")


def _stamp(func, home: str, busy: dict) -> str:
    """busy: id -> function of the stamps being made, "cycles": how many cycles were met, and
    "overloads": _overload_table()."""
    key = id(func)
    done = _stamps.get(key)
    if done is not None and done[0] is func:
        return done[1]
    if key in busy:                 # a call cycle: the function's own code stands for it
        busy["cycles"] += 1
        return own_code(func)
    busy[key] = func
    cycles = busy["cycles"]
    try:
        names = frozenset(_names(func.__code__, set()))
        parts = [func.__qualname__, own_code(func),       # default arguments are frozen in too
                 _value((func.__defaults__ or ()) + tuple((func.__kwdefaults__ or {}).items()), names, home, busy)]
        scope = func.__globals__
        for name in sorted(names):
            if name in scope:
                parts.append(f"{name}={_value(scope[name], names, home, busy)}")
        for name, cell in zip(func.__code__.co_freevars, func.__closure__ or ()):
            try:
                parts.append(f"{name}~{_value(cell.cell_contents, names, home, busy)}")
            except ValueError:      # an empty cell
                parts.append(f"{name}~")
        for impl in busy["overloads"].get(key, ()):
            parts.append("overload:" + _value(impl, names, home, busy))
        stamp = hashlib.sha256("\0".join(parts).encode()).hexdigest()
    finally:
        del busy[key]
    if busy["cycles"] == cycles:    # a stamp that met a cycle depends on where it was entered: not kept
        _stamps[key] = (func, stamp)
    return stamp


def kernel_stamp(py_func) -> str:
    """The stamp of a kernel's cache entries: its code and everything it compiles in (see above)."""
    with _lock:
        return _stamp(py_func, py_func.__module__, {"cycles": 0, "overloads": _overload_table()})


def function_key(py_func) -> str:
    """A short hash of a function's own code: the cache entry's name, which does not move with the
    lines above it."""
    return own_code(py_func)[:12]


def all_stamps() -> dict[str, str]:
    """module.qualname -> stamp of every cached kernel of the package (every module imported)."""
    import importlib
    import pkgutil
    stamps = {}
    for info in pkgutil.walk_packages([str(PACKAGE)], OURS + "."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        for obj in list(vars(module).values()):
            if isinstance(getattr(obj, "_cache", None), KernelCache) and obj.py_func.__module__ == info.name:
                stamps[f"{info.name}.{obj.py_func.__qualname__}"] = kernel_stamp(obj.py_func)
    return stamps


class _CodeLocator(_CacheLocator):
    """numba's cache locator for raykernel's kernels: the folder of `cache_dir()`, the stamp of
    kernel_stamp, the entry name of function_key."""

    cache_dir = None        # set by config: a callable giving the folder of this checkout's kernels

    def __init__(self, py_func, py_file):
        self._py_func = py_func
        self._py_file = py_file     # where numba's "cannot cache" warning points (NUMBA_OPT=0 meets it)
        self._cache_path = os.path.join(self.cache_dir(), self.get_suitable_cache_subpath(py_file))

    def get_cache_path(self):
        return self._cache_path

    def get_source_stamp(self):
        return kernel_stamp(self._py_func)

    def get_disambiguator(self):
        return function_key(self._py_func)

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


# what unpickling an entry raises when it names a module or class that has moved or gone since it was written
_STALE = (ImportError, AttributeError, EOFError, TypeError, pickle.UnpicklingError)


class _TolerantIndex(IndexDataCacheFile):
    """numba's index and data files of one kernel, where an entry that no longer unpickles is a miss,
    compiled again and written over: the code it was compiled from is unchanged (the stamp matches),
    but a type it names now lives in another module. numba's own raises, and the kernel fails."""

    def _load_index(self):
        try:
            return super()._load_index()
        except _STALE:
            return {}

    def _load_data(self, name):
        try:
            return super()._load_data(name)
        except _STALE:
            return None


class _LinkedOnDemand(JITCodeLibrary):
    """numba's JIT code library, where a kernel loaded from raykernel's cache parses the LLVM module
    that later compiles link against (the whole kernel, a large part of a load) only when one does.
    Its machine code and its symbols load at once: the entry stores the symbols' names beside the
    module's bitcode (_CodeCacheImpl.reduce). Libraries numba compiles or loads otherwise are
    numba's own in all but the class name."""

    @property
    def _shared_module(self):
        bitcode = self.__dict__.pop("_bitcode", None)
        if bitcode is not None:         # the first link: under numba's compile lock, as every link
            self.__dict__["_linking_module"] = ll.parse_bitcode(bitcode)
        return self.__dict__.get("_linking_module")

    @_shared_module.setter
    def _shared_module(self, module):
        self.__dict__.pop("_bitcode", None)
        self.__dict__["_linking_module"] = module

    @classmethod
    def _unserialize(cls, codegen, state):
        name, kind, data = state
        if kind != "object" or len(data) != 3:      # numba's own entries
            return super()._unserialize(codegen, state)
        object_code, bitcode, symbols = data
        library = codegen.create_library(name)
        library.enable_object_caching()
        library._set_compiled_object(object_code)
        library._bitcode = bitcode
        library._finalize_final_module()
        codegen._engine._defined_symbols.update(symbols)     # what numba reads off the parsed module
        return library


def _linked_on_demand(target_context) -> bool:
    """Make target_context's codegen create _LinkedOnDemand libraries (once; where its class is
    numba's JIT library, as written against). Returns whether they are in effect."""
    codegen = target_context.codegen()
    if codegen._library_class is JITCodeLibrary:
        codegen._library_class = _LinkedOnDemand
    return codegen._library_class is _LinkedOnDemand


class _CodeCacheImpl(CompileResultCacheImpl):
    _locator_classes = [_CodeLocator]

    def reduce(self, cres):
        """numba's entry, with the names of the symbols the kernel's code defines beside its bitcode
        where it will load as a _LinkedOnDemand library."""
        libdata, *rest = super().reduce(cres)
        name, kind, data = libdata
        if not (kind == "object" and isinstance(cres.library, _LinkedOnDemand)):
            return (libdata, *rest)
        module = cres.library._get_module_for_linking()
        symbols = sorted(g.name for part in (module.functions, module.global_variables) for g in part
                         if not g.is_declaration)
        return ((name, kind, (*data, symbols)), *rest)


def _ready_to_load(target_context) -> None:
    """What machine code loaded from the cache links against: numba's runtime (NRT) and the hash
    secret's symbols; and loaded libraries that parse their LLVM module on demand (_LinkedOnDemand).
    numba's own load refreshes the whole target context first, importing and registering every
    typing and lowering module, which only a compile needs (and numba's compiler refreshes before
    it compiles): a fifth of a second of every process's start."""
    rtsys.initialize(target_context)
    import numba.cpython.hashing  # noqa: F401  (defines the _numba_hashsecret_ symbols)
    _linked_on_demand(target_context)


class KernelCache(FunctionCache):
    """numba's function cache with the locator above; other numba code keeps numba's own. Made
    when a kernel is decorated, it finds its folder and stamp only when the kernel is first
    compiled or loaded; without a writable folder it caches nothing."""
    _impl_class = _CodeCacheImpl

    def __init__(self, py_func):        # numba's stamps the kernel here: deferred to _open
        self._name = repr(py_func)
        self._py_func = py_func
        self._opened = False
        self._usable = False
        self.enable()

    def _open(self) -> bool:
        with _lock:
            if not self._opened:
                try:
                    self._impl = self._impl_class(self._py_func)
                except RuntimeError:        # no writable cache folder: compiled in every process
                    self._impl = None
                else:
                    self._cache_path = self._impl.locator.get_cache_path()
                    self._cache_file = _TolerantIndex(cache_path=self._cache_path,
                                                          filename_base=self._impl.filename_base,
                                                          source_stamp=self._impl.locator.get_source_stamp())
                self._usable = self._impl is not None
                self._opened = True
        return self._usable

    @property
    def cache_path(self):
        return self._cache_path if self._open() else None

    def has_entries(self) -> bool:
        """True when the cache holds an entry of this kernel for its current code."""
        return self._open() and bool(self._cache_file._load_index())

    def flush(self):
        if self._open():
            self._cache_file.flush()

    def load_overload(self, sig, target_context):
        if not self._open():
            skip_inline_copies()
            return None
        _ready_to_load(target_context)
        with self._guard_against_spurious_io_errors():
            found = self._load_overload(sig, target_context)
        if found is None:       # numba compiles it next (under its compile lock): with the short inliner
            skip_inline_copies()
        return found

    def save_overload(self, sig, data):
        if self._open():
            super().save_overload(sig, data)
