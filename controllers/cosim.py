"""Closed-loop co-simulation: a sampled control law drives the FMU through fmpy's low-level ``FMU2Slave``.

One :class:`FmuLoop` extracts and instantiates the FMU once; each :meth:`FmuLoop.run` resets it
(``fmi2Reset``) when it has run before, sets the parameters, initialises, then at every sample::

    y_k = getReal(outputs)                 (outputs at t_k, the torque u_{k−1} still applied)
    u_k = law.step(y_k, x_ref[k], u_ff[k]) (saturated)
    setReal(<joint>.tau, u_k); doStep(t_k, dt)     (every actuated joint's torque: law.inputs)

and returns the recorded outputs as named time series (:class:`LoopResult`).  Two loops do this, the same
run up to rounding (tests/test_control_fmu.py):

* :meth:`FmuLoop._run_affine` — for a law with an :class:`~controllers.laws.AffineForm` (the LQG without a
  measurement schedule, the PD) and no sensor noise: one ``numpy.dot`` per sample and the FMU's own
  functions called through ctypes on addresses (issue 22: fmpy's wrappers and numpy on tiny arrays were
  most of a sample's time);
* :meth:`FmuLoop._run_stepped` — any law (multi-joint, scheduled, noisy): ``law.step`` per sample on fmpy's
  ctypes functions and value arrays allocated once.

Errors the FMU reports reach the caller as :class:`FmuLoopError` with the FMU's own log messages.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from controllers.laws import AffineForm, SampledLaw
from controllers.trajectory import Reference
from flexlink.errors import FlexlinkError

__all__ = ["FmuLoop", "FmuLoopError", "LoopResult"]


class FmuLoopError(FlexlinkError):
    """The FMU refused a call during a closed-loop run (message: the call and the FMU's log)."""


@dataclass
class LoopResult:
    """Named time series of one closed-loop run (``series["time"]``, outputs by FMU name, the torque under
    the input's name), plus the wall-clock time of the run (instantiation and FMU build excluded)."""

    series: dict[str, np.ndarray]
    wall_time: float
    parameters: dict[str, float] = field(default_factory=dict)
    cpu_time: float | None = None       # this process's CPU time over the same span (a loaded machine's
                                        # wall time includes the time the loop waited for a core)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.series[name]

    @property
    def time(self) -> np.ndarray:
        return self.series["time"]

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return float(self.time[-1] - self.time[0]) / self.wall_time if self.wall_time > 0 else float("inf")


class FmuLoop:
    """An FMU instantiated once for repeated closed-loop runs.

    Parameters
    ----------
    fmu : path
        A Co-Simulation FMU (FMI 2.0).
    record : list of str, optional
        Outputs to record besides the law's sensors (FMU names).
    instance_name : str, optional

    Examples
    --------
    >>> with FmuLoop("rotating_link.fmu", record=["arm.tip.v"]) as loop:   # doctest: +SKIP
    ...     res = loop.run(law, reference)
    ...     res2 = loop.run(law, reference, parameters={"arm.payload.mass": 0.65})
    """

    def __init__(self, fmu: str | os.PathLike, record: Sequence[str] = (), instance_name: str = "flexlink_loop"):
        import fmpy
        from fmpy.fmi2 import (
            FMU2Slave,
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
        )

        self.path = os.fspath(fmu)
        self.md = fmpy.read_model_description(self.path)
        if self.md.coSimulation is None:
            raise FlexlinkError(f"{self.path}: not a Co-Simulation FMU")
        self.variables = {v.name: v for v in self.md.modelVariables}
        self.record = list(record)
        self.messages: list[str] = []
        self._unzipdir = fmpy.extract(self.path)
        self.slave = FMU2Slave(guid=self.md.guid, unzipDirectory=self._unzipdir,
                               modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=instance_name)

        def logger(env, instance, status, category, message):
            text = message.decode(errors="replace") if isinstance(message, bytes) else str(message)
            self.messages.append(text.replace("%%", "%"))   # FMI messages are printf formats

        from fmpy import calloc, free

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._callbacks = cb
        self._logger = logger
        self._fresh = True
        self._call("instantiate", lambda: self.slave.instantiate(callbacks=cb, loggingOn=False))

    # -------------------------------------------------------------------------------------- helpers
    def _call(self, what: str, f):
        from fmpy.fmi1 import FMICallException

        n = len(self.messages)
        try:
            return f()
        except FMICallException as e:
            detail = "; ".join(self.messages[n:]) or "no message from the FMU"
            raise FmuLoopError(f"{os.path.basename(self.path)}: {what} failed ({e}): {detail}") from None
        except Exception as e:  # fmpy raises a bare Exception when fmi2Instantiate returns NULL
            detail = "; ".join(self.messages[n:]) or str(e)
            raise FmuLoopError(f"{os.path.basename(self.path)}: {what} failed: {detail}") from None

    def vr(self, name: str) -> int:
        try:
            return self.variables[name].valueReference
        except KeyError:
            raise FlexlinkError(f"{os.path.basename(self.path)} has no variable {name!r}") from None

    def close(self) -> None:
        if self.slave is not None:
            try:
                self.slave.terminate()
            except Exception:  # noqa: BLE001 (already terminated or in error: free anyway)
                pass
            self.slave.freeInstance()
            self.slave.freeLibrary()
            self.slave = None
        shutil.rmtree(self._unzipdir, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -------------------------------------------------------------------------------------- a run
    def run(self, law: SampledLaw, reference: Reference, parameters: Mapping[str, float] | None = None,
            solver_step: float | None = None, noise: Mapping[str, float] | None = None,
            seed: int = 0, fast: bool = True) -> LoopResult:
        """Run ``law`` against the FMU along ``reference`` (its time grid, its sample time).

        Parameters
        ----------
        law : SampledLaw or a multi-joint law (:mod:`controllers.multijoint`)
            ``sensors``, ``dt``, ``inputs`` (or one ``input``), ``reset()``, ``step(y, x_ref, u_ff)`` → the
            torque(s); reset before the run.
        reference : Reference
            ``x_ref`` and ``u_ff`` per sample; the run lasts ``reference.time[-1]``.
        parameters : dict, optional
            FMU parameters to set before initialisation (e.g. ``{"arm.payload.mass": 0.65}``).
        solver_step : float, optional
            ``solver.step`` (internal SS22 step); default: the FMU's own.
        noise : dict, optional
            Sensor name → standard deviation of white Gaussian noise added to what the law reads (the
            recorded outputs stay noise-free), e.g. :data:`controllers.design.SENSOR_NOISE` levels.
        seed : int
            Seed of the noise generator.
        fast : bool
            Run a law that has an :meth:`~controllers.laws.SampledLaw.affine` form (and no noise) as one
            matrix product per sample on raw ctypes calls (:meth:`_run_affine`); False: always the reference
            loop that calls ``law.step`` (:meth:`_run_stepped`), the same run up to rounding.
        """
        dt = reference.dt
        if abs(law.dt - dt) > 1e-12:
            raise ValueError(f"the law samples at {law.dt} s but the reference at {dt} s")
        params = dict(parameters or {})
        if solver_step is not None:
            params["solver.step"] = solver_step
        for name in params:
            v = self.variables.get(name)
            if v is None or v.causality != "parameter":
                raise FlexlinkError(f"{name}: not a parameter of {os.path.basename(self.path)}")
        sensors = list(law.sensors)
        unknown = set(noise or {}) - set(sensors)
        if unknown:
            raise FlexlinkError(f"noise on {sorted(unknown)}: not sensors of the law ({sensors})")
        names = list(dict.fromkeys([*sensors, *self.record]))
        inputs = list(getattr(law, "inputs", None) or [law.input])
        law.reset()
        form = law.affine(reference) if fast and not noise and hasattr(law, "affine") else None
        vr_out = (ctypes.c_uint * len(names))(*[self.vr(n) for n in names])
        vr_in = (ctypes.c_uint * len(inputs))(*[self.vr(n) for n in inputs])

        t0, c0 = time.perf_counter(), time.process_time()
        self._initialise(params)
        try:
            if form is not None:
                Y, U = self._run_affine(form, [names.index(n) for n in sensors], vr_out, vr_in, reference)
            else:
                Y, U = self._run_stepped(law, [names.index(n) for n in sensors], vr_out, vr_in, reference,
                                         noise, seed)
        finally:
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        self._call("fmi2Terminate", self.slave.terminate)
        series = {"time": reference.time.copy()}
        for i, name in enumerate(names):
            series[name] = Y[:, i].copy()
        for i, name in enumerate(inputs):
            series[name] = U[:, i].copy()
        return LoopResult(series, wall, params, cpu)

    def _initialise(self, params: Mapping[str, float]) -> None:
        """Reset (after a first run), set up, set the parameters, initialise."""
        s = self.slave
        if not self._fresh:
            self._call("fmi2Reset", s.reset)
        self._fresh = False
        self._call("fmi2SetupExperiment", lambda: s.setupExperiment(startTime=0.0))
        if params:
            pvr = list(params)
            self._call("fmi2SetReal (parameters)", lambda: s.setReal([self.vr(n) for n in pvr],
                                                                     [float(params[n]) for n in pvr]))
        self._call("fmi2EnterInitializationMode", s.enterInitializationMode)
        self._call("fmi2ExitInitializationMode", s.exitInitializationMode)

    def _step_failed(self, k: int, dt: float, e: Exception) -> FmuLoopError:
        detail = "; ".join(self.messages[-3:]) or "no message from the FMU"
        return FmuLoopError(f"{os.path.basename(self.path)}: step {k} (t = {k * dt:.6g} s) failed ({e}): {detail}")

    def _run_stepped(self, law, sensor_idx: list[int], vr_out, vr_in, reference: Reference, noise, seed: int):
        """The reference loop: fmpy's ctypes functions on arrays allocated once, ``law.step`` per sample."""
        from fmpy.fmi1 import FMICallException

        s, dt = self.slave, reference.dt
        n_out, m, p = len(vr_out), len(vr_in), len(sensor_idx)
        val_out, val_in = (ctypes.c_double * n_out)(), (ctypes.c_double * m)()
        u_in = np.frombuffer(val_in, dtype=np.float64)
        n_steps = len(reference.time) - 1
        sensors = list(law.sensors)
        sigma = np.array([float((noise or {}).get(n, 0.0)) for n in sensors])
        E = np.random.default_rng(seed).standard_normal((n_steps + 1, p)) * sigma if noise else None
        Y, U = np.empty((n_steps + 1, n_out)), np.empty((n_steps + 1, m))
        x_ref, u_ff = reference.x, reference.u_ff
        comp = s.component
        get_real, set_real, do_step = s.fmi2GetReal, s.fmi2SetReal, s.fmi2DoStep
        k = 0
        y = np.frombuffer(val_out, dtype=np.float64)          # a view: fmi2GetReal refills it in place
        prefix = sensor_idx == list(range(p))                 # the sensors come first: a slice, not a copy
        try:
            for k in range(n_steps + 1):
                get_real(comp, vr_out, n_out, val_out)
                Y[k] = y
                if E is not None:
                    ys = y[sensor_idx] + E[k]
                else:
                    ys = y[:p] if prefix else y[sensor_idx]
                u = law.step(ys, x_ref[k], u_ff[k])
                U[k] = u
                if k == n_steps:
                    break
                u_in[:] = u
                set_real(comp, vr_in, m, val_in)
                do_step(comp, k * dt, dt, 1)
        except FMICallException as e:
            raise self._step_failed(k, dt, e) from None
        return Y, U

    def _run_affine(self, form: AffineForm, sensor_idx: list[int], vr_out, vr_in, reference: Reference):
        """The fast loop (issue 22): per sample three raw ctypes calls and one ``numpy.dot``.

        Everything of a sample lives in one row of ``H`` = (outputs y_k, law state s_k, u_{k−1}, 1):
        ``fmi2GetReal`` writes y_k straight into row k, ``G @ H[k]`` writes (s_{k+1}, v_k) into row k+1,
        the clipped torque overwrites v_k there and ``fmi2SetReal`` reads it from there.  The recorded
        outputs and torques are columns of ``H``: nothing is copied or allocated per sample.
        """
        from fmpy.fmi1 import FMICallException

        dt, n_out, ns = reference.dt, len(vr_out), form.n_state
        n_steps = len(reference.time) - 1
        iu = n_out + ns                                        # column of u_{k−1}
        G = np.zeros((ns + 1, iu + 2))
        G[:, sensor_idx] = form.Gy
        G[:, n_out:iu] = form.Gs
        G[:, iu], G[:, iu + 1] = form.gu, form.g1
        H = np.zeros((n_steps + 2, iu + 2))
        H[:, iu + 1] = 1.0
        H[0, iu] = form.u0
        get_real, set_real, do_step = (_raw(self.slave, f) for f in ("fmi2GetReal", "fmi2SetReal", "fmi2DoStep"))
        comp, base, rb = self.slave.component, H.ctypes.data, H.strides[0]
        u_addr = base + rb + 8 * iu                           # &H[k + 1, iu] = u_addr + k rb
        n_vr_out, p_vr_out, p_vr_in = len(vr_out), ctypes.addressof(vr_out), ctypes.addressof(vr_in)
        r, hi = form.r.tolist(), form.limit
        lo, dot = -hi, np.dot
        rows, outs = list(H), list(H[1:, n_out:iu + 1])      # views made in C once, not per sample
        k = 0
        try:
            for k in range(n_steps + 1):
                st = get_real(comp, p_vr_out, n_vr_out, base + k * rb)
                if st > 1:
                    raise FMICallException("fmi2GetReal", st)
                out = outs[k]
                dot(G, rows[k], out=out)
                u = out[ns] + r[k]
                out[ns] = hi if u > hi else (lo if u < lo else u)
                if k == n_steps:
                    break
                st = set_real(comp, p_vr_in, 1, u_addr + k * rb)
                if st > 1:
                    raise FMICallException("fmi2SetReal", st)
                st = do_step(comp, k * dt, dt, 1)
                if st > 1:
                    raise FMICallException("fmi2DoStep", st)
        except FMICallException as e:
            raise self._step_failed(k, dt, e) from None
        return H[:-1, :n_out], H[1:, iu:iu + 1]


def _raw(slave, name: str):
    """The FMU's own ``name`` as a ctypes function taking addresses (ints): the call without fmpy's Python
    wrapper and its status check, and without ctypes converting arrays (the caller checks the status)."""
    proto = {"fmi2DoStep": (ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int)}.get(
        name, (ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p))
    return ctypes.CFUNCTYPE(ctypes.c_int, *proto)((name, slave.dll))
