"""Compiling the C half of an FMU: where its sources and the FMI headers are, and one compiler call.

The generic C sources (``fmu_src/`` in the repository) are shipped as the package data
``flexlink.fmu_src``; the FMI 2.0 and 3.0 headers come from fmpy (``fmpy/c-code``) and are never copied
into the repository.  Everything is built with all warnings as errors and ``-fvisibility=hidden``: an FMU
library exports the ``fmi2…`` (FMI 3: ``fmi3…``) functions only (their declarations in ``fmi2Functions.h`` /
``fmi3Functions.h`` carry the visibility).
"""

from __future__ import annotations

import importlib.resources
import importlib.util
import os
import re
import shlex
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from flexlink.errors import BuildError

#: The environment variable that imposes one gcc optimisation level on the generated code
#: (flexlink.export.codegen.generated_code_optimisation); part of the FMU cache key (flexlink.export.cache).
OPTIMISE_ENV = "FLEXLINK_OPTIMISE"

#: The log categories of the C glue (``LOG_CATEGORY_NAMES`` in fmu_src/logging.c), in its order:
#: modelDescription.xml must list exactly these in ``<LogCategories>``.
LOG_CATEGORIES: tuple[str, ...] = (
    "logEvents", "logStatusWarning", "logStatusDiscard", "logStatusError", "logStatistics", "logAll",
)

#: The generic C sources of every FMU, compiled with the generated model half: the FMI API layer, the
#: functions behind it (cosimulation.h) by concern, the integrator and dense LU.
GENERIC_SOURCES: tuple[str, ...] = (
    "fmi2Functions.c", "calls.c", "logging.c", "instance.c", "variables.c", "cs_step.c", "model_exchange.c",
    "derivatives.c", "complex_step.c", "fmu_state.c", "guards.c", "consistent.c", "richardson.c", "ss22.c",
    "predictor.c", "mass_update.c", "linalg.c",
)
#: The FMI API layer of each FMI version, by concern: an FMU carries one (the functions behind it are shared).
API_SOURCES: dict[int, tuple[str, ...]] = {
    2: ("fmi2Functions.c",),
    3: ("fmi3Functions.c", "fmi3_variables.c", "fmi3_model_exchange.c", "fmi3_state.c", "fmi3_unsupported.c"),
}
#: The headers of an API layer's own (beside GENERIC_HEADERS).
API_HEADERS: dict[int, tuple[str, ...]] = {2: (), 3: ("fmi3_internal.h",)}
#: The FMI versions an FMU can be exported as.
FMI_VERSIONS: tuple[int, ...] = (2, 3)


def generic_sources(fmi_version: int = 2) -> tuple[str, ...]:
    """The generic C sources of an FMI ``fmi_version`` FMU: GENERIC_SOURCES with the API layer of that version."""
    if fmi_version not in API_SOURCES:
        raise BuildError(f"unknown FMI version {fmi_version!r}: choose 2 or 3")
    api, fmi2 = API_SOURCES[fmi_version], API_SOURCES[2]
    return (*api, *(f for f in GENERIC_SOURCES if f not in fmi2))


def generic_headers(fmi_version: int = 2) -> tuple[str, ...]:
    """The generic headers an FMI ``fmi_version`` FMU's sources include: GENERIC_HEADERS and its API layer's."""
    if fmi_version not in API_HEADERS:
        raise BuildError(f"unknown FMI version {fmi_version!r}: choose 2 or 3")
    return (*GENERIC_HEADERS, *API_HEADERS[fmi_version])


def fmi_headers(fmi_version: int = 2) -> list[Path]:
    """Fmpy's FMI headers an FMU's sources need.

    FMI 2's always (the functions behind the API layer use its types), FMI 3's too for an FMI 3 FMU.
    """
    names = ["fmi2*.h"] + (["fmi3*.h"] if fmi_version == 3 else [])
    return sorted(h for pattern in names for h in fmi_headers_dir().glob(pattern))


#: The generic headers they include (copied into an FMU's ``sources/`` with them).
GENERIC_HEADERS: tuple[str, ...] = ("model.h", "solver_settings.h", "cosimulation.h", "internal.h", "ss22.h",
                                    "predictor.h", "mass_update.h", "linalg.h", "pairs.h", "avx.h")

#: Flags of every FMU build (generated CasADi code included).
CFLAGS: tuple[str, ...] = (
    "-shared", "-fPIC", "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror", "-fvisibility=hidden",
)
#: The platforms an FMU can carry a binary for (FMI 2.0 folder names under ``binaries/``).
PLATFORMS: tuple[str, ...] = ("linux64", "win64")
#: Their folders under ``binaries/`` by FMI version (FMI 3.0 names platforms by architecture-OS tuples).
PLATFORM_FOLDER = {2: {"linux64": "linux64", "win64": "win64"},
                   3: {"linux64": "x86_64-linux", "win64": "x86_64-windows"}}
#: The MinGW-w64 cross-compiler of win64 binaries (``$FLEXLINK_MINGW_CC`` overrides it).
MINGW_CC = "x86_64-w64-mingw32-gcc"
#: The library suffix of each platform.
LIBRARY_SUFFIX = {"linux64": ".so", "win64": ".dll"}
#: Added for a memory-checked build; the later ``-O1`` wins over ``-O2``.
SANITIZE_CFLAGS: tuple[str, ...] = (
    "-fsanitize=address,undefined", "-fno-omit-frame-pointer", "-g", "-O1",
)


def fmi_headers_dir() -> Path:
    """The directory of fmpy's FMI 2.0 headers (``fmi2Functions.h`` and the two it includes)."""
    spec = importlib.util.find_spec("fmpy")
    if spec is None or spec.origin is None:
        raise BuildError("fmpy is not installed: it provides the FMI 2.0 headers (pip install fmpy)")
    path = Path(spec.origin).parent / "c-code"
    if not (path / "fmi2Functions.h").is_file():
        raise BuildError(f"fmpy's FMI headers are missing: no fmi2Functions.h in {path}")
    return path


def fmu_src_dir() -> Path:
    """The directory of the generic C sources (the package data ``flexlink.fmu_src``).

    The copy next to this flexlink comes first: a source tree's ``fmu_src/`` (a checkout on sys.path, or
    a second worktree whose interpreter has another checkout installed in editable mode, whose mapping
    of ``flexlink.fmu_src`` would otherwise pair this Python with that checkout's C), or an installed
    package's ``flexlink/fmu_src``; the package mapping only if neither exists.
    """
    here = Path(__file__).resolve()
    for path in (here.parents[2] / "fmu_src", here.parents[1] / "fmu_src"):
        if (path / "fmi2Functions.c").is_file():
            return path
    try:
        path = Path(str(importlib.resources.files("flexlink.fmu_src")))
    except ModuleNotFoundError:
        path = here.parents[2] / "fmu_src"
    if not (path / "fmi2Functions.c").is_file():
        raise BuildError(f"the generic FMU sources are missing: no fmi2Functions.c in {path}")
    return path


def compiler(platform: str = "linux64") -> list[str]:
    """The C compiler command of ``platform``.

    linux64: ``$CC`` (may carry arguments, e.g. ``ccache gcc``) or ``gcc``.  win64: ``$FLEXLINK_MINGW_CC``
    or the MinGW-w64 cross-compiler ``x86_64-w64-mingw32-gcc``; when it is not installed, a one-line
    BuildError says which package provides it (checked here, before minutes of code generation).
    """
    if platform == "linux64":
        return shlex.split(os.environ.get("CC", "").strip() or "gcc")
    if platform != "win64":
        raise BuildError(f"unknown platform {platform!r}: choose among {', '.join(PLATFORMS)}")
    command = shlex.split(os.environ.get("FLEXLINK_MINGW_CC", "").strip() or MINGW_CC)
    if shutil.which(command[0]) is None:
        raise BuildError(f"win64 binaries need the MinGW-w64 cross-compiler {command[0]}, which is not installed "
                         "(Debian/Ubuntu: apt-get install gcc-mingw-w64-x86-64)")
    return command


def parse_platforms(platforms: str | Iterable[str]) -> tuple[str, ...]:
    """Platform names from ``"linux64,win64"`` or a sequence, in the order given and without repeats.

    An unknown or missing name is a BuildError naming the choices.
    """
    names = platforms.split(",") if isinstance(platforms, str) else list(platforms)
    names = [n.strip() for n in names]
    unknown = [n for n in names if n not in PLATFORMS]
    if unknown or not names:
        raise BuildError(f"unknown platform {(unknown or [''])[0]!r}: choose among {', '.join(PLATFORMS)} "
                         "(comma-separated, e.g. linux64,win64)")
    return tuple(dict.fromkeys(names))


def compile_shared_library(
    sources: Iterable[str | os.PathLike[str]],
    include_dirs: Iterable[str | os.PathLike[str]],
    output: str | os.PathLike[str],
    *,
    extra_cflags: Sequence[str] = (),
    sanitize: bool = False,
    platform: str = "linux64",
) -> Path:
    """Compile C sources into one shared library and return its path.

    Parameters
    ----------
    sources
        C files to compile and link together.
    include_dirs
        Directories searched for headers (``-I``), in order.
    output
        Path of the library to write; its directory is created if needed.
    extra_cflags
        Further compiler flags, after the standard ones (e.g. ``-DFLEXLINK_TEST_FAIL``).
    sanitize
        Build with AddressSanitizer and UndefinedBehaviorSanitizer (for tests: the program that loads
        the library must be built with them too, or preload their runtime).
    platform
        ``"linux64"`` (a ``.so`` with the host's compiler) or ``"win64"`` (a ``.dll`` cross-compiled with
        MinGW-w64: the same flags but ``-fPIC``, which PE code does not need; the C runtime is the
        system's ``msvcrt.dll`` and libgcc is linked statically, so the DLL depends on no MinGW library).

    Raises
    ------
    BuildError
        If the compiler is missing or fails; the message carries its command line and stderr.
    """
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    cc = compiler(platform)
    base = CFLAGS if platform == "linux64" else tuple(f for f in CFLAGS if f != "-fPIC")
    flags = [*base, *(SANITIZE_CFLAGS if sanitize else ()), *extra_cflags, *(f"-I{d}" for d in include_dirs)]
    files = [Path(s) for s in sources]
    with tempfile.TemporaryDirectory(prefix="flexlink-objects-") as tmp:
        objects = [Path(tmp) / f"{k}_{s.stem}.o" for k, s in enumerate(files)]
        # the largest first, one compiler per core: the units of a large model compile side by side
        order = sorted(range(len(files)), key=lambda k: -_compiled_size(files[k]))
        with ThreadPoolExecutor(max_workers=max(1, os.cpu_count() or 1)) as pool:
            for _ in pool.map(lambda k: _run([*cc, *flags, "-c", str(files[k]), "-o", str(objects[k])],
                                             output.name), order):
                pass
        # libgcc's helpers (the complex step's complex products and quotients) linked in: on win64 they
        # would otherwise come from MinGW's libgcc_s_seh-1.dll, which a Windows host does not have
        link = ["-static-libgcc"] if platform == "win64" else []
        _run([*cc, *flags, *(str(o) for o in objects), *link, "-o", str(output), "-lm"], output.name)
    return output


_INCLUDED_UNIT = re.compile(r'^#include "([^"]+\.c)"', re.MULTILINE)


def _compiled_size(source: Path) -> int:
    """What a file gives the compiler to do, in bytes: its own text and the C files it includes.

    A twin of a generated unit (codegen's ``<unit>_avx.c`` or ``<unit>_complex.c``) is a few lines around its unit.
    """
    if not source.is_file():
        return 0
    text = source.read_text(errors="replace")
    return len(text) + sum((source.parent / name).stat().st_size for name in _INCLUDED_UNIT.findall(text)
                           if (source.parent / name).is_file())


def _run(command: list[str], what: str) -> None:
    """One compiler call; a failure is a BuildError with the command line and the compiler's stderr."""
    try:
        result = subprocess.run(command, capture_output=True, text=True, check=False)
    except OSError as error:
        raise BuildError(f"cannot run the C compiler {command[0]!r}: {error}") from error
    if result.returncode != 0:
        raise BuildError(
            f"compiling {what} failed (exit {result.returncode}):\n  {shlex.join(command)}\n"
            f"{result.stderr.strip()}"
        )
