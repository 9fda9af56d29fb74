"""The viewer's background thread: each panel runs its work on one :class:`Worker`, the latest job only."""

from __future__ import annotations

import threading
import time
import traceback
from collections.abc import Callable


class Worker:
    """One background thread running the latest job posted to it (a pending job is replaced by a newer one).

    A job may belong to a client (the page whose event posted it): when that client leaves,
    :meth:`cancel` drops its pending job and asks its running one to stop (long jobs poll
    :attr:`stop_requested`). :meth:`close` stops the thread and joins it."""

    def __init__(self, name: str, on_error: Callable[[str], None]) -> None:
        self.on_error = on_error
        self._cond = threading.Condition()
        self._pending: tuple[Callable[[], None], int | None] | None = None
        self._running = False
        self._running_client: int | None = None
        self._cancelled = False
        self._closed = False
        self._thread = threading.Thread(target=self._loop, name=f"seqmotion-view-{name}", daemon=True)
        self._thread.start()

    def submit(self, job: Callable[[], None], client: int | None = None) -> None:
        """Run ``job`` next (replacing a pending one); ``client``: the id of the page it is for, or None."""
        with self._cond:
            self._pending = (job, client)
            self._cond.notify()

    @property
    def has_pending(self) -> bool:
        return self._pending is not None

    @property
    def stop_requested(self) -> bool:
        """A newer job waits, the running job's client left, or the worker is closing: a long job stops."""
        return self._pending is not None or self._cancelled or self._closed

    def cancel(self, client: int) -> None:
        """``client`` left the page: drop its pending job and ask its running job to stop."""
        with self._cond:
            if self._pending is not None and self._pending[1] == client:
                self._pending = None
            if self._running and self._running_client == client:
                self._cancelled = True

    def idle(self, timeout: float = 30.0) -> bool:
        """Wait until no job runs or waits (tests, benchmarks); False on timeout."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._cond:
                if self._pending is None and not self._running:
                    return True
            time.sleep(0.005)
        return False

    def close(self, timeout: float = 120.0) -> None:
        """Drop the pending job, ask the running one to stop, and join the thread (a thread still inside
        torch when the interpreter exits aborts the process). RuntimeError if it does not end in time."""
        with self._cond:
            self._closed = True
            self._pending = None
            self._cond.notify()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout)
            if self._thread.is_alive():
                raise RuntimeError(f"{self._thread.name}: its job did not end within {timeout:g} s")

    def _loop(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                (job, self._running_client), self._pending = self._pending, None
                self._running, self._cancelled = True, False
            try:
                job()
            except Exception as exc:  # noqa: BLE001 - shown on the page, the server keeps running
                self.on_error(f"{type(exc).__name__}: {exc}")
                if not isinstance(exc, ValueError):  # bad input says all in its message; a bug needs the trace
                    traceback.print_exc()
            finally:
                with self._cond:
                    self._running, self._running_client = False, None


__all__ = ["Worker"]
