"""A wall-clock limit on one block of Python code, in whatever thread runs it (a sweep's case).

A sweep case runs in the calling thread (``scheduler="serial"``) or in a Dask worker's executor thread, where
``signal.alarm`` cannot reach. So the limit is a timer thread that, when it expires, raises
:class:`CaseTimeout` in the case's thread with CPython's ``PyThreadState_SetAsyncExc``: the exception
arrives at the next Python bytecode the thread runs, i.e. between two FMU calls. A call into the FMU's C
code is not cut short; a single ``fmi2DoStep`` is bounded by the FMU's own step limit (docs/integrator.md),
so the overshoot past the limit is at most one communication step's work.
"""

from __future__ import annotations

import ctypes
import threading


class CaseTimeout(Exception):
    """The block ran past its wall-clock limit."""


def _raise_in(thread_id: int, exc: type[BaseException] | None) -> None:
    """Schedule ``exc`` in the thread (None: cancel a scheduled one)."""
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(thread_id), ctypes.py_object(exc) if exc else None)


class Deadline:
    """A wall-clock limit on a block: ``with Deadline(seconds): ...`` raises :class:`CaseTimeout` in it.

    Raised once ``seconds`` of wall clock have passed (``None``: no limit). An expiry that races with the
    block's end still ends in CaseTimeout (the block did run past the limit), never in an exception delivered
    after the ``with``.
    """

    def __init__(self, seconds: float | None):
        self.seconds = seconds
        self._lock = threading.Lock()
        self._done = False
        self.expired = False

    def _expire(self) -> None:
        with self._lock:
            if not self._done:
                self.expired = True
                _raise_in(self._thread, CaseTimeout)

    def __enter__(self):
        if self.seconds is not None:
            self._thread = threading.get_ident()
            self._timer = threading.Timer(self.seconds, self._expire)
            self._timer.daemon = True
            self._timer.start()
        return self

    def __exit__(self, exc_type, exc, tb):
        if self.seconds is None:
            return False
        self._timer.cancel()
        with self._lock:
            self._done = True
            if self.expired:
                _raise_in(self._thread, None)        # not delivered yet: withdraw it, and say it here
        if self.expired and exc_type is not CaseTimeout:
            raise CaseTimeout
        return False
