"""A C probe compiled with an FMU's own sources, for tests that read the FMU's C functions directly
(tests/c/mass_probe.c, tests/c/mass_update_probe.c, tests/c/avx_probe.c)."""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

from flexlink.export.cbuild import compiler


def compile_probe(fmu: Path, probe: Path, work: Path, defines: tuple[str, ...] = ()) -> tuple[Path, Path]:
    """Extract ``fmu`` into ``work`` and compile ``probe`` with the sources its description lists: (the
    sources directory, the executable).  ``defines``: ``-D`` flags (``NAME=VALUE``)."""
    with zipfile.ZipFile(fmu) as z:
        z.extractall(work)
        files = [f.get("name") for f in ET.fromstring(z.read("modelDescription.xml")).findall(
            "CoSimulation/SourceFiles/File")]
    src = work / "sources"
    exe = work / probe.stem
    subprocess.run([*compiler(), "-O2", "-std=c99", *(f"-D{d}" for d in defines), f"-I{src}",
                    *(str(src / f) for f in files), str(probe), "-o", str(exe), "-lm"],
                   check=True, capture_output=True, text=True)
    return src, exe
