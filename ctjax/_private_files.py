"""Files that no other user can have written: the cache folders ctjax reads code from.

Whoever can write a kept program (`ctjax._programs`), or JAX's compiled programs beside it,
chooses the machine code a later process runs. So the cache folder, `programs/` and its
files are created for the user alone (0700, 0600). A folder that another user can write
(owned by another user, or group- or world-writable) is neither read nor written, and a
file that another user can write is not read (it is replaced), with one warning per
process (`enable_compilation_cache` leaves such a cache folder off altogether). Only the
folder and the file are checked: one that another user put in their place is theirs.
"""

import hashlib
import json
import os
import stat
import tempfile
import warnings
from pathlib import Path

_WARNED = [False]  # one warning per process for a cache others can write (module doc)


def _private(status: os.stat_result) -> bool:
    """Owned by this user, and writable by no other (neither group- nor world-writable)."""
    owner = not hasattr(os, "getuid") or status.st_uid == os.getuid()
    return owner and not status.st_mode & (stat.S_IWGRP | stat.S_IWOTH)


def _warn_unsafe(path: Path) -> None:
    if not _WARNED[0]:
        _WARNED[0] = True
        warnings.warn(
            f"ctjax: not using the cache at {path}: another user can write to it (it is not "
            "yours, or it is group- or world-writable), and whoever writes it chooses the "
            "code ctjax runs; make it yours alone (chmod go-w) or set CTJAX_CACHE_DIR to a "
            "folder of your own",
            RuntimeWarning,
            stacklevel=3,
        )


def private_folder(folder: Path) -> bool:
    """Whether `folder` is the user's alone, or missing (it is then created so); warns
    once per process otherwise (see the module doc)."""
    try:
        status = folder.stat()
    except FileNotFoundError:
        return True
    except OSError:
        return False
    if not _private(status):
        _warn_unsafe(folder)
        return False
    return True


def read_private(path: Path) -> bytes | None:
    """A program file's bytes; None where it is missing, or another user can write it."""
    try:
        # Not through a link; not blocking on a FIFO (checked below: a regular file only).
        descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return None  # missing: the usual miss
    with os.fdopen(descriptor, "rb") as file:
        status = os.fstat(file.fileno())  # the file opened, not whatever the path is now
        if not stat.S_ISREG(status.st_mode):
            return None
        if not _private(status):
            _warn_unsafe(path)
            return None
        return file.read()


def write_private(path: Path, blob: bytes) -> None:
    try:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        descriptor, temporary = tempfile.mkstemp(dir=path.parent, suffix=".tmp")  # 0600
    except OSError:
        return  # a read-only cache: keep the program for this process only
    try:
        with os.fdopen(descriptor, "wb") as file:
            file.write(blob)
        os.replace(temporary, path)  # atomic: concurrent processes never read half a file
    except OSError:
        Path(temporary).unlink(missing_ok=True)


def keyed_blob(magic: bytes, key: str, header: dict, payload: bytes) -> bytes:
    """A cache file's bytes: the line `magic` (the format and its version), one line of
    JSON (`header` with the key's digest and the sha256 of `payload`), then `payload`."""
    header = {"key": key, "sha256": hashlib.sha256(payload).hexdigest(), **header}
    return magic + json.dumps(header, separators=(",", ":")).encode() + b"\n" + payload


def read_keyed(blob: bytes, magic: bytes, key: str) -> tuple[dict, bytes]:
    """A cache file's header and payload (`keyed_blob`); raises `ValueError` where it is of
    another format, another key's (renamed) or damaged, before anything reads the payload."""
    if not blob.startswith(magic):
        raise ValueError("not a file of this format")
    line, _, payload = blob[len(magic) :].partition(b"\n")
    header = json.loads(line)
    if header["key"] != key or header["sha256"] != hashlib.sha256(payload).hexdigest():
        raise ValueError("another key's file, or a damaged one")
    return header, payload
