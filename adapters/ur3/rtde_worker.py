"""ur_rtde in a worker process, so a lost link can never crash the process that uses it.

ur_rtde 1.6.5 aborts its process (``std::terminate``) when an interface whose socket
died is disconnected or destroyed, and its background threads (the control interface
reconnects by itself) keep running through interpreter shutdown, where they were seen to
crash the process (SIGSEGV). So the three interfaces live in one worker process of their
own, and the user's process holds thin proxies:

* :class:`RTDEWorker` starts the worker as a fresh interpreter (``subprocess``, never a
  fork: the parent has threads, and a fork would copy them mid-flight) and forwards
  ``(interface, method, args)`` requests over a socket pair (``multiprocessing``'s
  :class:`~multiprocessing.connection.Connection` framing). The worker runs only this
  module: unlike ``multiprocessing``'s "spawn" it never imports the user's main module,
  so a plain script that connects at top level (no ``if __name__ == "__main__":``) works
  as well as the ``dlo`` command. Each request carries an id; the
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
  its socket), so ur_rtde's destructors never run at interpreter shutdown. It ignores
  SIGINT: Ctrl-C in a terminal reaches the whole process group, and the parent decides
  how the worker ends.

This module imports only the standard library at import time, so the worker starts
without loading the rest of the project. The worker needs POSIX (it inherits its socket
through ``pass_fds``), like the rest of the UR3 adapter's process handling.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import signal
import socket
import subprocess
import sys
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

PACKAGE_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
"""The directory holding this copy of the ``adapters`` package (site-packages when
installed, the repository when run from it): the worker imports the same copy."""

_WORKER_BOOTSTRAP = """\
import signal
signal.signal(signal.SIGINT, signal.SIG_IGN)
import sys
root, fd, robot_ip = sys.argv[1:]
if root not in sys.path:
    sys.path.insert(0, root)
from adapters.ur3.rtde_worker import worker_main
worker_main(int(fd), robot_ip)
"""
"""The worker's ``-c`` program: SIGINT ignored first, then this module from ``root``.
Run with ``-P``: neither the cwd nor a script directory lands on ``sys.path``, so a
user's file named like a module (``socket.py``) cannot shadow it in the worker."""


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
        # Both ends are created non-inheritable: only the worker gets its end (pass_fds),
        # and no other child of this process ever holds one.
        parent_end, worker_end = socket.socketpair()
        try:
            self._process = subprocess.Popen(
                worker_command(worker_end.fileno(), robot_ip),
                stdin=subprocess.DEVNULL,
                pass_fds=(worker_end.fileno(),),
            )
        except BaseException:
            parent_end.close()
            raise
        finally:
            # Only the worker may hold its end, or its death would never read as EOF here.
            # If the user never closes the picker, the worker sees this process's end
            # close at exit and leaves (os._exit, no C++ teardown).
            worker_end.close()
        self._connection = Connection(parent_end.detach())
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
        return self._process.pid

    @property
    def exitcode(self) -> int | None:
        """The worker's exit status once it has been reaped (0 after :meth:`close`,
        ``-SIGKILL`` after :meth:`kill`); None while it runs."""
        return self._process.poll()

    @property
    def ended(self) -> bool:
        """Whether the worker can no longer serve calls (it exited, or its socket closed)."""
        with self._state_lock:
            return self._ended

    def wait_ended(self, timeout_s: float | None = None) -> bool:
        """Block until the worker has ended (its socket closed); False when ``timeout_s`` passed."""
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
        if self._reap(timeout_s):
            self._wait_for_reader()
        else:
            self.kill()

    def kill(self) -> None:
        """End the worker with SIGKILL and reap it; no disconnect or destructor runs.

        For links in doubt: the operating system closes the worker's sockets, and
        nothing in ur_rtde gets the chance to write to them.
        """
        self._kill_and_reap()
        self._wait_for_reader()

    def _reap(self, timeout_s: float) -> bool:
        """Wait for the worker to exit and reap it; False when it still runs."""
        try:
            self._process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return False
        return True

    def _kill_and_reap(self) -> None:
        # Popen.kill signals only a worker not yet reaped: never a recycled pid.
        self._process.kill()
        self._reap(KILL_TIMEOUT_S)

    def _await_startup(self, timeout_s: float) -> None:
        """Wait for the worker's first message: connected, or ur_rtde's error."""
        try:
            if not self._connection.poll(timeout_s):
                self._kill_and_reap()
                self._connection.close()
                raise RuntimeError(
                    f"the ur_rtde worker did not connect to {self.robot_ip} within "
                    f"{timeout_s:.0f} s (killed)"
                )
            status, detail = self._connection.recv()
        except (EOFError, OSError) as error:
            if not self._reap(KILL_TIMEOUT_S):
                self._kill_and_reap()
            self._connection.close()
            raise WorkerEndedError(
                f"the ur_rtde worker process (pid {self.pid}) ended while connecting to "
                f"{self.robot_ip} (exit code {self._process.returncode})"
            ) from error
        except BaseException:
            self._kill_and_reap()
            self._connection.close()
            raise
        if status != "ready":
            # The worker leaves on its own after reporting the error.
            if not self._reap(KILL_TIMEOUT_S):
                self._kill_and_reap()
            self._connection.close()
            raise RuntimeError(detail)

    def _read_replies(self) -> None:
        """Hand each reply to its waiting caller until the worker's end of the socket closes."""
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
        # The reader sees the end of the socket once the worker is gone; waiting for it
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


def worker_command(fd: int, robot_ip: str) -> list[str]:
    """The worker's command line: this interpreter, ``-P`` (no cwd on ``sys.path``), the
    bootstrap, and its arguments (package root, the worker's socket ``fd``, the robot)."""
    return [sys.executable, "-P", "-c", _WORKER_BOOTSTRAP, PACKAGE_ROOT, str(fd), robot_ip]


# --- inside the worker process -------------------------------------------------------------


def worker_main(fd: int, robot_ip: str) -> None:
    """The worker process's entry point: serve the connection on the inherited socket ``fd``."""
    serve_interfaces(Connection(fd), robot_ip)


def serve_interfaces(connection: Connection, robot_ip: str) -> None:
    """The worker's main: construct the interfaces, then serve calls until told to exit.

    Runs in the worker process. Every way out is ``os._exit``: interpreter shutdown
    would destroy the interfaces (ur_rtde aborts on a dead socket) while ur_rtde's
    threads still run.
    """
    # Ctrl-C in a terminal reaches the whole process group; the parent decides how the
    # worker ends, and a KeyboardInterrupt here would run the interpreter's shutdown.
    # (The bootstrap ignored SIGINT already; this covers a worker started otherwise.)
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
    """Read requests until ``exit`` or the end of the socket; each call on its own thread."""
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
