"""The FMI 2.0 behaviour of real flexlink FMUs, driven call by call through fmpy's ``FMU2Slave``.

Three example scenes are exported once per module: ``rotating_link`` (second-order kinematics: a nonlinear
model, Newton in every SS22 step), ``rotating_link_linear`` (linear: constant Newton matrix, factorised once
and cached) and ``steel_beam_raise`` (a position-driven joint with a built-in law, static start, FE beam).

Covered: independent instances, FMU states (get/set/serialize), reset, variable communication steps,
tunable parameters in step mode, every kind of bad input (status, message, state afterwards), a step that
fails (fmi2Discard and its undo) and the ModelStructure's feedthrough.

Log messages reach Python through ``flexlink.run.simulate.logging_callbacks``, which routes every instance's
messages through one router (fmpy's native proxy keeps a single process-wide logger); the slaves here file
them under their instance name (test_logging_callbacks_of_two_runners_stay_separate checks the routing).
"""

from __future__ import annotations

import itertools
import math
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, fmi2LastSuccessfulTime
from serial_state import payload_start, reseal

from flexlink.mechanics.analysis import natural_frequencies
from flexlink.mechanics.model import build_model
from flexlink.run.simulate import logging_callbacks
from flexlink.scene.loader import load_scene

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
SCENES = ("rotating_link", "rotating_link_linear", "steel_beam_raise")
ROTATING = ("rotating_link", "rotating_link_linear")
OK, WARNING, DISCARD, ERROR = 0, 1, 2, 3
CATEGORY = {DISCARD: "logStatusDiscard", ERROR: "logStatusError"}
STEP_2_10 = 2.0 ** -10        # a solver step whose multiples are exact: every internal step has the same dt


# ------------------------------------------------------------------------------------------------ helpers


def _text(x) -> str:
    return x.decode(errors="replace") if isinstance(x, bytes) else str(x)


_LOGS: dict[str, list[tuple[int, str, str]]] = {}
_KEEP_ALIVE: list = []          # fmpy's proxy may still call any registered logger: never free one
_NAMES = itertools.count()


def _route(component, instance, status, category, message):
    _LOGS.setdefault(_text(instance), []).append((status, _text(category), _text(message)))


def _callbacks():
    cb = logging_callbacks(_route)
    _KEEP_ALIVE.append(cb)
    return cb


@dataclass
class Built:
    fmu: Path
    md: object
    unzipdir: str
    vr: dict[str, int] = field(default_factory=dict)
    outputs: list[str] = field(default_factory=list)
    start: dict[str, float] = field(default_factory=dict)


class Slave:
    """One FMU2Slave instance with its own log (``log``: (status, category, message) tuples) and clock ``t``."""

    def __init__(self, built: Built, guid: str | None = None):
        self.built = built
        self.vr = built.vr
        self.name = f"{built.md.modelName}-{next(_NAMES)}"
        self.log = _LOGS.setdefault(self.name, [])
        self.fmu = FMU2Slave(guid=guid or built.md.guid, unzipDirectory=built.unzipdir,
                             modelIdentifier=built.md.coSimulation.modelIdentifier, instanceName=self.name)
        self.fmu.instantiate(loggingOn=False, callbacks=_callbacks())
        self.t = 0.0

    def set(self, values: dict[str, float]) -> None:
        self.fmu.setReal([self.vr[n] for n in values], [float(x) for x in values.values()])

    def get(self, names: list[str] | None = None) -> np.ndarray:
        names = names or self.built.outputs
        return np.array(self.fmu.getReal([self.vr[n] for n in names]))

    def initialize(self, start: dict[str, float] | None = None, stop_time: float | None = None) -> None:
        if start:
            self.set(start)
        self.fmu.setupExperiment(startTime=0.0, stopTime=stop_time)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.t = 0.0

    def step(self, h: float) -> None:
        self.fmu.doStep(currentCommunicationPoint=self.t, communicationStepSize=h)
        self.t += h

    def close(self) -> None:
        self.fmu.freeInstance()


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, example_fmu) -> dict[str, Built]:
    out = tmp_path_factory.mktemp("behaviour")
    built = {}
    for name in SCENES:
        fmu = example_fmu(name)
        md = fmpy.read_model_description(str(fmu))
        b = Built(fmu, md, fmpy.extract(str(fmu), out / f"{name}.unzipped"))
        b.vr = {v.name: v.valueReference for v in md.modelVariables}
        b.outputs = [v.name for v in md.modelVariables if v.causality == "output"]
        b.start = {v.name: float(v.start) for v in md.modelVariables if v.causality in ("parameter", "input")}
        built[name] = b
    return built


@pytest.fixture
def new_slave(fmus):
    made: list[Slave] = []

    def make(scene: str, **kwargs) -> Slave:
        s = Slave(fmus[scene], **kwargs)
        made.append(s)
        return s

    yield make
    for s in made:
        s.close()


def refused(slave: Slave, call, status: int, *words: str) -> str:
    """``call()`` raises FMICallException with ``status`` and logs, under that status, a message containing
    every one of ``words``; returns the message."""
    n = len(slave.log)
    with pytest.raises(FMICallException) as info:
        call()
    assert info.value.status == status, info.value
    new = [m for s, c, m in slave.log[n:] if s == status and c == CATEGORY[status]]
    assert new, f"no message logged with status {status}: {slave.log[n:]}"
    assert any(all(w in m for w in words) for m in new), f"expected {words} in {new}"
    return new[-1]


# ------------------------------------------------------------------------------------------------ plans


@dataclass(frozen=True)
class Plan:
    """A run: start values, a communication step, and the inputs set before step k."""

    h: float
    start: dict = field(default_factory=dict)
    inputs: object = None          # k -> {name: value}

    def advance(self, slave: Slave, k0: int, k1: int) -> np.ndarray:
        """Steps k0 .. k1-1; the outputs after each."""
        rows = []
        for k in range(k0, k1):
            if self.inputs is not None:
                slave.set(self.inputs(k))
            slave.step(self.h)
            rows.append(slave.get())
        return np.array(rows)

    def run(self, slave: Slave, n: int) -> np.ndarray:
        slave.initialize(self.start)
        return np.vstack([slave.get()[None, :], self.advance(slave, 0, n)])


def _bang_bang(k: int) -> dict:
    return {"hub.tau": 0.3 if k < 15 else (-0.3 if k < 30 else 0.05 * math.sin(0.3 * k))}


PLANS = {
    "rotating_link": Plan(0.01, inputs=_bang_bang),
    "rotating_link_linear": Plan(0.01, inputs=_bang_bang),
    "steel_beam_raise": Plan(0.002),       # 10 internal steps of 2e-4 s per communication step
}
# the second instance of the interleaving test: other start values, other inputs, a change in step mode
OTHER = {
    "rotating_link": Plan(0.01, {"hub.inertia": 0.25, "arm.EI": 150.0, "solver.step": 5e-4},
                          lambda k: {"hub.tau": -0.1 * math.cos(0.2 * k), **({"arm.linear_density": 0.4} if k == 20
                                                                             else {})}),
    "rotating_link_linear": Plan(0.01, {"hub.inertia": 0.05, "solver.theta1": 0.6, "solver.theta2": 0.7},
                                 lambda k: {"hub.tau": 0.2 * (k % 7 == 0), **({"arm.EI": 200.0} if k == 20
                                                                              else {})}),
    "steel_beam_raise": Plan(0.002, {"gravity[2]": -3.0, "solver.step": 1e-4},
                             lambda k: {"beam.EI": 60000.0} if k == 20 else {}),
}


def short_run(slave: Slave) -> np.ndarray:
    """Ten steps of the scene's plan from a fresh start (the reference for 'reset recovers')."""
    scene = slave.built.md.modelName
    return PLANS[scene].run(slave, 10)


# ------------------------------------------------------------------------------------------------ instances


@pytest.mark.parametrize("scene", SCENES)
def test_two_instances_interleaved_give_what_each_gives_alone(new_slave, scene):
    n = 40
    alone_a = PLANS[scene].run(new_slave(scene), n)
    alone_b = OTHER[scene].run(new_slave(scene), n)
    a, b = new_slave(scene), new_slave(scene)
    a.initialize(PLANS[scene].start)
    b.initialize(OTHER[scene].start)
    rows_a, rows_b = [a.get()], [b.get()]
    for k in range(n):                       # one step of each in turn
        rows_a.append(PLANS[scene].advance(a, k, k + 1)[0])
        rows_b.append(OTHER[scene].advance(b, k, k + 1)[0])
    assert np.array_equal(np.array(rows_a), alone_a)
    assert np.array_equal(np.array(rows_b), alone_b)
    assert not np.array_equal(alone_a, alone_b)


def test_logging_callbacks_of_two_runners_stay_separate(fmus, tmp_path):
    """Two SlaveRunners in one process: an error of the first is logged to the first, also after the second
    has been closed and collected.  In a child process: today this segfaults."""
    script = tmp_path / "two_runners.py"
    script.write_text(textwrap.dedent(f"""
        import gc
        from fmpy.fmi1 import FMICallException
        from flexlink.run.simulate import SlaveRunner
        a = SlaveRunner({str(fmus['rotating_link'].fmu)!r}, instance_name="A")
        b = SlaveRunner({str(fmus['rotating_link'].fmu)!r}, instance_name="B")
        try:
            a.slave.setReal([a.vr["arm.EI"]], [-1.0])
        except FMICallException:
            pass
        assert any("arm.EI" in m for m in a.messages), ("A", a.messages, "B", b.messages)
        assert not b.messages, b.messages
        b.close()
        del b
        gc.collect()
        a.slave.reset()
        try:
            a.slave.setReal([a.vr["arm.linear_density"]], [-1.0])
        except FMICallException:
            pass
        assert any("arm.linear_density" in m for m in a.messages), a.messages
        a.close()
    """))
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, (run.returncode, run.stderr[-2000:])


# ------------------------------------------------------------------------------------------------ FMU state


def test_order_four_state_carries_its_starts_bit_for_bit(new_slave):
    """The order-4 option starts each SS22 step from its last miss (fmu_src/cs_step.c, RichardsonStarts in
    FmuData): a state restored, or deserialised into a second instance, continues to the last bit as the first
    run did, which it would not if those misses lived outside the state."""
    plan = Plan(0.01, {"solver.order": 4.0, "solver.step": 1e-3}, _bang_bang)
    s = new_slave("rotating_link")
    s.initialize(plan.start)
    plan.advance(s, 0, 30)
    saved_t = s.t
    state = s.fmu.getFMUstate()
    blob = s.fmu.serializeFMUstate(state)
    first = plan.advance(s, 30, 60)
    s.fmu.setFMUstate(state)
    s.t = saved_t
    assert np.array_equal(plan.advance(s, 30, 60), first)
    other = new_slave("rotating_link")
    other.fmu.setFMUstate(other.fmu.deSerializeFMUstate(blob))
    other.t = saved_t
    assert np.array_equal(plan.advance(other, 30, 60), first)
    s.fmu.freeFMUstate(state)


@pytest.mark.parametrize("scene", SCENES)
def test_fmu_state_get_set_and_serialize_reproduce_bit_for_bit(new_slave, scene):
    plan = PLANS[scene]
    s = new_slave(scene)
    s.initialize(plan.start)
    plan.advance(s, 0, 20)
    saved_t = s.t
    state = s.fmu.getFMUstate()
    first = plan.advance(s, 20, 40)

    s.fmu.setFMUstate(state)
    s.t = saved_t
    assert np.array_equal(plan.advance(s, 20, 40), first)

    blob = s.fmu.serializeFMUstate(state)
    plan.advance(s, 40, 45)                  # move on, then come back from the bytes
    restored = s.fmu.deSerializeFMUstate(blob)
    s.fmu.setFMUstate(restored)
    s.t = saved_t
    assert np.array_equal(plan.advance(s, 20, 40), first)

    reused = s.fmu.deSerializeFMUstate(blob, restored)     # into an existing state object
    assert reused.value == restored.value

    other = new_slave(scene)                 # a second instance, instantiated only
    state2 = other.fmu.deSerializeFMUstate(blob)
    other.fmu.setFMUstate(state2)
    other.t = saved_t
    assert np.array_equal(plan.advance(other, 20, 40), first)

    for fmu, st in ((s.fmu, state), (s.fmu, restored), (other.fmu, state2)):
        fmu.freeFMUstate(st)
        assert not st


def test_corrupted_serialized_state_is_refused(new_slave):
    plan = PLANS["rotating_link"]
    s = new_slave("rotating_link")
    s.initialize()
    plan.advance(s, 0, 10)
    saved_t = s.t
    good = s.fmu.getFMUstate()
    blob = s.fmu.serializeFMUstate(good)
    expected = plan.advance(s, 10, 15)

    foreign = new_slave("rotating_link_linear")
    foreign.initialize()
    foreign_state = foreign.fmu.getFMUstate()
    foreign_blob = foreign.fmu.serializeFMUstate(foreign_state)
    foreign.fmu.freeFMUstate(foreign_state)

    flipped = bytearray(blob)
    flipped[-17] ^= 0x5A                      # a byte of the payload
    bad_magic = bytearray(blob)
    bad_magic[0] ^= 0xFF
    # a state of another FMU with this one's layout: the same bytes under another GUID (the linear link's state
    # is smaller since 2026-11-29: it keeps no J - M for mass updates, fmu_src/mass_update.c)
    guid = s.built.md.guid.encode()
    other = guid[:-2] + (b"0" if guid[-2:-1] != b"0" else b"1") + guid[-1:]
    assert blob.count(guid) == 1
    same_layout = blob.replace(guid, other)
    cases = [
        (bytes(flipped), ("fmi2DeSerializeFMUstate", "corrupted")),
        (blob[:-1], ("fmi2DeSerializeFMUstate", "bytes")),
        (blob + b"\0", ("fmi2DeSerializeFMUstate", "bytes")),
        (bytes(bad_magic), ("fmi2DeSerializeFMUstate", "not a serialized")),
        (same_layout, ("fmi2DeSerializeFMUstate", "another FMU")),
        (foreign_blob, ("fmi2DeSerializeFMUstate", "bytes")),
    ]
    for buffer, words in cases:
        refused(s, lambda buffer=buffer: s.fmu.deSerializeFMUstate(buffer), ERROR, *words)
        # the error state: no stepping, values still readable ...
        refused(s, lambda: s.fmu.doStep(s.t, 0.01), ERROR, "fmi2DoStep", "not allowed in state error")
        assert np.all(np.isfinite(s.get()))
        # ... and a formerly stored state brings the instance back (FMI 2.0 section 2.1.3)
        s.fmu.setFMUstate(good)
        s.t = saved_t
        assert np.array_equal(plan.advance(s, 10, 15), expected)
    s.fmu.freeFMUstate(good)


def test_deserialized_state_values_pass_the_set_real_gate(new_slave, fmus):
    """A state whose bytes are intact (checksum right) but whose parameter is outside the domain the model
    description declares is refused as fmi2SetReal would refuse that value; nothing is restored."""
    import struct

    plan = PLANS["rotating_link"]
    s = new_slave("rotating_link")
    s.initialize()
    plan.advance(s, 0, 5)
    good = s.fmu.getFMUstate()
    blob = bytearray(s.fmu.serializeFMUstate(good))
    md = fmus["rotating_link"].md
    ei = next(v for v in md.modelVariables if v.name.endswith(".EI"))
    declared_min = float(ei.min)                       # the domain the FMU declares: EI > min
    header = payload_start(md.guid)
    value = struct.pack("<d", float(s.get([ei.name])[0]))
    at = bytes(blob).find(value, header)
    assert at > 0 and bytes(blob).find(value, at + 1) < 0, "the parameter's bytes must be unique in the state"
    for bad in (declared_min - 1.0, float("nan")):
        forged = bytearray(blob)
        forged[at:at + 8] = struct.pack("<d", bad)
        reseal(forged, md.guid)
        refused(s, lambda forged=forged: s.fmu.deSerializeFMUstate(bytes(forged)), ERROR,
                "fmi2DeSerializeFMUstate", ei.name)
        s.fmu.setFMUstate(good)                        # the instance comes back from a stored state
    restored = s.fmu.deSerializeFMUstate(bytes(blob))  # the untouched bytes still restore
    s.fmu.freeFMUstate(restored)
    s.fmu.freeFMUstate(good)


# ------------------------------------------------------------------------------------------------ reset


@pytest.mark.parametrize("scene", SCENES)
def test_reset_restores_start_values_and_reruns_bit_for_bit(new_slave, fmus, scene):
    plan, n = PLANS[scene], 30
    built = fmus[scene]
    tunable = [v.name for v in built.md.modelVariables if v.variability == "tunable"]
    s = new_slave(scene)
    first = plan.run(s, n)

    # tunable parameters changed in step mode, a few steps, then reset
    s.set({name: built.start[name] * 1.5 + 0.1 for name in tunable})
    plan.advance(s, n, n + 5)
    s.fmu.reset()
    s.fmu.setupExperiment(startTime=0.0)
    s.fmu.enterInitializationMode()
    names = list(built.start)
    assert np.array_equal(s.get(names), [built.start[n_] for n_ in names])
    s.fmu.exitInitializationMode()
    s.t = 0.0
    assert np.array_equal(np.vstack([s.get()[None, :], plan.advance(s, 0, n)]), first)

    # parameters and solver settings changed before initialization, then reset
    s.fmu.reset()
    s.set({"solver.step": 3e-4, "solver.theta1": 0.7, "solver.theta2": 0.9,
           **{name: built.start[name] * 0.5 for name in tunable}})
    s.fmu.reset()
    assert np.array_equal(plan.run(s, n), first)

    # from the terminated state
    s.fmu.terminate()
    s.fmu.reset()
    assert np.array_equal(plan.run(s, n), first)


# ------------------------------------------------------------------------------------------------ steps

IRREGULAR = (0.013, 0.0007, 0.05, 0.0363)      # sums to 0.1: both runs pass through t = 0.1 k


def _cycle_input(t: float) -> dict:
    cycle = int(math.floor(t / 0.1 + 1e-6))      # constant over each 0.1 s: both runs see the same u(t)
    return {"hub.tau": (0.3, 0.3, 0.3, -0.3, -0.3, -0.3, 0.1, 0.0, 0.0, 0.0)[cycle]}


def _run_steps(slave: Slave, steps, names, inputs=None, stop_time=None) -> tuple[list[float], np.ndarray]:
    """Steps of the given sizes; after each, fmi2LastSuccessfulTime must be exactly tc + h."""
    slave.initialize(stop_time=stop_time)
    times, rows = [0.0], [slave.get(names)]
    for h in steps:
        if inputs is not None:
            slave.set(inputs(slave.t))
        tc = slave.t
        slave.step(h)
        assert slave.fmu.getRealStatus(fmi2LastSuccessfulTime) == tc + h
        times.append(slave.t)
        rows.append(slave.get(names))
    return times, np.array(rows)


def test_variable_communication_steps_agree_within_the_ss22_error(new_slave):
    """Irregular communication steps (not multiples of solver.step = 1e-3) against regular ones.

    The FMU starts its internal grid afresh at every communication point (steps of solver.step, the last one
    shortened), so the two runs integrate on different grids and differ by SS22's truncation error, which is
    O(h²) (Θ = ½).  Richardson: the error of the regular run is about 4/3 |y(h) − y(h/2)|; the irregular
    grid's steps are all ≤ h, so its error is no larger; the difference of the two is then below
    8/3 |y(h) − y(h/2)| — asserted with the factor 3.  (Observed: about 100 times less, since the two grids
    share the step size except for the few shortened steps, and so share most of their error.)  The input
    switches only at common points."""
    names = ["hub.theta", "hub.omega", "arm.tip.v", "arm.root.moment", "tip.y"]
    _, regular = _run_steps(new_slave("rotating_link"), [0.01] * 100, names, _cycle_input)
    fine = new_slave("rotating_link")
    fine.set({"solver.step": 5e-4})
    _, halved = _run_steps(fine, [0.01] * 100, names, _cycle_input)
    times, irregular = _run_steps(new_slave("rotating_link"), list(IRREGULAR) * 10, names, _cycle_input,
                                  stop_time=1.0)
    common = [i for i, t in enumerate(times) if abs(t / 0.1 - round(t / 0.1)) < 1e-9]
    assert len(common) == 11
    irr = irregular[common]
    reg = regular[::10]
    bound = 3.0 * np.max(np.abs(regular - halved)[::10], axis=0)
    diff = np.max(np.abs(irr - reg), axis=0)
    scale = np.max(np.abs(reg), axis=0)
    print({n: f"{d:.3g} <= {b:.3g} (signal {s_:.3g})" for n, d, b, s_ in zip(names, diff, bound, scale, strict=True)})
    assert np.all(diff <= bound + 1e-13 * scale), dict(zip(names, zip(diff, bound, strict=True), strict=True))
    assert np.all(diff > 0)                  # the grids do differ: the comparison is not vacuous


def test_irregular_steps_land_exactly_on_the_communication_points(new_slave):
    """Built-in law θ(t) = π/4 (1 − cos πt): at every communication point the output base.theta is the law
    at tc + h, to rounding (the outputs take the law's exact angle at the FMU's time) — the FMU is exactly
    there, neither short nor beyond."""
    steps = [0.0131, 0.0007, 0.05, 0.00001, 0.0363, 0.1, 0.0219] * 4
    times, rows = _run_steps(new_slave("steel_beam_raise"), steps, ["base.theta", "base.tau"])
    t = np.array(times)
    law = np.where(t < 1.0, np.pi / 4 * (1 - np.cos(np.pi * t)), np.pi / 2)
    assert np.max(np.abs(rows[:, 0] - law)) < 1e-12
    assert np.all(np.isfinite(rows))


# ------------------------------------------------------------------------------------------------ tunables


def _peak_frequency(t: np.ndarray, x: np.ndarray, f_lo: float, f_hi: float) -> float:
    """Frequency of the largest spectral peak in [f_lo, f_hi] (Hann window, DTFT maximised on a grid)."""
    x = (x - x.mean()) * np.hanning(len(x))
    for _ in range(2):
        fs = np.linspace(f_lo, f_hi, 801)
        amplitude = np.abs(np.exp(-2j * np.pi * np.outer(fs, t)) @ x)
        k = int(np.argmax(amplitude))
        f_lo, f_hi = fs[max(k - 1, 0)], fs[min(k + 1, len(fs) - 1)]
    return float(fs[k])


def _ss22_frequency(f: float, dt: float) -> float:
    """What SS22 with Θ = ½ (the trapezoidal rule on M a + K q = 0) shows for an undamped mode of frequency f:
    the numerical rotation per step is 2 atan(ω dt / 2) instead of ω dt (period elongation ≈ (ω dt)²/12)."""
    w = 2 * np.pi * f
    return f * 2 * np.arctan(w * dt / 2) / (w * dt)


def _ring(slave: Slave, change: dict | None, start: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """0.03 s at rest (the step matrix gets factorised with the start values), then ``change`` in step mode,
    a ±0.05 N m torque doublet (no net angular momentum: the hub ends at rest on average) and 3 s of free
    vibration; the tip deflection arm.tip.v."""
    h = 4 * STEP_2_10
    slave.initialize({"solver.step": STEP_2_10, **(start or {})})
    for _ in range(8):
        slave.step(h)
    if change:
        slave.set(change)
    t, x = [], []
    for k in range(800):
        slave.set({"hub.tau": 0.05 if k < 5 else (-0.05 if k < 10 else 0.0)})
        slave.step(h)
        t.append(slave.t)
        x.append(slave.get(["arm.tip.v"])[0])
    return np.array(t), np.array(x)


def _scaled_scene(scene: str, key: str, factor: float, tmp_path: Path) -> Path:
    text = (EXAMPLES / f"{scene}.toml").read_text()
    lines = text.splitlines()
    hits = [i for i, line in enumerate(lines) if line.split("=")[0].strip() == key]
    assert len(hits) == 1, hits
    value = float(lines[hits[0]].split("=")[1].split("#")[0])
    lines[hits[0]] = f"{key} = {value * factor!r}"
    path = tmp_path / f"{scene}_{key}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def base_rings(fmus):
    rings = {}
    for scene in ROTATING:
        s = Slave(fmus[scene])
        rings[scene] = _ring(s, None)
        s.close()
    return rings


@pytest.mark.parametrize("scene", ROTATING)
@pytest.mark.parametrize("name, factor", [("arm.EI", 4.0), ("hub.inertia", 3.0), ("arm.linear_density", 0.5)])
def test_tunable_parameter_changed_in_step_mode_takes_effect(new_slave, fmus, base_rings, tmp_path, scene, name,
                                                             factor):
    """The first vibration frequency measured after the change equals natural_frequencies of the changed
    model (shifted by SS22's known period elongation), and the run equals that of an instance started with the
    new value: bit for bit for the linear model (Newton matrix factorised once, solver.step a power of two so
    that the cache always hits: this needs the factorisation to be rebuilt when the parameter changes); within
    what the Newton tolerance lets two runs differ for the nonlinear one, whose kept matrix and recurrence start
    (fmu_src/ss22.c, predictor.c) are formed at other steps in the two runs (after the change, at the start)
    and whose stops judge the matrix's rate by its age."""
    value = fmus[scene].start[name] * factor
    t, x = _ring(new_slave(scene), {name: value})
    t_fresh, x_fresh = _ring(new_slave(scene), None, start={name: value})
    if build_model(load_scene(EXAMPLES / f"{scene}.toml")).linear_in_state:
        assert np.array_equal(x, x_fresh)
    else:
        assert np.max(np.abs(x - x_fresh)) <= 1e-6 * np.max(np.abs(x_fresh))

    if name == "arm.EI":                     # rebuilt from a scene with the new EI
        model = build_model(load_scene(_scaled_scene(scene, "EI", factor, tmp_path)))
        p = None
    else:
        model = build_model(load_scene(EXAMPLES / f"{scene}.toml"))
        p = model.p0.copy()
        p[model.parameter_index(name)] = value
    f_model = natural_frequencies(model, 0.0, p).frequencies_hz[0]
    f_expected = _ss22_frequency(f_model, STEP_2_10)
    f_measured = _peak_frequency(t[t > 0.1], x[t > 0.1], 0.6 * f_model, 1.4 * f_model)
    assert f_measured == pytest.approx(f_expected, rel=2e-5)

    tb, xb = base_rings[scene]
    f_before = _peak_frequency(tb[tb > 0.1], xb[tb > 0.1], 3.0, 9.0)
    if name == "arm.EI":                     # K × 4 with M unchanged: ω × 2 exactly (at rest, linearised)
        ratio = _ss22_frequency(2 * f_before, STEP_2_10) / _ss22_frequency(f_before, STEP_2_10)
        assert f_measured / f_before == pytest.approx(ratio, rel=2e-5)
    else:
        assert abs(f_measured / f_before - 1) > 0.05


# ------------------------------------------------------------------------------------------------ bad input


def _to_phase(s: Slave, phase: str) -> None:
    if phase in ("initialization", "step"):
        s.fmu.setupExperiment(startTime=0.0)
        s.fmu.enterInitializationMode()
    if phase == "step":
        s.fmu.exitInitializationMode()
        s.set({"hub.tau": 0.1})
        s.step(0.01)


def _theta2_below_theta1(s: Slave) -> None:
    s.set({"solver.theta1": 0.8, "solver.theta2": 0.6})      # each within [0.5, 1]: only the pair is wrong
    s.fmu.setupExperiment(startTime=0.0)
    s.fmu.enterInitializationMode()
    s.fmu.exitInitializationMode()


BAD_INPUT = [
    ("nan-input", "step", lambda s: s.set({"hub.tau": math.nan}), ("fmi2SetReal", "hub.tau", "NaN")),
    ("inf-input", "step", lambda s: s.set({"hub.tau": math.inf}), ("fmi2SetReal", "hub.tau", "infinite")),
    ("minus-inf-input", "initialization", lambda s: s.set({"hub.tau": -math.inf}), ("hub.tau",)),
    ("nan-parameter", "step", lambda s: s.set({"arm.EI": math.nan}), ("fmi2SetReal", "arm.EI", "NaN")),
    ("nan-parameter-instantiated", "instantiated", lambda s: s.set({"hub.inertia": math.nan}), ("hub.inertia",)),
    ("negative-EI", "instantiated", lambda s: s.set({"arm.EI": -93.72}), ("fmi2SetReal", "arm.EI", "> 0")),
    ("negative-EI-in-step-mode", "step", lambda s: s.set({"arm.EI": -1.0}), ("fmi2SetReal", "arm.EI")),
    ("zero-EI", "step", lambda s: s.set({"arm.EI": 0.0}), ("arm.EI", "> 0")),
    ("subnormal-EI", "step", lambda s: s.set({"arm.EI": 5e-324}), ("fmi2SetReal", "arm.EI", "subnormal")),
    ("subnormal-hub-inertia", "instantiated", lambda s: s.set({"hub.inertia": 1e-310}), ("hub.inertia", "subnormal")),
    ("negative-linear-density", "step", lambda s: s.set({"arm.linear_density": -0.349}),
     ("fmi2SetReal", "arm.linear_density")),
    ("negative-hub-inertia", "initialization", lambda s: s.set({"hub.inertia": -0.1}), ("hub.inertia",)),
    ("zero-solver-step", "instantiated", lambda s: s.set({"solver.step": 0.0}), ("fmi2SetReal", "solver.step")),
    ("theta1-0.3", "instantiated", lambda s: s.set({"solver.theta1": 0.3}), ("solver.theta1", "0.5")),
    ("theta2-above-1", "instantiated", lambda s: s.set({"solver.theta2": 1.5}), ("solver.theta2",)),
    ("theta2-below-theta1", "instantiated", _theta2_below_theta1,
     ("fmi2ExitInitializationMode", "solver.theta1", "solver.theta2")),
    ("zero-communication-step", "step", lambda s: s.fmu.doStep(s.t, 0.0), ("fmi2DoStep", "communicationStepSize")),
    ("negative-communication-step", "step", lambda s: s.fmu.doStep(s.t, -0.01),
     ("fmi2DoStep", "communicationStepSize")),
    ("nan-communication-step", "step", lambda s: s.fmu.doStep(s.t, math.nan), ("fmi2DoStep", "communicationStepSize")),
    ("inf-communication-step", "step", lambda s: s.fmu.doStep(s.t, math.inf), ("fmi2DoStep", "communicationStepSize")),
    ("wrong-communication-point", "step", lambda s: s.fmu.doStep(s.t + 0.05, 0.01),
     ("fmi2DoStep", "currentCommunicationPoint")),
    ("communication-point-in-the-past", "step", lambda s: s.fmu.doStep(0.0, 0.01),
     ("fmi2DoStep", "currentCommunicationPoint")),
    ("doStep-before-initialization", "instantiated", lambda s: s.fmu.doStep(0.0, 0.01),
     ("fmi2DoStep", "not allowed in state instantiated")),
    ("doStep-in-initialization-mode", "initialization", lambda s: s.fmu.doStep(0.0, 0.01),
     ("fmi2DoStep", "initialization mode")),
    ("fixed-initial-angle-in-step-mode", "step", lambda s: s.set({"hub.initial_angle": 0.1}),
     ("fmi2SetReal", "hub.initial_angle", "fixed")),
    ("fixed-solver-step-in-step-mode", "step", lambda s: s.set({"solver.step": 1e-4}),
     ("fmi2SetReal", "solver.step", "fixed")),
    ("set-output", "step", lambda s: s.set({"tip.x": 1.0}), ("fmi2SetReal", "tip.x", "output")),
    ("set-output-instantiated", "instantiated", lambda s: s.set({"arm.tip.v": 0.0}), ("arm.tip.v", "output")),
    ("getReal-unknown-reference", "step", lambda s: s.fmu.getReal([99999]), ("fmi2GetReal", "99999")),
    ("setReal-unknown-reference", "step", lambda s: s.fmu.setReal([99999], [1.0]), ("fmi2SetReal", "99999")),
    ("setReal-mixed-known-and-unknown", "step", lambda s: s.fmu.setReal([s.vr["hub.tau"], 99999], [1.0, 1.0]),
     ("fmi2SetReal", "99999")),
    ("getInteger-unknown-reference", "step", lambda s: s.fmu.getInteger([99999]), ("fmi2GetInteger", "99999")),
    ("getBoolean-unknown-reference", "step", lambda s: s.fmu.getBoolean([99999]), ("fmi2GetBoolean", "99999")),
    ("getInteger-of-a-real", "step", lambda s: s.fmu.getInteger([s.vr["hub.theta"]]), ("fmi2GetInteger",)),
    ("terminate-before-initialization", "instantiated", lambda s: s.fmu.terminate(), ("fmi2Terminate",)),
]


@pytest.mark.parametrize("phase, call, words", [c[1:] for c in BAD_INPUT], ids=[c[0] for c in BAD_INPUT])
def test_bad_input_is_refused_with_fmi2Error_then_reset_recovers(new_slave, phase, call, words):
    s = new_slave("rotating_link")
    _to_phase(s, phase)
    refused(s, lambda: call(s), ERROR, *words)
    # the error state: only get, reset and free (and the FMU-state functions)
    refused(s, lambda: s.fmu.doStep(s.t, 0.01), ERROR, "fmi2DoStep", "not allowed in state error")
    refused(s, lambda: s.set({"hub.tau": 0.0}), ERROR, "fmi2SetReal", "not allowed in state error")
    refused(s, lambda: s.fmu.enterInitializationMode(), ERROR, "fmi2EnterInitializationMode", "error")
    refused(s, lambda: s.fmu.terminate(), ERROR, "fmi2Terminate", "error")
    assert s.get(["hub.theta"]).shape == (1,)
    s.fmu.reset()
    assert np.array_equal(short_run(s), short_run(new_slave("rotating_link")))


def test_wrong_guid_is_refused_at_instantiate(fmus, new_slave):
    built = fmus["rotating_link"]
    name = f"wrong-guid-{next(_NAMES)}"
    log = _LOGS.setdefault(name, [])
    fmu = FMU2Slave(guid="{00000000-0000-0000-0000-000000000000}", unzipDirectory=built.unzipdir,
                    modelIdentifier=built.md.coSimulation.modelIdentifier, instanceName=name)
    with pytest.raises(Exception, match="Failed to instantiate"):
        fmu.instantiate(callbacks=_callbacks())
    fmu.freeLibrary()
    assert any(s == ERROR and "fmi2Instantiate" in m and "GUID" in m and built.md.guid in m for s, _, m in log), log
    # the library is still fine for a correct instance
    s = new_slave("rotating_link")
    assert np.all(np.isfinite(short_run(s)))


def test_failed_step_is_discarded_and_leaves_the_last_good_state(new_slave):
    """A torque so large (1e300 N m: legal, inputs have no bounds) that the second internal step overflows:
    fmi2Discard with a message, the FMU back at the communication point with exactly the state it had,
    fmi2LastSuccessfulTime = tc, still in step mode; the host then continues with a smaller step (and a sane
    torque), alone or after fmi2SetFMUstate to the state it stored, and the run is that of a twin instance
    that never tried the failed step."""
    def start(s: Slave) -> None:
        s.initialize({"solver.step": 0.05})
        s.set({"hub.tau": 0.2})
        s.step(0.05)
        s.step(0.05)

    s, twin = new_slave("rotating_link"), new_slave("rotating_link")
    start(s)
    start(twin)
    stored = s.fmu.getFMUstate()
    tc = s.t
    s.set({"hub.tau": 1e300})
    names = [*s.built.outputs, *s.built.start]
    before = s.get(names)
    message = refused(s, lambda: s.fmu.doStep(tc, 0.5), DISCARD, "fmi2DoStep", "discarded")
    assert "NaN or an infinite value" in message
    assert s.fmu.getRealStatus(fmi2LastSuccessfulTime) == tc
    assert np.array_equal(s.get(names), before)

    def continue_small(x: Slave) -> np.ndarray:
        x.set({"hub.tau": 0.2})
        rows = []
        for _ in range(4):
            x.step(0.01)
            assert x.fmu.getRealStatus(fmi2LastSuccessfulTime) == x.t
            rows.append(x.get())
        return np.array(rows)

    expected = continue_small(twin)
    assert np.array_equal(continue_small(s), expected)          # straight on, in step mode
    s.fmu.setFMUstate(stored)                                    # or the standard way: back to the stored state
    s.t = tc
    assert np.array_equal(continue_small(s), expected)
    s.fmu.freeFMUstate(stored)


def test_nonlinear_step_solves_the_ss22_equation_to_the_tolerance(new_slave):
    """One SS22 step of the nonlinear rotating link (hub turning at 20 rad/s, 5 N m, step 0.05 s) against the
    same step solved here with the model's own residual and Newton to convergence.  The FMU stops when the
    remaining |Δα| dt / nominal ≤ solver.tolerance (1e-10), so its q may differ by dt²/2 |Δα| ≤
    dt/2 · 1e-10 · nominal; asserted with a margin of 100."""
    model = build_model(load_scene(EXAMPLES / "rotating_link.toml"))
    newton = model.newton_matrix_function()
    rate, tau, dt, tol = 20.0, 5.0, 0.05, 1e-10
    s = new_slave("rotating_link")
    s.initialize({"hub.initial_rate": rate, "solver.step": dt})
    s.set({"hub.tau": tau})
    s.step(dt)
    coords = ["hub.theta", "arm.eta[1]", "arm.eta[2]", "arm.eta[3]"]
    assert model.coordinates == ["hub.theta", "arm.eta[1]", "arm.eta[2]", "arm.eta[3]"]
    q_fmu, omega_fmu = s.get(coords), s.get(["hub.omega"])[0]

    q0, v0 = model.start_state()
    v0[0] = rate
    u, p, n = np.array([tau]), model.p0, model.n_q
    M = np.asarray(newton(q0, v0, np.zeros(n), u, p, 1.0, 0.0, 0.0))
    a = np.linalg.solve(M, -np.asarray(model.residual(q0, v0, np.zeros(n), u, p)).ravel())   # the FMU's guess
    for _ in range(30):
        qb, vb = q0 + 0.5 * dt * v0 + 0.25 * dt * dt * a, v0 + 0.5 * dt * a
        r = np.asarray(model.residual(qb, vb, a, u, p)).ravel()
        a = a + np.linalg.solve(np.asarray(newton(qb, vb, a, u, p, 1.0, 0.5 * dt, 0.25 * dt * dt)), -r)
    qb, vb = q0 + 0.5 * dt * v0 + 0.25 * dt * dt * a, v0 + 0.5 * dt * a
    assert np.max(np.abs(np.asarray(model.residual(qb, vb, a, u, p)))) < 1e-10
    q_ref, omega_ref = q0 + dt * v0 + 0.5 * dt * dt * a, v0[0] + dt * a[0]
    assert np.all(np.abs(q_fmu - q_ref) <= 100 * dt / 2 * tol * model.nominal_q), q_fmu - q_ref
    assert abs(omega_fmu - omega_ref) <= 100 * tol


# ------------------------------------------------------------------------------------------------ structure


def _xml_unknowns(fmu: Path) -> tuple[list[ET.Element], dict[str, ET.Element]]:
    with zipfile.ZipFile(fmu) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    variables = root.findall("./ModelVariables/ScalarVariable")
    outputs = {variables[int(u.get("index")) - 1].get("name"): u
               for u in root.findall("./ModelStructure/Outputs/Unknown")}
    return variables, outputs


def test_model_structure_declares_the_feedthrough(fmus):
    # steel_beam_raise: built-in law, no inputs: the joint torque depends on nothing (attribute present, empty —
    # an absent attribute would mean "depends on every input")
    raise_md = fmus["steel_beam_raise"].md
    assert not [v for v in raise_md.modelVariables if v.causality == "input"]
    # (since Model Exchange: on the continuous states q.*, v.* only)
    _, outputs = _xml_unknowns(fmus["steel_beam_raise"].fmu)
    assert outputs["base.tau"].get("dependencies") is not None
    (tau,) = [u for u in raise_md.outputs if u.variable.name == "base.tau"]
    assert [d.name for d in tau.dependencies if d.causality == "input"] == []
    assert all(d.name.startswith(("q.", "v.")) for d in tau.dependencies)

    # rotating_link: the accelerations read the torque directly; positions and rates do not (the outputs'
    # dependencies on the continuous states q.*, v.* are left out here: test_model_exchange.py)
    md = fmus["rotating_link"].md
    deps = {u.variable.name: ([d.name for d in u.dependencies if d.causality == "input"],
                              [k for d, k in zip(u.dependencies, u.dependenciesKind, strict=True)
                               if d.causality == "input"]) for u in md.outputs}
    for name in ("tip.ax", "tip.ay", "tip.sx", "tip.sy"):
        assert deps[name] == (["hub.tau"], ["dependent"]), name
    for name in ("hub.theta", "hub.omega", "arm.tip.v", "tip.x", "energy.kinetic"):
        assert deps[name] == ([], []), name
    _, xml_outputs = _xml_unknowns(fmus["rotating_link"].fmu)
    assert all("dependencies" in u.attrib for u in xml_outputs.values())


def test_declared_feedthrough_matches_the_values(new_slave, fmus):
    """Changing hub.tau at a communication point (no step) changes exactly the outputs that list it."""
    md = fmus["rotating_link"].md
    listed = {u.variable.name for u in md.outputs
              if [d.name for d in u.dependencies if d.causality == "input"] == ["hub.tau"]}
    s = new_slave("rotating_link")
    s.initialize()
    PLANS["rotating_link"].advance(s, 0, 12)              # moving and vibrating
    before = s.get()
    s.set({"hub.tau": -0.7})
    after = s.get()
    changed = {n for n, x, y in zip(s.built.outputs, before, after, strict=True) if x != y}
    assert changed <= listed
    assert {"tip.ax", "tip.ay", "tip.sx", "tip.sy"} <= changed      # tip.az, tip.sz stay 0: a planar motion


def test_position_driven_joint_torque_is_finite_and_starts_from_the_static_load(new_slave):
    """steel_beam_raise: base.tau over the raise (θ = π/4 (1 − cos πt), 1 s) and after.  At t = 0 the beam
    hangs in static equilibrium and the law starts with θ̈ = π³/4: the torque is at least the weight's moment
    m g L/2 and at most that plus the rigid-body inertia m L²/3 · θ̈ (the FE beam's elastic coordinates take
    most of the sudden acceleration: the tip lags)."""
    s = new_slave("steel_beam_raise")
    times, rows = _run_steps(s, [0.01] * 120, ["base.tau", "base.theta", "beam.tip.v"])
    assert np.all(np.isfinite(rows))
    m, g, length = 7800.0 * 1.2e-3 * 1.0, 9.81, 1.0
    static = m * g * length / 2
    rigid = m * length**2 / 3 * np.pi**3 / 4
    assert static * (1 - 1e-3) <= rows[0, 0] <= static + rigid
    assert np.max(np.abs(rows[:, 0])) < 10 * (static + rigid)
    assert rows[-1, 1] == pytest.approx(np.pi / 2, abs=1e-12)


def test_a_subnormal_input_is_accepted(new_slave):
    """Unlike a parameter, an input may decay to a subnormal value (a controller's output tending to 0): it is
    taken, and the step gives what a zero input gives (1e-310 N m moves nothing measurable)."""
    s = new_slave("rotating_link")
    _to_phase(s, "step")
    s.set({"hub.tau": 1e-310})
    s.fmu.doStep(s.t, 0.01)
    tiny = s.get(["hub.theta", "arm.tip.v"])
    z = new_slave("rotating_link")
    _to_phase(z, "step")
    z.set({"hub.tau": 0.0})
    z.fmu.doStep(z.t, 0.01)
    np.testing.assert_allclose(tiny, z.get(["hub.theta", "arm.tip.v"]), rtol=0, atol=1e-300)
