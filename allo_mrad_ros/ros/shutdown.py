"""SIGINT and SIGTERM for the node's processes: the first stops the node in order, a second
ends the process at once.

rclpy's own signal handlers shut the ROS context down the moment a signal arrives, whatever
the node's threads are doing: a frame being published then fails with "publisher's context
is invalid". So the node's processes do not let rclpy handle the signals
(``SignalHandlerOptions.NO``). :class:`ShutdownSignals` catches both with a handler that
does nothing but have Python write the signal's number to a pipe (``signal.set_wakeup_fd``,
done inside the C handler, in whichever thread the signal lands), and one thread reads the
pipe. The first signal asks the main thread to stop (:meth:`ShutdownSignals.requested`),
which stops the processing threads, destroys the node and only then shuts the context down.
A second signal, while that shutdown waits on something (a frame stuck in publishing), ends
the process at once with status 130, without a traceback. A SIGINT ignored at start (a
command started in the background) stays ignored.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable

# Exit status of a process ended by a second signal: 128 + SIGINT, as a shell reports Ctrl-C.
EXIT_SECOND_SIGNAL = 130


class ShutdownSignals:
    """Takes SIGINT and SIGTERM for the whole process from the moment it is made.

    Make it in the main thread (Python sets signal handlers there only), before
    ``rclpy.init``.
    """

    def __init__(self) -> None:
        chosen = [signal.SIGTERM]
        if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
            chosen.append(signal.SIGINT)
        self._requested = threading.Event()
        self._callbacks: list[Callable[[], None]] = []
        self._lock = threading.Lock()
        self.received: signal.Signals | None = None
        self._read, write = os.pipe()
        os.set_blocking(write, False)  # the C handler must never block
        signal.set_wakeup_fd(write, warn_on_full_buffer=False)
        for signum in chosen:
            signal.signal(signum, _noted_by_the_pipe)
        self._thread = threading.Thread(target=self._wait, name="mrad_signals", daemon=True)
        self._thread.start()

    def requested(self) -> bool:
        """Whether a signal asked the process to stop."""
        return self._requested.is_set()

    def on_request(self, callback: Callable[[], None]) -> None:
        """Call ``callback`` (from the signal thread: it must not block) on the first signal,
        or now if it came already."""
        with self._lock:
            if not self._requested.is_set():
                self._callbacks.append(callback)
                return
        callback()

    def _wait(self) -> None:
        while True:
            for signum in os.read(self._read, 64):
                if signum not in (signal.SIGINT, signal.SIGTERM):
                    continue  # another signal Python catches (SIGCHLD, say)
                if self._requested.is_set():
                    # The orderly shutdown is stuck or too slow for the user: end, quietly.
                    os._exit(EXIT_SECOND_SIGNAL)
                with self._lock:
                    self.received = signal.Signals(signum)
                    self._requested.set()
                    callbacks, self._callbacks = self._callbacks, []
                for callback in callbacks:
                    # This thread must live on to take a second signal, whatever happens.
                    with contextlib.suppress(Exception):
                        callback()


def _noted_by_the_pipe(signum: int, frame: object) -> None:
    """The Python-level handler: nothing to do, the signal thread acts on the pipe's byte
    (and no KeyboardInterrupt is raised in the main thread)."""
