"""Atomic file writes: a temporary file in the same folder, flushed and synced, then renamed; and
the conversion of results to JSON-ready values."""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable, Iterable
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
    _remove_dead_temporaries(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp",
                                   dir=directory)
    except OSError as exc:
        raise _named(exc, path) from None
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
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError):  # a full disk, a file-size limit: say which file
            raise _named(exc, path) from None
        raise


def _remove_dead_temporaries(path: Path) -> None:
    """Remove the temporary files of :func:`atomic_write` to ``path`` that a killed process left
    (``.NAME.PID.XXXX.tmp``, PID no longer running)."""
    import glob

    prefix = f".{path.name}."
    for entry in path.parent.glob(glob.escape(prefix) + "*.tmp"):
        try:
            pid = int(entry.name[len(prefix):].split(".", 1)[0])
            os.kill(pid, 0)
        except ProcessLookupError:
            try:
                entry.unlink()
            except OSError:
                pass
        except (ValueError, PermissionError, OSError):
            pass  # not ours, or another user's live process


def _named(exc: OSError, path: Path) -> OSError:
    """``exc`` naming ``path`` (a full disk's error names no file)."""
    if exc.filename is not None and str(exc.filename) == str(path):
        return exc
    if exc.errno is None:
        return type(exc)(f"cannot write {path}: {exc}")
    return type(exc)(exc.errno, f"cannot write {path}: {exc.strerror or exc}")


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


#: The file a folder written as a whole (:func:`write_folder`) holds while its files are being
#: moved in: if it remains, the writer was killed and the folder may mix two runs.
INCOMPLETE_MARKER = "INCOMPLETE.txt"


def write_folder(out: str | os.PathLike[str], write: Callable[[Path], list[Path]],
                 owned: Iterable[str] = ()) -> list[Path]:
    """Write a run's files into folder ``out`` as a whole: ``write(tmp)`` writes them into a
    temporary folder inside ``out`` (the slow part: nothing in ``out`` changes meanwhile), then
    they are moved in by renames, with :data:`INCOMPLETE_MARKER` in ``out`` until the last one is
    in; the files in ``owned`` (names a run may write) that this run did not write are removed, so
    that the folder never mixes two runs. Returns the paths in ``out``. Any other file in ``out``
    is left alone (the folder may be the user's, e.g. ``.``)."""
    import shutil

    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        _remove_dead_writers(out)
        tmp = Path(tempfile.mkdtemp(prefix=f".iwr-writing-{os.getpid()}-", dir=out))
    except OSError as exc:
        raise OSError(exc.errno, f"{out}: cannot create the output folder: "
                                 f"{exc.strerror or exc}") from None
    marker = out / INCOMPLETE_MARKER
    try:
        try:
            written = write(tmp)
        except OSError as exc:
            raise OSError(exc.errno, f"{out}: cannot write the output: {exc.strerror or exc}"
                                     + (f" ({Path(exc.filename).name})" if exc.filename else "")
                          ) from None
        names = [Path(p).name for p in written]
        atomic_write_text(marker, f"iwr was writing this folder (process {os.getpid()}): if this "
                                  "file remains, it was stopped part way and the files here may "
                                  "be from two runs. Run it again.\n")
        for name in names:
            os.replace(tmp / name, out / name)
        for name in set(owned) - set(names):
            try:
                os.unlink(out / name)
            except FileNotFoundError:
                pass
        os.unlink(marker)
        return [out / name for name in names]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _remove_dead_writers(out: Path) -> None:
    """Remove the temporary folders of :func:`write_folder` that a killed process left in
    ``out`` (named ``.iwr-writing-PID-...``, PID no longer running)."""
    import shutil

    for entry in out.glob(".iwr-writing-*-*"):
        try:
            pid = int(entry.name.split("-")[2])
            os.kill(pid, 0)
        except ProcessLookupError:
            shutil.rmtree(entry, ignore_errors=True)
        except (ValueError, IndexError, PermissionError):
            pass  # not ours, or another user's live process


class NotRegularFileError(OSError):
    """An input that is not a regular file (a named pipe, a device, a socket): refused before it
    is read, for a read from it could block for ever or never end."""


def open_regular(path: str | os.PathLike[str]) -> IO[bytes]:
    """``path`` opened for binary reading, without blocking on a named pipe; a folder raises
    :class:`IsADirectoryError`, anything else that is not a regular file
    :class:`NotRegularFileError` (its message says what it is)."""
    import stat

    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    handed = False
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(21, "Is a directory", str(path))
        if not stat.S_ISREG(mode):
            kind = ("a named pipe (FIFO)" if stat.S_ISFIFO(mode) else
                    "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else
                    "a socket" if stat.S_ISSOCK(mode) else "not a file")
            raise NotRegularFileError(f"{path}: {kind}, not a regular file; give the file itself")
        os.set_blocking(fd, True)
        # From here the file object owns fd: if its construction fails (a Ctrl-C inside it), it
        # has closed fd itself, and closing it again here would turn the KeyboardInterrupt into
        # "Bad file descriptor" (or close a descriptor that another open has since been given).
        handed = True
        return os.fdopen(fd, "rb")
    except BaseException:
        if not handed:
            os.close(fd)
        raise


def available_memory() -> int:
    """The memory available to new allocations (bytes), as iwr-engine reckons it
    (``io::available_memory``): ``MemAvailable`` of /proc/meminfo (else the physical pages
    available), capped by a container's limit (cgroup v2) less its use and by the process's
    address-space limit (``ulimit -v``); 0 if unknown."""
    import resource

    def number(path: str) -> int:
        try:
            with open(path, encoding="ascii") as fh:
                return int(fh.read().split()[0])
        except (OSError, ValueError, IndexError):
            return 0  # absent, or "max"

    avail = 0
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if avail == 0:
        try:
            avail = max(0, int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGESIZE")))
        except (ValueError, OSError, AttributeError):
            pass
    caps = []
    limit = number("/sys/fs/cgroup/memory.max")
    if limit > 0:
        caps.append(max(1, limit - number("/sys/fs/cgroup/memory.current")))
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY and soft > 0:
        caps.append(soft)
    for cap in caps:
        if avail == 0 or cap < avail:
            avail = cap
    return avail
