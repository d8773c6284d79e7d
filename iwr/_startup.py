"""Ctrl-C during the start-up of the ``iwr`` and ``iwr-calibrate`` commands: one line, status 130.

Their console scripts import ``iwr`` (NumPy, SciPy, the compiled module: a few tenths of a second)
before the command's ``main`` and its handler of ``KeyboardInterrupt`` run, so a Ctrl-C there
printed a Python traceback (or, when it fell in the compiled module's initialisation, "the
compiled module iwr._core is missing"). ``iwr/__init__.py`` imports this module first: when the
process is one of these commands (``sys.argv[0]``, or ``python -m iwr``), SIGINT ends it at once
with ``PROG: interrupted`` and exit status 130 until the command's ``main`` takes over
(:func:`release`). A program that imports iwr keeps Python's ``KeyboardInterrupt``; a SIGINT
ignored at start (a background job, ``nohup``) stays ignored.

From :func:`release` on, SIGINT raises :class:`Interrupted`, a ``KeyboardInterrupt`` that the
command's ``main`` catches (one line, status 130), and not Python's own ``KeyboardInterrupt``.
The reason is CPython's exit: when a ``KeyboardInterrupt`` of exactly that type ends a string
``exec``/``eval`` (``collections.namedtuple`` and ``dataclasses`` run one per class they make, and
the commands import SciPy and Matplotlib lazily, after :func:`release`), CPython records it as
unhandled (``run_eval_code_obj`` in ``Python/pythonrun.c``) even though a caller catches it, and
``python -m`` (``Py_RunMain``) then ends the process by SIGINT instead of with the status ``main``
returned: ``iwr: interrupted`` and exit -2 rather than 130, seen under load. The check is on the
exact type (bpo-41602, gh-128130), so a subclass is never recorded. (The installed scripts exit
through ``Py_Exit`` and never read the record.)

Before Python has set its own handler (the first milliseconds of the interpreter's start) SIGINT
kills the process as it does any program: no message, and a shell says status 130.
"""

from __future__ import annotations

# _signal, the C module under signal: importing signal imports enum, and the guard should be in
# place as early as it can.
import _signal
import os
import sys

COMMANDS = ("iwr", "iwr-calibrate")


def _command() -> str | None:
    argv = getattr(sys, "argv", None)
    if not argv or not argv[0]:
        return None
    name = os.path.basename(argv[0]).removesuffix(".exe")
    if name in COMMANDS:
        return name
    # python -m iwr: while runpy imports the package, argv[0] is "-m"
    orig = list(getattr(sys, "orig_argv", []))
    if argv[0] == "-m" and any(a == "-m" and b in ("iwr", "iwr.__main__")
                               for a, b in zip(orig, orig[1:], strict=False)):
        return "iwr"
    return None


def command_kernel() -> None:
    """The commands' check of IWR_KERNEL, the objective's SIMD variant, which ``import iwr``
    applied where it could: raises ValueError naming the variable and its value. Unset or auto,
    nothing changes (a variant chosen in this process, as the tests do, stays)."""
    from . import _core

    if _core._kernel_environment_prefix():  # IWR_KERNEL names a variant (the rule: in C++)
        _core._select_kernel_from_environment()


class Interrupted(KeyboardInterrupt):
    """Ctrl-C in one of the commands, after their ``main`` took over (see the module's notes)."""


def _keyboard_interrupt(signum: int, frame: object) -> None:
    raise Interrupted


def interrupted_by(exc: BaseException) -> bool:
    """Whether ``exc`` is, or was raised while handling or because of, a ``KeyboardInterrupt``.

    A Ctrl-C that lands in an extension module's initialisation reaches the command as the
    module's ``ImportError`` (pybind11's ``initialization failed``, the ``KeyboardInterrupt`` its
    cause): SciPy and Matplotlib import some lazily, after :func:`release`. The commands report
    it as the interruption it is (one line, status 130), not as an internal error (status 1)."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _interrupted(signum: int, frame: object) -> None:
    try:
        os.write(2, f"\n{_command() or 'iwr'}: interrupted\n".encode())
    finally:
        os._exit(130)  # nothing to save yet; no exception through half-done imports


def guard() -> None:
    """SIGINT ends the process with one line and status 130, when it is one of the commands and
    SIGINT has Python's default handler (so neither ignored nor set by the program)."""
    if _command() is None or _signal.getsignal(_signal.SIGINT) is not _signal.default_int_handler:
        return
    try:
        _signal.signal(_signal.SIGINT, _interrupted)
    except ValueError:  # not the main thread: leave Python's handler
        pass


def release() -> None:
    """The command's ``main`` takes over, if :func:`guard` set the handler: SIGINT raises
    :class:`Interrupted`, a ``KeyboardInterrupt``, which ``main`` catches."""
    if _signal.getsignal(_signal.SIGINT) is _interrupted:
        _signal.signal(_signal.SIGINT, _keyboard_interrupt)


guard()
