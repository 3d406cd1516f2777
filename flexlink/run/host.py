"""One host for an FMU in this process: the fmpy calls every Python caller of an FMU shares.

An :class:`FmuHost` extracts the FMU, instantiates it (Co-Simulation or Model Exchange), routes its log
messages into :attr:`FmuHost.messages`, looks value references up by name, initialises it with start
values set by type, turns a refused call (``fmi2Discard``, ``fmi2Error``, ``fmi2Fatal``, an instantiation
that returns NULL) into one :class:`FmuCallError` carrying the FMU's logged reason, reads the integrator's
counters from the ``logStatistics`` category, and frees everything as a context manager.  The step loops
(``flexlink.run.simulate.SlaveRunner``, the bench's timing loop, a controller's closed loop) sit on top and
reach the raw fmpy object as :attr:`FmuHost.instance` where a loop must not pay for anything.

fmpy's native logger proxy keeps one process-wide Python logger, so every instance is registered with one
router that dispatches on ``componentEnvironment`` (:func:`logging_callbacks`).
"""

from __future__ import annotations

import ctypes
import difflib
import functools
import itertools
import os
import re
import shutil
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Self

from fmpy.fmi1 import FMICallException

from flexlink.errors import FlexlinkError

__all__ = [
    "STATISTICS_KEYS",
    "FmuCallError",
    "FmuHost",
    "logging_callbacks",
    "release_logging_callbacks",
    "set_start_values",
]

INTERFACES = ("CoSimulation", "ModelExchange")
STATUS_LABELS = ("ok", "warning", "discard", "error", "fatal", "pending")

# fmu_src/logging.c's logStatistics message, and the counters it holds
# the consistent accelerations' counters since 2026-11-27 (fmu_src/consistent.c), the iteration matrices' mass
# updates (fmu_src/mass_update.c, counted among the factorisations) since 2026-11-29; an older FMU logs without them
STATISTICS = re.compile(r"(\d+) SS22 steps, (\d+) Newton iterations, (\d+) factorisations, (\d+) residual"
                        r"(?:.*?consistent accelerations: (\d+) mass matrices, (\d+) residual iterations)?"
                        r"(?:.*?mass updates among the factorisations: (\d+))?"
                        r"(?:.*?the model's AVX code: (\d+))?")
STATISTICS_KEYS = ("steps", "newton_iterations", "factorisations", "residual_evaluations", "mass_matrices",
                   "consistent_iterations", "mass_updates", "avx_code")


#: The C types of the functions :meth:`FmuHost.raw` returns (FMI 2.0, ``fmi2FunctionTypes.h``: fmi2Component is
#: ``void *``, fmi2ValueReference ``unsigned int``, fmi2Real ``double``, fmi2Boolean and fmi2Status ``int``).
RAW_PROTOTYPES: dict[str, str] = {
    **{f"fmi2{verb}{kind}": f"int (*)(void *, const unsigned int *, size_t, {const}{ctype} *)"
       for verb, const in (("Get", ""), ("Set", "const ")) for kind, ctype in (("Real", "double"),
                                                                                 ("Integer", "int"),
                                                                                 ("Boolean", "int"))},
    "fmi2DoStep": "int (*)(void *, double, double, int)",
    "fmi2SetTime": "int (*)(void *, double)"}


def pointer(address: int, ctype: str) -> Any:
    """A ``ctype *`` at ``address`` for the functions of :meth:`FmuHost.raw`: cffi cdata, ``p + k`` the k-th's.

    The caller keeps the memory alive: a ctypes array's ``ctypes.addressof``, a numpy array's
    ``.ctypes.data``, an FMU's component.
    """
    return _ffi().cast(f"{ctype} *", address)


@functools.cache
def _ffi() -> Any:
    """The FFI of cffi, made by the first closed loop (a command that runs none never imports cffi)."""
    import cffi

    return cffi.FFI()


class FmuCallError(FlexlinkError, FMICallException):
    """An FMI call the FMU refused, with the reason the FMU logged.

    A :class:`~flexlink.errors.FlexlinkError` (the command line prints it in one line and exits 2) and an
    fmpy ``FMICallException`` (``function``, ``status``), so callers written against fmpy keep working.

    Parameters
    ----------
    fmu : str
        The FMU's file name, for the message.
    function : str
        The FMI function (``fmi2DoStep``, ...).
    status : int
        Its return status (2 discard, 3 error, 4 fatal).
    reason : str
        The FMU's last logged messages of that call, or a note that it logged none.
    where : str, optional
        Where in the caller's run the call failed (``"step 3 (t = 0.003 s)"``), for a loop that calls the
        FMU many times.
    """

    def __init__(self, fmu: str, function: str, status: int, reason: str, where: str | None = None):
        FMICallException.__init__(self, function, status)
        label = STATUS_LABELS[status] if 0 <= status < len(STATUS_LABELS) else "illegal return code"
        self.reason = reason
        self.where = where
        failed = f"{function} failed with status {status} ({label})"
        self.args = (f"{fmu}: {where} failed ({failed}): {reason}" if where else f"{fmu}: {failed}: {reason}",)

    def __str__(self) -> str:
        return str(self.args[0])


def set_start_values(instance: Any, variables: Iterable[Any], values: Mapping[str, float] | None) -> None:
    """Set values through an fmpy instance with the setter of each variable's type.

    ``setInteger`` for an Integer (``solver.order``), ``setReal`` otherwise.  ``variables``: the model
    description's variables (any iterable of fmpy ScalarVariables).
    """
    by_name = {v.name: v for v in variables}
    for name, value in (values or {}).items():
        v = by_name[name]
        if v.type in ("Integer", "Enumeration"):
            instance.setInteger([v.valueReference], [int(value)])
        else:
            instance.setReal([v.valueReference], [float(value)])


class FmuHost:
    """One instance of an FMU through fmpy, from extraction to clean-up.

    Parameters
    ----------
    fmu : str or path
        The FMU file.
    interface : {"CoSimulation", "ModelExchange"}
        Which interface to instantiate; an FMU without it is refused with a :class:`FlexlinkError`.
    instance_name : str
        The instance name the FMU logs under.
    logging : bool
        ``loggingOn`` at instantiation (every category); refusals are logged either way.

    Examples
    --------
    >>> with FmuHost("rotating_link.fmu") as host:          # doctest: +SKIP
    ...     host.initialize({"solver.step": 5e-4})
    ...     host.call("fmi2DoStep", host.instance.doStep, 0.0, 0.01)
    ...     tip = host.get_real(["arm.tip.v"])
    """

    def __init__(self, fmu: str | os.PathLike, *, interface: str = "CoSimulation", instance_name: str = "flexlink",
                 logging: bool = False):
        import fmpy
        from fmpy.fmi2 import FMU2Model, FMU2Slave

        if interface not in INTERFACES:
            raise ValueError(f"interface {interface!r}: expected one of {INTERFACES}")
        self.path = os.fspath(fmu)
        self.name = os.path.basename(self.path)
        self.model_description = fmpy.read_model_description(self.path)
        side = self.model_description.coSimulation if interface == "CoSimulation" else \
            self.model_description.modelExchange
        if side is None:
            raise FlexlinkError(f"{self.name}: the FMU has no {interface} interface")
        self.variables = {v.name: v for v in self.model_description.modelVariables}
        self.vr = {name: v.valueReference for name, v in self.variables.items()}
        self.messages: list[str] = []
        self.statuses: list[int] = []
        self._unzipdir: str | None = fmpy.extract(self.path)
        cls = FMU2Slave if interface == "CoSimulation" else FMU2Model
        self.instance = cls(guid=self.model_description.guid, unzipDirectory=self._unzipdir,
                            modelIdentifier=side.modelIdentifier, instanceName=instance_name)
        self._callbacks = logging_callbacks(self._log)
        self._live = False
        self._fresh = True
        try:
            self.call("fmi2Instantiate", lambda: self.instance.instantiate(loggingOn=logging,
                                                                           callbacks=self._callbacks))
        except BaseException:
            self._release(free_instance=False)
            raise
        self._live = True

    # ------------------------------------------------------------------------------------ messages

    def _log(self, component, instance, status, category, message) -> None:
        self.messages.append(message.decode(errors="replace") if isinstance(message, bytes) else str(message))
        self.statuses.append(int(status))

    def call(self, function: str, f: Callable[..., Any], *args: Any) -> Any:
        """Call ``f(*args)``, an fmpy call of FMI ``function``.

        A refusal becomes one :class:`FmuCallError` with the messages the FMU logged during the call (the
        last three), or a note that it logged none.
        """
        seen = len(self.messages)
        try:
            return f(*args)
        except FmuCallError:
            raise
        except FMICallException as e:
            raise self.refusal(function, e.status, seen) from None
        except Exception as e:  # fmpy raises a bare Exception when fmi2Instantiate returns NULL
            if function != "fmi2Instantiate":
                raise
            raise FmuCallError(self.name, function, 3, self._reason(seen, str(e))) from None

    def refusal(self, function: str, status: int, seen: int | None = None, where: str | None = None
                ) -> FmuCallError:
        """The :class:`FmuCallError` of a refused call made without :meth:`call` (a loop on :meth:`raw`).

        ``seen``: the number of messages before the call (default: the last three logged are the reason);
        ``where``: the loop's place of the call, for the message.
        """
        return FmuCallError(self.name, function, status,
                            self._reason(len(self.messages) - 3 if seen is None else seen), where)

    def _reason(self, seen: int, fallback: str = "the FMU logged no reason") -> str:
        logged = [m.replace("%%", "%") for m in self.messages[max(seen, 0):][-3:]]
        return "; ".join(logged) or fallback

    def raw(self, function: str) -> Any:
        """The FMU's own FMI 2 ``function`` as a cffi function pointer of its C type, returning the status.

        Without fmpy's Python wrapper, its status check and ctypes' conversions: the call a closed loop makes
        every sample (issue 22: fmpy's wrappers were most of a sample's time, then ctypes' own: it converts
        each argument and prepares libffi's call at every call, where cffi's typed pointer did both once --
        the fast loop ran 1.21 times as fast, in the same run, benchmarks/closed_loop.py).  Pointer arguments
        are cdata (:func:`pointer`); the caller checks the status (> 1: :meth:`refusal`).  Known: the get/set
        functions of Real, Integer and Boolean (``component, vr*, size_t, values*``), ``fmi2DoStep`` and
        ``fmi2SetTime``.
        """
        proto = RAW_PROTOTYPES.get(function)
        if proto is None:
            raise ValueError(f"raw {function!r}: expected one of {sorted(RAW_PROTOTYPES)}")
        address = ctypes.cast(getattr(self.instance.dll, function), ctypes.c_void_p).value
        return _ffi().cast(proto, address)

    # ------------------------------------------------------------------------------------ variables

    def value_reference(self, name: str) -> int:
        """The value reference of ``name``; an unknown name is a :class:`FlexlinkError` naming close ones."""
        try:
            return self.vr[name]
        except KeyError:
            close = difflib.get_close_matches(name, list(self.vr), n=4, cutoff=0.5)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise FlexlinkError(f"{self.name}: no variable {name!r}{hint}") from None

    def set_values(self, values: Mapping[str, float] | None, function: str = "fmi2SetReal") -> None:
        """Set parameters or inputs by name, each with the setter of its type (see :func:`set_start_values`)."""
        for name in values or {}:
            self.value_reference(name)
        self.call(function, set_start_values, self.instance, self.model_description.modelVariables, values)

    def get_real(self, names: list[str]) -> list[float]:
        """The Real values of ``names``."""
        refs = [self.value_reference(n) for n in names]
        return list(self.call("fmi2GetReal", self.instance.getReal, refs))

    # ------------------------------------------------------------------------------------ life cycle

    def initialize(self, start: Mapping[str, float] | None = None, *, start_time: float = 0.0,
                   tolerance: float | None = None) -> None:
        """Reset (after a first initialisation), set ``start`` values, and initialise.

        Each start value goes through its type's setter; then the experiment is set up and the instance
        passes through initialisation mode.
        """
        s = self.instance
        if not self._fresh:
            self.call("fmi2Reset", s.reset)
        self._fresh = False
        self.set_values(start)
        self.call("fmi2SetupExperiment", lambda: s.setupExperiment(tolerance=tolerance, startTime=start_time))
        self.call("fmi2EnterInitializationMode", s.enterInitializationMode)
        self.call("fmi2ExitInitializationMode", s.exitInitializationMode)

    def solver_statistics(self) -> dict[str, int]:
        """Read the integrator's counters of the run just made from the FMU's ``logStatistics`` message.

        SS22 steps, Newton iterations, factorisations and residual evaluations, logged at fmi2Terminate, the
        consistent accelerations' mass matrices and residual iterations (fmu_src/consistent.c), and how many of
        the factorisations were mass updates of the Newton matrix (``mass_updates``, fmu_src/mass_update.c);
        ``avx_code`` is 1 where model.c calls the AVX twins of the model's Newton-iteration units: the build
        has them and the processor has AVX (fmu_src/avx.h).

        Ends the run (the next :meth:`initialize` resets the instance).  Empty for an FMU without that
        category.
        """
        self.messages.clear()
        self.instance.setDebugLogging(True, ["logStatistics"])
        self.call("fmi2Terminate", self.instance.terminate)
        self.instance.setDebugLogging(False, [])
        for message in reversed(self.messages):
            found = STATISTICS.search(message)
            if found:
                return {key: int(value) for key, value in zip(STATISTICS_KEYS, found.groups(), strict=True)
                        if value is not None}
        return {}

    def close(self) -> None:
        """Terminate (if it can), free the instance and its library, and delete the extracted files."""
        if self._live:
            try:
                self.instance.terminate()
            except Exception:   # already terminated, or in error: freeing is what matters
                pass
        self._release(free_instance=self._live)

    def _release(self, free_instance: bool) -> None:
        """Free the instance and its library, once.

        fmpy's ``freeInstance`` unloads the library itself (a further ``freeLibrary`` would close it twice);
        after a refused instantiation the library alone is freed.
        """
        if free_instance:
            self.instance.freeInstance()            # fmpy frees the library with it
            self._live = False
        elif self._unzipdir is not None:
            self.instance.freeLibrary()             # instantiation refused: nothing else unloads it
        release_logging_callbacks(self._callbacks)
        if self._unzipdir is not None:
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            self._unzipdir = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------------------------- logging

_ROUTES: dict[int, Callable[..., None]] = {}   # componentEnvironment key → the Python logger of one instance
_ROUTE_KEYS = itertools.count(1)
_ROUTER: Any = None                             # the one ctypes logger fmpy's native proxy ever calls


def _route(environment, instance, status, category, message) -> None:
    logger = _ROUTES.get(environment or 0)
    if logger is not None:
        logger(environment, instance, status, category, message)


def install_router() -> None:
    """Point fmpy's process-wide logger proxy back at our router.

    fmpy.simulate_fmu replaces it with a logger that dies with the call; a message after that would call
    freed memory.
    """
    global _ROUTER
    from ctypes import byref

    from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE

    if _ROUTER is None:
        _ROUTER = fmi2CallbackLoggerTYPE(_route)
    try:
        from fmpy.logging import addLoggerProxy
    except ImportError:   # older fmpy: no proxy, messages arrive unformatted
        return
    holder = fmi2CallbackFunctions()
    holder.logger = _ROUTER
    addLoggerProxy(byref(holder))


def logging_callbacks(logger: Callable[..., None]) -> Any:
    """fmi2CallbackFunctions whose messages reach ``logger(component, instance, status, category, message)``.

    Keep the returned object alive while the instance lives; :func:`release_logging_callbacks` ends the
    route.
    """
    from ctypes import byref, c_void_p

    from fmpy import calloc, free
    from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions

    install_router()
    key = next(_ROUTE_KEYS)
    _ROUTES[key] = logger
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = _ROUTER
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    callbacks.componentEnvironment = c_void_p(key)
    try:
        from fmpy.logging import addLoggerProxy

        addLoggerProxy(byref(callbacks))
    except ImportError:
        pass
    callbacks.route_key = key
    return callbacks


def release_logging_callbacks(callbacks: Any) -> None:
    """End the route of callbacks made by :func:`logging_callbacks` (the instance is freed)."""
    _ROUTES.pop(getattr(callbacks, "route_key", 0), None)
