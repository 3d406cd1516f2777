"""A serialised FMU state whose SS22 rate cadence is out of range is refused, nothing restored.

SS22's kept factorisations come back with an FMU state (fmu_src/fmu_state.c), each with its rate measures'
cadence: ``confirmed`` measures in a row (0 … SS22_RATE_CONFIRMATIONS = 3) and ``estimated`` steps accepted since
the last one (at most SS22_RATE_MEASURE_EVERY << confirmed).  ``confirmed`` is a shift count: out of range it
would be undefined behaviour, so deserialisation checks it like the cache's pivots.  The offsets come from the
FMU's own FmuData (tests/c/state_offsets.c compiled with its sources); the forged states carry a right checksum,
so only the range check can refuse them.
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
    valid, estimated, confirmed, confirmed_first, every, bias, miss = (int(x) for x in subprocess.run(
        [str(exe)], check=True, capture_output=True, text=True).stdout.split())
    return fmu, valid, estimated, confirmed, confirmed_first, every, bias, miss


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
    fmu, at_valid, at_estimated, at_confirmed, at_confirmed_first, every, _, _ = layout
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


@pytest.mark.parametrize("field, value, accepted", [
    ("bias", -1.0, True),           # the vote at its end: restored
    ("bias", 2.0, False),           # a running mean of +-1 beyond 1
    ("miss", float("nan"), False),  # a start that would be NaN
])
def test_a_forged_order_four_start_is_refused(layout, field, value, accepted):
    """The order-4 option's starts come back with the state (fmu_src/cosimulation.h, RichardsonStarts): a vote
    beyond +-1 or a non-finite miss is refused on deserialisation, nothing restored."""
    fmu, *_, at_bias, at_miss = layout
    with FmuHost(fmu) as host:
        host.initialize({"hub.tau": 0.5, "solver.order": 4.0, "solver.step": 1e-3})
        blob, guid = _state_after_20_steps(host, fmu)
        at = payload_start(guid) + (at_bias if field == "bias" else at_miss)
        assert struct.unpack_from("<d", blob, at)[0] != 0.0, "the run voted and missed"
        struct.pack_into("<d", blob, at, value)
        _restore_forged(host, blob, guid, accepted, "order-4 starts")
