"""ur_rtde in a worker process, so a lost link can never crash the process that uses it.

ur_rtde 1.6.5 aborts its process (``std::terminate``) when an interface whose socket
died is disconnected or destroyed, and its background threads (the control interface
reconnects by itself) keep running through interpreter shutdown, where they were seen to
crash the process (SIGSEGV). So the three interfaces live in one worker process of their
own, and the user's process holds thin proxies:

* :class:`RTDEWorker` starts the worker (``multiprocessing`` "spawn": the parent has
  threads, and a fork would copy them mid-flight) and forwards
  ``(interface, method, args)`` requests over a pipe. Each request carries an id; the
  worker serves each on its own thread, so a ``moveL`` that blocks forever on a dead link
  does not hold up the ``stopL`` sent after it. A reader thread in the parent hands each
  reply to the caller waiting for it.
* :class:`ControlProxy`, :class:`ReceiveProxy` and :class:`IOProxy` implement the
  driver's ports (plus ``disconnect``) by forwarding to the worker.
* A worker that ended (crash, killed) fails every pending and later call at once with
  :class:`WorkerEndedError`; an exception inside the worker comes back as a one-line
  :class:`RuntimeError`.
* Ending: :meth:`RTDEWorker.close` asks the worker to disconnect the interfaces and exit
  (links fine); :meth:`RTDEWorker.kill` ends it with SIGKILL (links in doubt): the
  operating system closes its sockets and no C++ teardown runs anywhere. The worker
  leaves with ``os._exit`` in every case, and also when the parent disappears (end of
  the pipe), so ur_rtde's destructors never run at interpreter shutdown.

This module imports only the standard library at import time, so the worker starts
without loading the rest of the project.
"""

from __future__ import annotations

import contextlib
import itertools
import multiprocessing
import os
import signal
import threading
from multiprocessing.connection import Connection
from typing import Any

INTERFACE_NAMES = ("control", "receive", "io")
"""The three ur_rtde interfaces, in the order ``connect`` returns them."""

STARTUP_TIMEOUT_S = 120.0
"""Longest wait for the worker to start and construct the three interfaces. ur_rtde has
its own timeouts (a refused connection fails at once; a control script that never
starts fails after 5 s); this only bounds a worker that hangs, on a slow machine too."""

CLOSE_TIMEOUT_S = 20.0
"""Longest wait for a worker asked to disconnect and exit (ur_rtde takes ~2 s to
disconnect the three interfaces); past it the worker is killed."""

KILL_TIMEOUT_S = 10.0
"""Longest wait for a killed worker to be reaped."""

_SPAWN = multiprocessing.get_context("spawn")


class WorkerEndedError(ConnectionError):
    """The ur_rtde worker process has ended: the call cannot reach the robot."""


class RTDEWorker:
    """One worker process holding the three ur_rtde interfaces to one robot.

    Constructing it starts the worker and waits until the interfaces are connected.

    Parameters
    ----------
    robot_ip
        Address of the robot (or of a fake controller).
    startup_timeout_s
        Longest wait for the interfaces to be constructed.

    Raises
    ------
    RuntimeError
        ur_rtde refused to connect (its message, one line), or the worker did not
        finish connecting within ``startup_timeout_s`` (it is killed).
    WorkerEndedError
        The worker ended while connecting.
    """

    def __init__(self, robot_ip: str, *, startup_timeout_s: float = STARTUP_TIMEOUT_S) -> None:
        self.robot_ip = robot_ip
        parent_end, worker_end = _SPAWN.Pipe()
        self._process = _SPAWN.Process(
            target=serve_interfaces,
            args=(worker_end, robot_ip),
            name=f"ur_rtde worker for {robot_ip}",
            # Daemonic: if the user never closes the picker, multiprocessing ends the
            # worker at interpreter exit (SIGTERM, no C++ teardown) instead of waiting.
            daemon=True,
        )
        self._process.start()
        # Only the worker may hold its end, or its death would never read as EOF here.
        worker_end.close()
        self._connection = parent_end
        self._send_lock = threading.Lock()
        self._state_lock = threading.Lock()
        self._pending: dict[int, _PendingCall] = {}
        self._call_ids = itertools.count()
        self._ended = False
        self._ended_event = threading.Event()
        self._await_startup(startup_timeout_s)
        self._reader = threading.Thread(
            target=self._read_replies, name=f"ur_rtde replies from {self.pid}", daemon=True
        )
        self._reader.start()

    @property
    def pid(self) -> int:
        """The worker's process id."""
        assert self._process.pid is not None
        return self._process.pid

    @property
    def exitcode(self) -> int | None:
        """The worker's exit status once it has been reaped (0 after :meth:`close`,
        ``-SIGKILL`` after :meth:`kill`); None while it runs."""
        return self._process.exitcode

    @property
    def ended(self) -> bool:
        """Whether the worker can no longer serve calls (it exited, or its pipe closed)."""
        with self._state_lock:
            return self._ended

    def wait_ended(self, timeout_s: float | None = None) -> bool:
        """Block until the worker has ended (its pipe closed); False when ``timeout_s`` passed."""
        return self._ended_event.wait(timeout_s)

    def proxies(self) -> tuple[ControlProxy, ReceiveProxy, IOProxy]:
        """The ``(control, receive, io)`` proxies forwarding to this worker."""
        return ControlProxy(self), ReceiveProxy(self), IOProxy(self)

    def call(self, interface: str, method: str, *args: Any) -> Any:
        """Call ``method(*args)`` on one of the worker's interfaces and return its result.

        Blocks until the worker replies, however long the call takes inside ur_rtde (the
        picker bounds its blocking commands with its own deadlines); other threads can
        call meanwhile.

        Raises
        ------
        RuntimeError
            The call raised inside the worker (the type and message, one line).
        WorkerEndedError
            The worker has ended, before or during the call.
        """
        pending = _PendingCall()
        with self._state_lock:
            if self._ended:
                raise WorkerEndedError(self._ended_message())
            call_id = next(self._call_ids)
            self._pending[call_id] = pending
        try:
            with self._send_lock:
                self._connection.send(("call", call_id, interface, method, args))
        except (OSError, ValueError):  # the worker's end is gone (ValueError: closed here)
            self._end()
        return pending.result()

    def close(self, timeout_s: float = CLOSE_TIMEOUT_S) -> None:
        """Ask the worker to disconnect the interfaces and exit; kill it past ``timeout_s``.

        For links known to be fine: with a dead socket ur_rtde's ``disconnect`` aborts
        the worker (harmless to this process, but use :meth:`kill` then). Calls still
        pending (one abandoned inside ur_rtde) fail with :class:`WorkerEndedError`.
        Closing an ended worker only reaps it.
        """
        if not self.ended:
            with contextlib.suppress(OSError, ValueError), self._send_lock:
                self._connection.send(("exit",))
        self._process.join(timeout_s)
        if self._process.exitcode is None:
            self.kill()
        else:
            self._wait_for_reader()

    def kill(self) -> None:
        """End the worker with SIGKILL and reap it; no disconnect or destructor runs.

        For links in doubt: the operating system closes the worker's sockets, and
        nothing in ur_rtde gets the chance to write to them.
        """
        self._process.kill()
        self._process.join(KILL_TIMEOUT_S)
        self._wait_for_reader()

    def _await_startup(self, timeout_s: float) -> None:
        """Wait for the worker's first message: connected, or ur_rtde's error."""
        try:
            if not self._connection.poll(timeout_s):
                self._process.kill()
                self._process.join(KILL_TIMEOUT_S)
                raise RuntimeError(
                    f"the ur_rtde worker did not connect to {self.robot_ip} within "
                    f"{timeout_s:.0f} s (killed)"
                )
            status, detail = self._connection.recv()
        except (EOFError, OSError) as error:
            self._process.join(KILL_TIMEOUT_S)
            self._connection.close()
            raise WorkerEndedError(
                f"the ur_rtde worker process (pid {self.pid}) ended while connecting to "
                f"{self.robot_ip} (exit code {self._process.exitcode})"
            ) from error
        except BaseException:
            self._connection.close()
            raise
        if status != "ready":
            # The worker leaves on its own after reporting the error.
            self._process.join(KILL_TIMEOUT_S)
            if self._process.exitcode is None:
                self._process.kill()
                self._process.join(KILL_TIMEOUT_S)
            self._connection.close()
            raise RuntimeError(detail)

    def _read_replies(self) -> None:
        """Hand each reply to its waiting caller until the worker's end of the pipe closes."""
        while True:
            try:
                call_id, succeeded, value = self._connection.recv()
            except (EOFError, OSError):
                break
            with self._state_lock:
                pending = self._pending.pop(call_id, None)
            if pending is not None:
                pending.settle(succeeded, value)
        self._end()
        self._connection.close()

    def _end(self) -> None:
        """Mark the worker ended and fail every pending call."""
        with self._state_lock:
            self._ended = True
            pending, self._pending = list(self._pending.values()), {}
        self._ended_event.set()
        message = self._ended_message()
        for call in pending:
            call.fail(WorkerEndedError(message))

    def _ended_message(self) -> str:
        return (
            f"the ur_rtde worker process (pid {self.pid}) for {self.robot_ip} has ended; "
            "the robot cannot be reached through it"
        )

    def _wait_for_reader(self) -> None:
        # The reader sees the end of the pipe once the worker is gone; waiting for it
        # means no thread of this worker outlives close() or kill().
        self._reader.join(KILL_TIMEOUT_S)


class _PendingCall:
    """One call waiting for its reply: the value, the worker's error, or the worker's end."""

    def __init__(self) -> None:
        self._settled = threading.Event()
        self._value: Any = None
        self._error: Exception | None = None

    def settle(self, succeeded: bool, value: Any) -> None:
        if succeeded:
            self._value = value
        else:
            self._error = RuntimeError(value)
        self._settled.set()

    def fail(self, error: Exception) -> None:
        self._error = error
        self._settled.set()

    def result(self) -> Any:
        self._settled.wait()
        if self._error is not None:
            raise self._error
        return self._value


class _InterfaceProxy:
    """Forwards calls to one interface of a :class:`RTDEWorker`."""

    interface = ""
    """``"control"``, ``"receive"`` or ``"io"``."""

    def __init__(self, worker: RTDEWorker) -> None:
        self.worker = worker

    def _call(self, method: str, *args: Any) -> Any:
        return self.worker.call(self.interface, method, *args)

    def isConnected(self) -> bool:
        return self._call("isConnected")

    def reconnect(self) -> bool:
        return self._call("reconnect")

    def disconnect(self) -> None:
        self._call("disconnect")

    def __repr__(self) -> str:
        return f"<{type(self).__name__} of worker pid {self.worker.pid}>"


class ControlProxy(_InterfaceProxy):
    """``RTDEControlInterface`` in the worker (the driver's ``ControlPort``)."""

    interface = "control"

    def moveL(
        self, pose: list[float], speed: float, acceleration: float, asynchronous: bool = False
    ) -> bool:
        return self._call("moveL", list(pose), speed, acceleration, asynchronous)

    def stopL(self, a: float = 10.0, asynchronous: bool = False) -> None:
        self._call("stopL", a, asynchronous)

    def isPoseWithinSafetyLimits(self, pose: list[float]) -> bool:
        return self._call("isPoseWithinSafetyLimits", list(pose))

    def isProgramRunning(self) -> bool:
        return self._call("isProgramRunning")


class ReceiveProxy(_InterfaceProxy):
    """``RTDEReceiveInterface`` in the worker (the driver's ``ReceivePort``)."""

    interface = "receive"

    def getActualTCPPose(self) -> list[float]:
        return self._call("getActualTCPPose")

    def isProtectiveStopped(self) -> bool:
        return self._call("isProtectiveStopped")

    def isEmergencyStopped(self) -> bool:
        return self._call("isEmergencyStopped")

    def getSafetyMode(self) -> int:
        return self._call("getSafetyMode")


class IOProxy(_InterfaceProxy):
    """``RTDEIOInterface`` in the worker (the driver's ``IOPort``)."""

    interface = "io"

    def setToolDigitalOut(self, output_id: int, level: bool) -> bool:
        return self._call("setToolDigitalOut", output_id, level)

    def setStandardDigitalOut(self, output_id: int, level: bool) -> bool:
        return self._call("setStandardDigitalOut", output_id, level)


# --- inside the worker process -------------------------------------------------------------


def serve_interfaces(connection: Connection, robot_ip: str) -> None:
    """The worker's main: construct the interfaces, then serve calls until told to exit.

    Runs in the spawned process. Every way out is ``os._exit``: interpreter shutdown
    would destroy the interfaces (ur_rtde aborts on a dead socket) while ur_rtde's
    threads still run.
    """
    # Ctrl-C in a terminal reaches the whole process group; the parent decides how the
    # worker ends, and a KeyboardInterrupt here would run the interpreter's shutdown.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        try:
            interfaces = _open_interfaces(robot_ip)
        except Exception as error:
            # Interfaces constructed before the failure are never destroyed: os._exit.
            connection.send(("failed", _one_line(error)))
            return
        connection.send(("ready", None))
        _serve_calls(connection, interfaces)
    finally:
        os._exit(0)


def _open_interfaces(robot_ip: str) -> dict[str, Any]:
    """Construct the three ur_rtde interfaces (the control one uploads its script)."""
    import rtde_control
    import rtde_io
    import rtde_receive

    control = rtde_control.RTDEControlInterface(robot_ip)
    receive = rtde_receive.RTDEReceiveInterface(robot_ip)
    io = rtde_io.RTDEIOInterface(robot_ip)
    return {"control": control, "receive": receive, "io": io}


def _serve_calls(connection: Connection, interfaces: dict[str, Any]) -> None:
    """Read requests until ``exit`` or the end of the pipe; each call on its own thread."""
    send_lock = threading.Lock()

    def serve(call_id: int, interface: str, method: str, args: tuple) -> None:
        try:
            reply = (call_id, True, getattr(interfaces[interface], method)(*args))
        except Exception as error:
            reply = (call_id, False, _one_line(error))
        with contextlib.suppress(OSError, ValueError), send_lock:  # parent gone: no one waits
            connection.send(reply)

    while True:
        try:
            request = connection.recv()
        except (EOFError, OSError):
            return  # the parent is gone; leave without touching the interfaces
        if request[0] == "exit":
            for interface in interfaces.values():
                with contextlib.suppress(Exception):  # the process ends either way
                    interface.disconnect()
            return
        _, call_id, interface, method, args = request
        threading.Thread(target=serve, args=(call_id, interface, method, args), daemon=True).start()


def _one_line(error: BaseException) -> str:
    """``"Type: message"`` on one line (``RuntimeError`` as ur_rtde raises it: the message)."""
    message = " ".join(str(error).split()) or repr(error)
    return message if type(error) is RuntimeError else f"{type(error).__name__}: {message}"
