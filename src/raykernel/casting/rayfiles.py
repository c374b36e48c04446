"""Files of rays and of their hits, read and written a chunk at a time (what `raykernel cast` streams).

    rays = open_rays("rays.npz")                # RayFileError now if its arrays' shapes or dtypes are wrong
    o, d, lo, hi = rays.read(a, b)              # rays a..b-1: float64 (n, 3), (n, 3), and (n,) or None
    o, d, lo, hi = rays.read(a, b, buffers)     # the same, into a Buffers' arrays kept from chunk to chunk
    out = open_results("hits.zarr", rays.count, chunk, fields, fields_dtype, about)   # made, or checked to resume
    out.write(k, {"t": t, "prim_id": prim})     # chunk k, each array of it written atomically
    out.done()                                  # the chunks already written (a set of k)

Rays come from:

* ``.npz`` with ``origins`` and ``directions`` (N, 3) and optionally ``tmin`` and ``tmax``
  (N,), as np.savez writes it (stored: np.savez_compressed's members cannot be read a chunk
  at a time and are refused);
* ``.npy`` of shape (N, 6): origin then direction, a ray a row;
* a zarr group (a folder, ``.zarr``) with the arrays of the .npz;
* a Parquet file with columns ox, oy, oz, dx, dy, dz (and optionally tmin, tmax).

Any real dtype, read as float64. Results go to a zarr group (a folder ``.zarr``: one array a
field, chunked as the cast, written uncompressed, since t compresses little and the cores are
the cast's) or a Parquet dataset (a folder ``.parquet``: one file a chunk, vector fields as
fixed-size lists), both readable whole by their libraries (``zarr.open_group``,
``pyarrow.parquet.read_table``). A results folder records what made it (`about`: the rays,
their count, the scene, the fields, the chunk), so a rerun of the same cast resumes it and
another is refused. Every chunk is written atomically (zarr's local store and atomicfile
write a temporary file and rename it), so a killed run leaves whole chunks only.

A reader and a writer pickle small (paths and shapes): Dask workers open the files themselves,
which they must reach at the same paths (as with Dask's own from_zarr and to_zarr).
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

from ..atomicfile import atomic_write, check_output_directory
from ..errors import OptionError
from ..geometry.config import njit
from .rayinput import RayInputError

PARQUET_COLUMNS = ("ox", "oy", "oz", "dx", "dy", "dz")
ABOUT = "raykernel.cast"        # the zarr group's attribute, and the Parquet folder's file _cast.json
STOP = ".stop"                  # a results folder's file that tells tasks at work to stop


class RayFileError(RayInputError):
    """A file of rays or of results is not valid, or a chunk of it holds a bad ray: the message
    starts with the file (and the chunk)."""

    def __init__(self, message: str, path, chunk: int | None = None, rows: tuple | None = None):
        self.message, self.path, self.chunk, self.rows = message, str(path), chunk, rows
        where = f"{path}: " if chunk is None else f"{path}: chunk {chunk} (rays {rows[0]:,} to {rows[1] - 1:,}): "
        super().__init__(where + message)

    def __reduce__(self):       # made again from its parts on the far side of a Dask task
        return type(self), (self.message, self.path, self.chunk, self.rows)


def _needs(module: str, extra: str = "cast"):
    try:
        return __import__(module, fromlist=["_"])
    except ImportError:
        raise OptionError(f"{module} is needed for this file: pip install 'raykernel[{extra}]'") from None


def _real(dtype, name: str, path) -> None:
    if not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer)) or dtype == bool:
        raise RayFileError(f"{name} must hold real numbers, got dtype {dtype}", path)


# ----------------------------------------------------------------- rays

class Buffers:
    """Arrays kept from one chunk to the next: new memory each chunk costs the process a page fault
    every 4 kB (a tenth of a chunk's casting, in the kernel's time)."""

    def __init__(self):
        self._arrays = {}

    def get(self, name: str, shape: tuple, dtype) -> np.ndarray:
        """An array of this shape and dtype, not cleared: the one of this name, grown if need be."""
        dtype, size = np.dtype(dtype), int(np.prod(shape, dtype=np.int64))
        have = self._arrays.get(name)
        if have is None or have.dtype != dtype or have.size < size:
            have = self._arrays[name] = np.empty(size, dtype)
        return have[:size].reshape(shape)


def array_in(buffers: Buffers | None, name: str, shape: tuple, dtype) -> np.ndarray:
    """buffers.get(name, shape, dtype), or a new array where there are no buffers."""
    return np.empty(shape, dtype) if buffers is None else buffers.get(name, shape, dtype)


@njit
def _split_rays(block, o, d):
    # one pass on one thread (numpy's strided, converting copy takes three times as long, and the
    # cores are the casting's): origins and directions of (n, 6) rows
    for i in range(block.shape[0]):
        for j in range(3):
            o[i, j] = block[i, j]
            d[i, j] = block[i, 3 + j]


class _Npy:
    """A C-ordered array at `offset` bytes into a file (a .npy, or a stored member of a .npz), read a
    block of rows at a time (the process keeps only the block it reads: no mapping of the whole)."""

    def __init__(self, path, offset: int, shape: tuple, dtype):
        self.path, self.offset, self.shape, self.dtype = str(path), offset, shape, np.dtype(dtype)

    def window(self, a: int, b: int) -> np.ndarray:
        """Rows a..b-1 mapped, not read: the pages are the file's own (no copy), mapped until the
        array is dropped."""
        row = self.dtype.itemsize * int(np.prod(self.shape[1:], dtype=np.int64))
        if os.path.getsize(self.path) < self.offset + b * row:
            raise RayFileError(f"ends before row {b:,} of {self.shape[0]:,}", self.path)
        return np.memmap(self.path, self.dtype, "r", self.offset + a * row, (b - a,) + self.shape[1:])

    def rows(self, a: int, b: int) -> np.ndarray:
        row = self.dtype.itemsize * int(np.prod(self.shape[1:], dtype=np.int64))
        out = np.empty((b - a,) + self.shape[1:], self.dtype)
        with open(self.path, "rb") as f:
            f.seek(self.offset + a * row)
            if f.readinto(memoryview(out).cast("B")) != out.nbytes:
                raise RayFileError(f"ends before row {b:,} of {self.shape[0]:,}", self.path)
        return out


def _npy_header(f, path, name: str):
    """(shape, dtype) of the .npy stream f (its header read)."""
    try:
        version = np.lib.format.read_magic(f)
        read = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}.get(version)
        if read is None:
            raise ValueError(f"format version {version} (write it with numpy's np.save)")
        shape, fortran, dtype = read(f)
    except ValueError as e:
        raise RayFileError(f"{name} is not a .npy array ({e})", path) from None
    if fortran and len(shape) > 1:
        raise RayFileError(f"{name} is in Fortran order; write it in C order (np.ascontiguousarray)", path)
    if dtype.hasobject:
        raise RayFileError(f"{name} holds Python objects, not numbers", path)
    return shape, dtype


def _npz_member(path, zf: zipfile.ZipFile, name: str, shown) -> _Npy | None:
    """The member `name` of the .npz at `path` (named `shown` in errors), None if it has none."""
    info = next((i for i in zf.infolist() if i.filename in (name, name + ".npy")), None)
    if info is None:
        return None
    if info.compress_type != zipfile.ZIP_STORED:
        raise RayFileError(f"{name} is compressed (np.savez_compressed), which cannot be read a chunk at a time; "
                           f"write the file with np.savez", shown)
    with zf.open(info) as member:
        shape, dtype = _npy_header(member, shown, name)
        header = member.tell()
    with open(path, "rb") as f:         # the member's data follows its local header and name
        f.seek(info.header_offset + 26)
        skip = int.from_bytes(f.read(2), "little") + int.from_bytes(f.read(2), "little")
    return _Npy(path, info.header_offset + 30 + skip + header, shape, dtype)


class RaySource:
    """The rays of a file: `count` of them, read by `read(a, b)` (module docstring: the formats)."""

    def __init__(self, path, kind: str, count: int, parts: dict):
        # read at its absolute path (a worker's working folder may differ), named as given
        self.name, self.path = str(path), str(Path(path).absolute())
        self.kind, self.count, self.parts = kind, count, parts

    def describe(self) -> dict:
        """What identifies these rays for a resumed cast: the file, its size and the ray count."""
        p = Path(self.path)
        size = p.stat().st_size if p.is_file() else None
        return {"rays": str(p.resolve()), "bytes": size, "count": self.count, "tmin": "tmin" in self.parts,
                "tmax": "tmax" in self.parts}

    def reserve(self, n: int, buffers: Buffers) -> None:
        """Make and touch the arrays read(a, a + n, buffers) fills, so that its first call meets no
        fresh memory (only a .npy reads into buffers)."""
        if self.kind == "npy":
            for name in ("origins", "directions"):
                buffers.get(name, (n, 3), np.float64).fill(0.0)

    def read(self, a: int, b: int, buffers: Buffers | None = None):
        """Rays a..b-1: origins and directions float64 (n, 3), tmin and tmax float64 (n,) or None;
        a .npy's into the arrays of `buffers` where given."""
        if self.kind == "npy":
            rays = self.parts["rays"]
            o, d = (array_in(buffers, name, (b - a, 3), np.float64) for name in ("origins", "directions"))
            block = rays.window(a, b)       # read once, as converted: no copy of the file's bytes first
            if rays.dtype in (np.float32, np.float64):
                _split_rays(np.asarray(block), o, d)
            else:
                o[:], d[:] = block[:, :3], block[:, 3:]
            del block
            return o, d, None, None
        if self.kind == "parquet":
            return self._parquet(a, b)
        if self.kind == "zarr":
            group = _needs("zarr").open_group(self.path, mode="r")
            get = lambda name: group[name][a:b] if name in self.parts else None     # noqa: E731
        else:
            get = lambda name: self.parts[name].rows(a, b) if name in self.parts else None     # noqa: E731
        o, d, lo, hi = (get(name) for name in ("origins", "directions", "tmin", "tmax"))
        as64 = lambda x: None if x is None else np.ascontiguousarray(x, np.float64)     # noqa: E731
        return as64(o), as64(d), as64(lo), as64(hi)

    def _parquet(self, a: int, b: int):
        pq = _needs("pyarrow.parquet")
        f = pq.ParquetFile(self.path)
        starts = np.cumsum([0] + [f.metadata.row_group(i).num_rows for i in range(f.num_row_groups)])
        first, last = np.searchsorted(starts, a, "right") - 1, np.searchsorted(starts, b, "left")
        columns = [c for c in (*PARQUET_COLUMNS, "tmin", "tmax") if c in self.parts]
        table = f.read_row_groups(list(range(first, last)), columns=columns).slice(a - starts[first], b - a)
        col = lambda name: table.column(name).to_numpy().astype(np.float64, copy=False)   # noqa: E731
        o = np.stack([col(c) for c in PARQUET_COLUMNS[:3]], axis=1)
        d = np.stack([col(c) for c in PARQUET_COLUMNS[3:]], axis=1)
        return o, d, *(col(c) if c in self.parts else None for c in ("tmin", "tmax"))


def _check_arrays(path, shapes: dict) -> int:
    """The ray count of origins, directions, tmin, tmax of these shapes (name -> (shape, dtype))."""
    for name in ("origins", "directions"):
        if name not in shapes:
            raise RayFileError(f"has no array {name!r} (it needs origins and directions, and may have tmin and "
                               f"tmax)", path)
    n = shapes["origins"][0][0] if len(shapes["origins"][0]) else -1
    for name, (shape, dtype) in shapes.items():
        want = (n, 3) if name in ("origins", "directions") else (n,)
        if tuple(shape) != want:
            raise RayFileError(f"{name} must have shape {want if n >= 0 else '(N, 3)'}, got {tuple(shape)}", path)
        _real(dtype, name, path)
    return n


def open_rays(path) -> RaySource:
    """The rays of `path`, its arrays' shapes and dtypes checked (RayFileError names what is wrong)."""
    p = Path(path).absolute()
    suffix = p.suffix.lower()
    if not p.exists():
        raise RayFileError("no such file or folder", path)
    names = ("origins", "directions", "tmin", "tmax")
    if suffix == ".npy":
        with open(p, "rb") as f:
            shape, dtype = _npy_header(f, path, "the array")
            offset = f.tell()
        if len(shape) != 2 or shape[1] != 6:
            raise RayFileError(f"must have shape (N, 6) (origin, direction), got {shape}", path)
        _real(dtype, "the array", path)
        return RaySource(path, "npy", shape[0], {"rays": _Npy(p, offset, shape, dtype)})
    if suffix == ".npz":
        try:
            with zipfile.ZipFile(p) as zf:
                parts = {n: m for n in names if (m := _npz_member(p, zf, n, path)) is not None}
        except zipfile.BadZipFile:
            raise RayFileError("is not a .npz file", path) from None
        n = _check_arrays(path, {k: (m.shape, m.dtype) for k, m in parts.items()})
        return RaySource(path, "npz", n, parts)
    if suffix == ".zarr":
        zarr = _needs("zarr")
        try:
            group = zarr.open_group(p, mode="r")
        except Exception as e:      # noqa: BLE001 (zarr's errors vary by version and store)
            raise RayFileError(f"is not a zarr group ({type(e).__name__}: {e})", path) from None
        shapes = {n: (group[n].shape, group[n].dtype) for n in names if n in group}
        n = _check_arrays(path, shapes)
        return RaySource(path, "zarr", n, dict.fromkeys(shapes))
    if suffix in (".parquet", ".pq"):
        pq = _needs("pyarrow.parquet")
        try:
            schema = pq.read_schema(p)
        except Exception as e:      # noqa: BLE001 (pyarrow's errors: ArrowInvalid, OSError)
            raise RayFileError(f"is not a Parquet file ({e})", path) from None
        missing = [c for c in PARQUET_COLUMNS if c not in schema.names]
        if missing:
            raise RayFileError(f"has no column {', '.join(missing)} (it needs {', '.join(PARQUET_COLUMNS)}, and may "
                               f"have tmin and tmax)", path)
        columns = [c for c in (*PARQUET_COLUMNS, "tmin", "tmax") if c in schema.names]
        for c in columns:
            _real(np.dtype(schema.field(c).type.to_pandas_dtype()), f"column {c}", path)
        return RaySource(path, "parquet", pq.ParquetFile(p).metadata.num_rows, dict.fromkeys(columns))
    raise RayFileError(f"unknown ray file type {suffix or '(no suffix)'!r}: use .npz (origins, directions), .npy "
                       f"(N, 6), .zarr or .parquet (ox, oy, oz, dx, dy, dz)", path)


# ----------------------------------------------------------------- results

def result_format(path) -> str:
    """"zarr" or "parquet" by the suffix of `path`, else OptionError."""
    suffix = Path(path).suffix.lower()
    if suffix == ".zarr":
        return "zarr"
    if suffix in (".parquet", ".pq"):
        return "parquet"
    raise OptionError(f"--out {path}: results are written to a .zarr group or a .parquet folder, got "
                      f"{suffix or 'no suffix'}")


class ResultFile:
    """Chunks of results written into a zarr group or a Parquet folder (module docstring)."""

    def __init__(self, path, count: int, chunk: int, fields: dict):
        self.path, self.count, self.chunk, self.fields = str(path), count, chunk, fields   # name -> (dtype, columns)
        self.format = result_format(path)

    def rows(self, k: int) -> tuple[int, int]:
        return k * self.chunk, min(self.count, (k + 1) * self.chunk)

    @property
    def chunks(self) -> int:
        return -(-self.count // self.chunk)

    def _part(self, k: int) -> Path:
        return Path(self.path) / f"part-{k:06d}.parquet"

    def write(self, k: int, arrays: dict) -> None:
        """Chunk k's arrays (name -> array), each file of it written whole or not at all."""
        if self.format == "parquet":
            pa, pq = _needs("pyarrow"), _needs("pyarrow.parquet")
            columns = {}
            for name, value in arrays.items():
                flat = pa.array(value.reshape(-1))
                columns[name] = flat if value.ndim == 1 else pa.FixedSizeListArray.from_arrays(flat, value.shape[1])
            with atomic_write(self._part(k), "wb") as f:
                pq.write_table(pa.table(columns), f)
            return
        zarr = _needs("zarr")
        a, b = self.rows(k)
        with zarr.config.set({"array.write_empty_chunks": True}):    # a chunk of misses is a chunk, too
            for name, value in arrays.items():
                self._array(name)[a:b] = value

    def prepare(self) -> None:
        """Import the format's library and open the arrays now (a worker's warm-up), not at the first chunk."""
        if self.format == "parquet":
            _needs("pyarrow"), _needs("pyarrow.parquet")
        else:
            for name in self.fields:
                self._array(name)

    def _array(self, name: str):
        """The zarr array of a field, opened once in this process (not pickled with this object)."""
        opened = self.__dict__.setdefault("_opened", {})
        if name not in opened:
            opened[name] = _needs("zarr").open_array(self.path, path=name, mode="r+")
        return opened[name]

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k != "_opened"}

    def _chunk_files(self, k: int) -> list[Path]:
        if self.format == "parquet":
            return [self._part(k)]
        return [Path(self.path) / name / ("c/" + "/".join([str(k)] + ["0"] * len(columns)))
                for name, (_, columns) in self.fields.items()]

    def done(self) -> set:
        """The chunks written whole (every field's file there)."""
        return {k for k in range(self.chunks) if all(f.exists() for f in self._chunk_files(k))}

    def remove_after(self, k: int) -> None:
        """Remove the chunks past chunk k (after a bad chunk: nothing is left past the last good one)."""
        for j in range(k + 1, self.chunks):
            for f in self._chunk_files(j):
                f.unlink(missing_ok=True)

    def tidy(self) -> None:
        """Remove the temporary files of writes a killed process left, and the chunks past a bad one
        that tasks still at work when it was found wrote after all (stop())."""
        for pattern in ("**/*.partial", ".part-*.tmp"):
            for f in Path(self.path).glob(pattern):
                f.unlink(missing_ok=True)
        marker = Path(self.path) / STOP
        if marker.exists():
            text = marker.read_text().strip()
            if text.isdigit():
                self.remove_after(int(text))
            marker.unlink()

    def stop(self, after: int | None = None) -> None:
        """Tell the chunks at work elsewhere (Dask tasks) to stop unwritten; with `after`, also remove
        the chunks past that one (now, and again at the next tidy())."""
        with atomic_write(Path(self.path) / STOP) as f:
            f.write("" if after is None else str(after))
        if after is not None:
            self.remove_after(after)

    def is_set(self) -> bool:
        """Whether stop() was called: a task checks between kernel calls and before writing."""
        return (Path(self.path) / STOP).exists()


def recorded(path) -> dict | None:
    """What made the results at `path` (open_results' `about`), or None where there are none."""
    p = Path(path)
    if not p.is_dir():
        return None
    if result_format(path) == "parquet":
        record = p / "_cast.json"
        return json.loads(record.read_text()) if record.exists() else None
    try:
        return _needs("zarr").open_group(p, mode="r").attrs.get(ABOUT)
    except Exception:       # noqa: BLE001 (not a zarr group)
        return None


def open_results(path, count: int, chunk: int, fields: dict, about: dict) -> ResultFile:
    """A ResultFile at `path` for `count` rays in chunks of `chunk`, with `fields` (name -> (dtype,
    columns)): made new, or an existing one made by the same cast (`about`) to resume; OptionError
    if it holds another's."""
    out = ResultFile(Path(path).absolute(), count, chunk, fields)     # written at that path by every worker
    p = Path(path)
    if not p.is_dir():
        check_output_directory(p)       # its folder exists, and it is no file
    about = json.loads(json.dumps(about))       # as it reads back
    found = recorded(path)
    if found is not None:
        _same(path, found, about)
        return out
    if out.format == "parquet":
        record = p / "_cast.json"
        if p.exists() and any(p.iterdir()):
            raise OptionError(f"--out {path}: the folder exists and holds no cast's results; remove it or choose "
                              f"another")
        p.mkdir(exist_ok=True)
        with atomic_write(record) as f:
            f.write(json.dumps(about, indent=1, sort_keys=True))
        return out
    zarr = _needs("zarr")
    unfinished = (p / "zarr.json").exists() and not any(p.glob("*/c"))     # made, its record not yet written
    if p.exists() and any(p.iterdir()) and not unfinished:
        raise OptionError(f"--out {path}: it exists and holds no cast's results; remove it or choose another")
    group = zarr.open_group(p, mode="w")
    for name, (dtype, columns) in fields.items():
        fill = np.nan if np.issubdtype(dtype, np.floating) else -1
        group.create_array(name, shape=(count,) + columns, chunks=(chunk,) + columns, dtype=dtype, fill_value=fill,
                           compressors=None)
    group.attrs[ABOUT] = about      # last: a group without it was not made whole
    return out


def _same(path, found: dict, about: dict) -> None:
    differ = sorted(k for k in set(found) | set(about) if found.get(k) != about.get(k))
    if differ:
        raise OptionError(f"--out {path} holds the results of another cast (its {', '.join(differ)} differ); remove "
                          f"it to start again, or choose another --out")
