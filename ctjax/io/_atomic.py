"""Atomic file writes: a temporary file in the same folder, then `os.replace`.

An interrupted command leaves either the old file or the new one, never half of one. The
file gets the mode a plain `open` would give it (0666 less the umask: 0644 under umask
022), not `mkstemp`'s private 0600, so that a colleague or a web server can read results.
"""

import io
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from .._errors import CtjaxError


def _file_mode() -> int:
    """0666 less the process's umask (read without changing it for good)."""
    umask = os.umask(0o022)
    os.umask(umask)
    return 0o666 & ~umask


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    # The command line checks its outputs when it parses them (`output_file`); this is the
    # Python API's one line, instead of a traceback from `os.replace`.
    if path.is_dir():
        raise CtjaxError(f"{path}: is a directory")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise CtjaxError(f"{path}: {path.parent} is not a folder") from None
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, _file_mode())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_json(path: Path, obj) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=2, sort_keys=False) + "\n").encode())


def atomic_write_npy(path: Path, array: np.ndarray) -> None:
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    atomic_write_bytes(path, buffer.getvalue())
