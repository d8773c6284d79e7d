"""Atomic file writes: a temporary file in the same folder, flushed and synced, then renamed; and
the conversion of results to JSON-ready values."""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any


def _default_mode() -> int:
    # mkstemp creates files readable by their owner only; give new files the mode that open()
    # would (0o666 less the umask). The umask can only be read by setting it: done once, at import.
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


_NEW_FILE_MODE = _default_mode()


def atomic_write(
    path: str | os.PathLike[str], write: Callable[[IO[Any]], Any], binary: bool = False
) -> None:
    """Write ``path`` through ``write(fh)`` so that a crash never leaves a half-written file."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise FileNotFoundError(f"{path}: folder {directory} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        if binary:
            fh = os.fdopen(fd, "wb")
        else:
            fh = os.fdopen(fd, "w", encoding="utf-8", newline="")
        with fh:
            write(fh)
            fh.flush()
            if hasattr(os, "fchmod"):
                try:  # keep the mode of the file replaced, else the usual mode of a new file
                    mode = path.stat().st_mode & 0o7777
                except OSError:
                    mode = _NEW_FILE_MODE
                os.fchmod(fh.fileno(), mode)
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` atomically."""
    atomic_write(path, lambda fh: fh.write(text))


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    atomic_write(path, lambda fh: fh.write(data), binary=True)


def jsonable(value: Any, *, finite_only: bool = False) -> Any:
    """``value`` with NumPy arrays, scalars and tuples turned into JSON-ready Python values
    (dict keys become strings; anything else unknown becomes its repr). ``finite_only``: NaN and
    infinities become None (strict JSON); otherwise they stay floats, which :mod:`json` writes as
    NaN and Infinity and reads back."""
    import numpy as np

    if isinstance(value, dict):
        return {str(k): jsonable(v, finite_only=finite_only) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v, finite_only=finite_only) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist(), finite_only=finite_only)
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return None if finite_only and not math.isfinite(v) else v
    if isinstance(value, str) or value is None:
        return value
    return repr(value)
