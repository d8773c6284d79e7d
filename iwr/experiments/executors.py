"""The executors of the experiment harness: a list of cells (:class:`iwr.experiments.harness.Cell`)
run in this process (:func:`run_in_process`) or on a Dask cluster (:func:`run_dask`), each
finished row handed to a callback; and :func:`dry_run`, the settings a method resolves from its
options before an experiment starts. ``iwr compare`` and ``iwr study`` run their grids here."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from .. import kinds
from ..noise import Noise
from ..robot import Robot
from ..simulation import simulate
from .harness import Cell, canonical, evaluate, registered_methods

__all__ = ["ExecutorError", "dry_run", "run_dask", "run_in_process"]

#: The robots of the cells a worker process evaluated, by their JSON (a few at most).
_ROBOTS: dict[str, Robot] = {}


def run_in_process(
    cells: Sequence[Cell], robot: Robot, on_done: Callable[[dict[str, Any]], None],
    runtime: Mapping[str, Any] | None = None, **evaluate_options: Any,
) -> list[tuple[Cell, BaseException]]:
    """Run the cells one after the other in this process (BLAS on one thread: the matrices are
    small and a busy machine makes its threads spin); ``on_done(row)`` after each. Returns the
    cells that failed on every attempt (none here: an unexpected error propagates)."""
    from .._blas import single_thread

    with single_thread():
        for cell in cells:
            on_done(evaluate(cell, robot, runtime, **evaluate_options))
    return []


def evaluate_json(cell: Cell, robot_json: str, runtime: Mapping[str, Any],
                  evaluate_options: Mapping[str, Any]) -> dict[str, Any]:
    """:func:`evaluate` with the robot as canonical JSON: what a Dask worker runs."""
    return evaluate(cell, _robot_from_json(robot_json), runtime, **evaluate_options)


def _robot_from_json(text: str) -> Robot:
    robot = _ROBOTS.get(text)
    if robot is None:
        if len(_ROBOTS) > 4:
            _ROBOTS.clear()
        robot = _ROBOTS[text] = Robot.from_dict(json.loads(text))
    return robot


class ExecutorError(RuntimeError):
    """An executor could not run: no Dask, or no scheduler at the address given."""


#: Seconds to wait for a Dask scheduler to answer (connection and handshake), and for the
#: cluster's shutdown: a study never waits on the network without end.
CONNECT_TIMEOUT = 20.0


#: Seconds between checks that the scheduler is still there while cells run; a cell itself may
#: take as long as it needs.
HEARTBEAT = 10.0


_DASK_HINT = ("pip install 'iwr[study]' (in a checkout: pip install '.[study]'), or run with "
              "scheduler='synchronous'")


def run_dask(
    cells: Sequence[Cell], robot: Robot, on_done: Callable[[dict[str, Any]], None],
    runtime: Mapping[str, Any] | None = None, *, scheduler: Any = None,
    workers: int | None = None, retries: int = 2, connect_timeout: float = CONNECT_TIMEOUT,
    **evaluate_options: Any,
) -> list[tuple[Cell, BaseException]]:
    """Run the cells on Dask distributed; ``on_done(row)`` in this process as each finishes, in
    the order they finish. ``scheduler``: None for a local cluster of ``workers`` processes (one
    thread each), an address (``"tcp://host:8786"``) or a ``distributed.Client``. A worker that
    dies loses only the cell it was running, which the scheduler runs again elsewhere, up to
    ``retries`` more times. Returns the cells that failed on every attempt, with their error.

    Raises :class:`ExecutorError` within ``connect_timeout`` seconds when nothing at the address
    answers as a Dask scheduler (a refused connection, a server of another kind, silence).
    """
    import os

    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ExecutorError(f"scheduler: Dask distributed is not installed; {_DASK_HINT}") from None
    import dask

    robot_json = canonical(robot.to_dict())
    runtime = dict(runtime or {})
    cluster = None
    # A worker that dies while running a cell makes the cell 'suspicious'; the scheduler runs it
    # again on another worker up to allowed-failures times (a local cluster's scheduler only: an
    # existing cluster keeps its own setting). `retries` covers exceptions raised by a cell.
    # The comm timeouts bound every connection and handshake, also with a server that is not a
    # scheduler and never answers.
    config = {
        "distributed.scheduler.allowed-failures": max(retries, 0) + 1,
        "distributed.comm.timeouts.connect": f"{connect_timeout}s",
        "distributed.comm.timeouts.tcp": f"{max(connect_timeout, 3 * HEARTBEAT)}s",
    }
    with dask.config.set(config):
        try:
            if scheduler is None:
                n = workers if workers is not None else (os.cpu_count() or 1)
                cluster = LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                    timeout=connect_timeout,
                )
                client = Client(cluster, timeout=connect_timeout)
            elif isinstance(scheduler, Client):
                client = scheduler
            else:
                client = _connect(Client, scheduler, connect_timeout)
        except ExecutorError:
            raise
        except Exception as exc:  # noqa: BLE001 - whatever a broken peer makes Dask raise
            if cluster is not None:
                cluster.close(timeout=connect_timeout)
            raise ExecutorError(f"scheduler: cannot start a local Dask cluster: "
                                f"{type(exc).__name__}: {exc}") from None
        failures: list[tuple[Cell, BaseException]] = []
        try:
            futures = {}
            for cell in cells:
                # The robot travels with each cell (a few kB): nothing for a dying worker to lose.
                fut = client.submit(
                    evaluate_json, cell, robot_json, runtime, evaluate_options,
                    key=f"iwr-cell-{cell.key}", retries=retries, pure=False,
                )
                futures[fut] = cell
            try:
                for fut in as_completed(list(futures)):
                    try:
                        # No timeout: a finished cell whose result was lost with its worker
                        # (killed before this process fetched the row) is computed again
                        # elsewhere, and the wait for that is a cell's computation, which may
                        # take as long as it needs. A lost scheduler cancels the futures.
                        row = fut.result()
                    except Exception as exc:  # noqa: BLE001 - any failure of a cell is reported
                        failures.append((futures[fut], exc))
                    else:
                        on_done(row)
                    fut.release()
            except BaseException:
                client.cancel(list(futures))
                raise
        finally:
            if client is not scheduler:
                client.close(timeout=connect_timeout)
            if cluster is not None:
                cluster.close(timeout=connect_timeout)
    return failures


def _connect(client_class: Any, address: Any, timeout: float) -> Any:
    """A Client of the scheduler at ``address``, or ExecutorError within ``timeout`` seconds (plus
    a few for the client's own shutdown).

    The connection runs in a helper thread with a deadline: a server of another kind may accept
    the connection and then never send the handshake, or send bytes that Dask reads as a frame
    length (an HTTP server made it allocate exabytes).
    """
    import threading

    box: dict[str, Any] = {}

    def connect() -> None:
        try:
            box["client"] = client_class(address, timeout=timeout)
        except BaseException as exc:  # noqa: BLE001 - reported to the caller below
            box["error"] = exc

    thread = threading.Thread(target=connect, name="iwr-dask-connect", daemon=True)
    thread.start()
    thread.join(timeout + 5.0)
    what = (f"scheduler: {address!r} did not answer as a Dask scheduler within {timeout:g} s "
            "(is it the scheduler's address, tcp://HOST:8786?)")
    if thread.is_alive():
        raise ExecutorError(what)
    if "error" in box:
        exc = box["error"]
        detail = str(exc).splitlines()[0] if str(exc) else ""
        if isinstance(exc, (OSError, TimeoutError)) or "Timed out" in detail:
            raise ExecutorError(f"scheduler: cannot connect to {address!r}: {detail or what}")
        raise ExecutorError(f"scheduler: {address!r} is not a Dask scheduler (its answer made "
                            f"Dask fail: {type(exc).__name__}: {detail})")
    return box["client"]


def dry_run(robot: Robot, method: str, options: Mapping[str, Any]) -> dict[str, Any]:
    """The settings a method resolves from ``options`` (for DE: strategy, NP, F, CR, ...), from a
    run stopped before it searches (DE: its initial population alone; the others: stopped by their
    callback at the first evaluation) on a small noise-free problem, so that bad options fail before
    an experiment starts, by the method's own checks (the efficient estimator given the realistic
    noise model, in the robot's kind's form, unless ``options`` name one). ValueError or TypeError
    names a bad option. A method registered from outside the package is not run (``{}``): a call of
    it may have side effects (files written, its process ended); its options' values are checked
    when its cells run."""
    from ..methods import identify

    if registered_methods()[method].__module__.partition(".")[0] != "iwr":
        return {}
    data, _ = simulate(robot, 12, seed=0)
    stop: dict[str, Any] = ({"generations": 0} if method == "de" else
                            {"callback": lambda _: True})
    if method == "efficient" and "noise" not in options:  # as evaluate gives it, in the kind's form
        stop["noise"] = kinds.for_robot(robot).experiment_noise(robot, Noise.realistic())
    res = identify(robot, data, method, seed=0, progress=False, **{**options, **stop})
    return dict(res.settings)
