"""A built RayScene in one file that the processes of a machine map, instead of a copy each.

    with SharedScene.write(rs) as shared:     # the scene's arrays written once (a temporary file)
        future = client.submit(..., shared)   # pickles to a few kilobytes: a path and where each array lies
    rs = shared.open()                        # in each process of this machine: the same RayScene, mapped

Why: the worker processes of a local cluster (`raykernel cast --dask local:N`) each held the copy
of the built scene Dask sent them: N copies of the same arrays in memory and in the processor's
shared cache, where one mapped file holds one (the page cache's), and the walks of N workers read
the same pages (bench/cast.py: local:2 against local:1).

The file holds the scene pickled (protocol 5) with its arrays out of band, each aligned to 64
bytes. `open` maps the file copy-on-write: the arrays are writable numpy arrays of the file's
pages, typed by numba as before (the kernels load from the cache), shared until a process writes
one, and such a write stays that process's own. The file is deleted when the `with` block ends;
the processes that mapped it keep their mappings.
"""

from __future__ import annotations

import mmap
import os
import pickle
import secrets
import tempfile
from dataclasses import dataclass
from pathlib import Path

ALIGN = 64              # bytes: an array's start, a cache line (numba's aligned arrays, the wide nodes' records)
MAGIC = b"raykernel shared scene\n"


class SharedSceneError(RuntimeError):
    """The file of a SharedScene is not there, or is not the one written (another machine's path)."""


@dataclass(frozen=True)
class SharedScene:
    """Where a RayScene lies in its file: what a process of this machine needs to map it."""

    path: str
    token: bytes                # written at the file's start: `open` checks it is this file
    spans: tuple                # (offset, bytes) of each array's data
    inband: tuple               # (offset, bytes) of the pickle itself

    @classmethod
    def write(cls, rs, folder=None) -> "SharedScene":
        """Write `rs` to a new file in `folder` (default: the temporary folder) and return its handle,
        a context manager that deletes the file on exit. (Only this handle names the file, so no
        process can open it before it is whole.)"""
        buffers = []
        inband = pickle.dumps(rs, protocol=5, buffer_callback=buffers.append)
        token = secrets.token_bytes(16)
        fd, path = tempfile.mkstemp(prefix="raykernel-scene-", dir=folder)
        spans = []
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(MAGIC + token)
                for buffer in buffers:
                    raw = buffer.raw()
                    f.write(b"\0" * (-f.tell() % ALIGN))
                    spans.append((f.tell(), raw.nbytes))
                    f.write(raw)
                where = (f.tell(), len(inband))
                f.write(inband)
        except BaseException:
            Path(path).unlink(missing_ok=True)
            raise
        return cls(path, token, tuple(spans), where)

    def open(self):
        """The RayScene, its arrays mapped from the file (copy-on-write).

        Raises
        ------
        SharedSceneError
            The file is gone or is another one (a process of another machine).
        """
        try:
            with open(self.path, "rb") as f:
                if f.read(len(MAGIC) + len(self.token)) != MAGIC + self.token:
                    raise SharedSceneError(f"{self.path} is not the shared scene this handle names")
                mapped = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_COPY)
        except FileNotFoundError:
            raise SharedSceneError(f"the shared scene {self.path} is not on this machine, or was deleted "
                                   f"when its cast ended") from None
        view = memoryview(mapped)
        start, size = self.inband
        return pickle.loads(view[start:start + size], buffers=[view[a:a + n] for a, n in self.spans])

    @property
    def nbytes(self) -> int:
        """The bytes of the arrays in the file."""
        return sum(n for _, n in self.spans)

    def delete(self) -> None:
        """Remove the file (the processes that mapped it keep their mappings)."""
        Path(self.path).unlink(missing_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.delete()
