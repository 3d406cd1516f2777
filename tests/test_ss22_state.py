"""A serialised FMU state whose SS22 rate cadence is out of range is refused, nothing restored.

SS22's kept factorisations come back with an FMU state (fmu_src/fmu_state.c), each with its rate measures'
cadence: ``confirmed`` measures in a row (0 … SS22_RATE_CONFIRMATIONS = 3) and ``estimated`` steps accepted since
the last one (at most SS22_RATE_MEASURE_EVERY << confirmed).  ``confirmed`` is a shift count: out of range it
would be undefined behaviour, so deserialisation checks it like the cache's pivots.  The offsets come from the
FMU's own FmuData (tests/c/state_offsets.c compiled with its sources); the forged states carry a right checksum,
so only the range check can refuse them.  The order-4 option's starts (RichardsonStarts) are checked the same
way, and what they keep is followed through a parameter change and late in a run.
"""

from __future__ import annotations

import struct
import subprocess
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import fmpy
import pytest
from fmpy.fmi1 import FMICallException
from serial_state import payload_start, reseal

from flexlink.export.cache import cached_fmu
from flexlink.export.cbuild import compiler
from flexlink.run.host import FmuHost

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "rotating_link.toml"
PROBE = Path(__file__).resolve().parent / "c" / "state_offsets.c"


@pytest.fixture(scope="module")
def layout(tmp_path_factory):
    """(FMU, offsets of cache[0].valid, .estimated, .confirmed in FmuData, SS22_RATE_MEASURE_EVERY)."""
    fmu = cached_fmu(EXAMPLE)
    work = tmp_path_factory.mktemp("state_offsets")
    with zipfile.ZipFile(fmu) as z:
        z.extractall(work)
        files = [f.get("name") for f in ET.fromstring(z.read("modelDescription.xml")).findall(
            "CoSimulation/SourceFiles/File")]
    src, exe = work / "sources", work / "state_offsets"
    subprocess.run([*compiler(), "-std=c99", f"-I{src}", *(str(src / f) for f in files), str(PROBE),
                    "-o", str(exe), "-lm"], check=True, capture_output=True, text=True)
    offsets = [int(x) for x in subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout.split()]
    names = ("bias", "miss", "valid", "dt", "alpha_half", "miss2", "first2")
    cadence, starts = offsets[:5], dict(zip(names, offsets[5:], strict=True))
    return fmu, *cadence, starts


def _state_after_20_steps(host, fmu) -> tuple[bytearray, str]:
    """The serialised state after 20 steps of 1 ms, and the FMU's GUID."""
    for k in range(20):
        host.instance.doStep(k * 1e-3, 1e-3)
    blob = bytearray(host.instance.serializeFMUstate(host.instance.getFMUstate()))
    return blob, fmpy.read_model_description(str(fmu)).guid


def _restore_forged(host, blob: bytearray, guid: str, accepted: bool, reason: str) -> None:
    """Deserialise the forged state with a right checksum: restored, or refused naming ``reason``."""
    reseal(blob, guid)
    if accepted:
        host.instance.deSerializeFMUstate(bytes(blob))
        return
    with pytest.raises(FMICallException):
        host.instance.deSerializeFMUstate(bytes(blob))
    assert reason in " ".join(host.messages)


@pytest.mark.parametrize("confirmed, estimated, accepted", [
    (3, 32, True),        # the largest cadence: restored
    (4, 0, False),        # beyond SS22_RATE_CONFIRMATIONS
    (-1, 0, False),       # a negative shift
    (0, 5, False),        # more steps on the kept rate than its cadence allows
])
def test_a_forged_rate_cadence_is_refused(layout, confirmed, estimated, accepted):
    fmu, at_valid, at_estimated, at_confirmed, at_confirmed_first, every, _ = layout
    assert every == 4
    with FmuHost(fmu) as host:
        host.initialize({"hub.tau": 0.5})
        blob, guid = _state_after_20_steps(host, fmu)
        header = payload_start(guid)
        assert struct.unpack_from("<i", blob, header + at_valid)[0] == 1, "the first factorisation is kept"
        struct.pack_into("<i", blob, header + at_confirmed, confirmed)
        struct.pack_into("<i", blob, header + at_confirmed_first, 0)   # the one-increment stops' cadence
        struct.pack_into("<i", blob, header + at_estimated, estimated)
        _restore_forged(host, blob, guid, accepted, "solver cache")


ORDER_FOUR = {"hub.tau": 0.5, "solver.order": 4.0, "solver.step": 1e-3}


@pytest.mark.parametrize("field, value, accepted", [
    ("bias", -1.0, True),               # the vote at its end: restored
    ("bias", 2.0, False),               # a running mean of +-1 beyond 1
    ("miss", float("nan"), False),      # a start that would be NaN
    ("miss2", float("nan"), False),     # the second half step's, the last of the three
    ("alpha_half", float("inf"), False),
    ("valid", 2, False),                # a flag is 0 or 1
    ("dt", 0.0, False),                 # kept misses of a step of no size
    ("first2", -1.0, True),             # no corrected start's first ratio yet: restored
    ("first2", 0.5, True),              # a ratio
    ("first2", -0.5, False),            # a ratio is >= 0, or -1 for none
    ("first2", float("inf"), False),
])
def test_a_forged_order_four_start_is_refused(layout, field, value, accepted):
    """The order-4 option's starts come back with the state (fmu_src/cosimulation.h, RichardsonStarts): a vote
    beyond +-1, a non-finite miss or base, a flag that is not 0 or 1, or misses said to be of a step of no size
    are refused on deserialisation, nothing restored; so is a kept factorisation's first ratio of corrected
    starts (SS22Factor.first[2]) that is neither -1 nor a finite ratio >= 0."""
    fmu, *_, at = layout
    with FmuHost(fmu) as host:
        host.initialize(ORDER_FOUR)
        blob, guid = _state_after_20_steps(host, fmu)
        where = payload_start(guid) + at[field]
        kind = "<i" if field == "valid" else "<d"
        assert struct.unpack_from(kind, blob, where)[0] != 0, "the run voted, missed and kept its misses"
        struct.pack_into(kind, blob, where, value)
        _restore_forged(host, blob, guid, accepted, "solver cache" if field == "first2" else "order-4 starts")


@pytest.mark.parametrize("change", [False, True])
def test_a_parameter_change_forgets_order_fours_misses(layout, change):
    """The misses order 4's starts add were measured on the parameters of their step: a tunable parameter set
    between steps (the hub's inertia, to a value it does not have) forgets them, as SS22 forgets its own."""
    fmu, *_, at = layout
    with FmuHost(fmu) as host:
        host.initialize(ORDER_FOUR)
        for k in range(20):
            host.instance.doStep(k * 1e-3, 1e-3)
        if change:
            host.instance.setReal([host.vr["hub.inertia"]], [0.12])
        header = payload_start(fmpy.read_model_description(str(fmu)).guid)
        blob = host.instance.serializeFMUstate(host.instance.getFMUstate())
        assert struct.unpack_from("<i", blob, header + at["valid"])[0] == (0 if change else 1)
        host.instance.doStep(20e-3, 1e-3)       # the next step starts from its base alone: no miss measured
        blob = host.instance.serializeFMUstate(host.instance.getFMUstate())
        assert (struct.unpack_from("<d", blob, header + at["miss"])[0] == 0.0) == change


@pytest.mark.parametrize("start_time", [0.0, 1e6])
def test_order_fours_misses_are_kept_late_in_a_run(layout, start_time):
    """Order 4 applies its kept misses to a step of the same size.  1e6 s into a run, t1 - t0 of a 1 ms step is
    off by up to 1.2e-10 s (the spacing of doubles there), 1.2e-7 of the step: still "the same size", so the full
    step's miss is measured (not zero) as at the start."""
    fmu, *_, at = layout
    with FmuHost(fmu) as host:
        host.initialize(ORDER_FOUR, start_time=start_time)
        for k in range(20):
            host.instance.doStep(start_time + k * 1e-3, 1e-3)
        blob = host.instance.serializeFMUstate(host.instance.getFMUstate())
        where = payload_start(fmpy.read_model_description(str(fmu)).guid) + at["miss"]
        assert struct.unpack_from("<d", blob, where)[0] != 0.0
