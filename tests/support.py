"""What several test modules share: the reference SPD files, small scenes, random rays.

    from support import SPD_DIR          # the SPD programs' NFF files, unpacked from tests/data/spd
    from support import make_scene, add_sphere, ray_counts, work_counts
"""

from __future__ import annotations

import gzip
import hashlib
import os
import tempfile
from pathlib import Path

DATA = Path(__file__).resolve().parent / "data"


def _unpacked(folder: Path) -> Path:
    """The .gz files of `folder` unpacked into a folder of the system's temporary directory named
    by their contents, made once (atomically, for test processes running side by side)."""
    packed = sorted(folder.glob("*.gz"))
    digest = hashlib.sha256(b"".join(p.name.encode() + p.read_bytes() for p in packed)).hexdigest()[:16]
    target = Path(tempfile.gettempdir()) / f"raykernel-tests-{folder.name}-{digest}"
    if target.is_dir():
        return target
    staging = Path(tempfile.mkdtemp(prefix=target.name + ".", dir=target.parent))
    for p in packed:
        (staging / p.stem).write_bytes(gzip.decompress(p.read_bytes()))
    try:
        os.rename(staging, target)
    except OSError:         # another process made it first
        for f in staging.iterdir():
            f.unlink()
        staging.rmdir()
    return target


# Every NFF file the SPD programs wrote at size factor 1 and at their default size (and teapot at 2
# and 12, jacks at 4): tests/data/spd/README.md says where they come from.
SPD_DIR = _unpacked(DATA / "spd")
