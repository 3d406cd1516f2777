"""The layout of a serialised flexlink FMU state, for tests that forge one (fmu_src/fmu_state.c).

magic (8 bytes) | the model's GUID with its NUL | payload size (uint64) | FNV-1a 64 checksum of the payload |
the FmuData bytes.  A forged state is one whose FmuData bytes were changed and whose checksum was made right
again, so that only the FMU's range checks can refuse it.
"""

from __future__ import annotations

import struct


def payload_start(guid: str) -> int:
    """The offset of the FmuData bytes in a serialised state of the FMU with this GUID."""
    return 8 + len(guid) + 1 + 16


def fnv1a(payload: bytes) -> int:
    """FNV-1a 64, the checksum of a serialised state's payload."""
    h = 14695981039346656037
    for byte in payload:
        h = ((h ^ byte) * 1099511628211) % 2**64
    return h


def reseal(blob: bytearray, guid: str) -> None:
    """Make the checksum of a changed state right again (in place)."""
    start = payload_start(guid)
    blob[start - 8:start] = struct.pack("<Q", fnv1a(bytes(blob[start:])))
