"""``flexlink check --platform win64``: the checks run the FMU's win64 DLL under Wine.

The harness and every importer it drives (fmpy, libcosim, fmutool) are Linux programs, so the FMU is
re-packed for them: its linux64 binary (FMI 3.0: ``x86_64-linux``) is replaced by flexlink's *call proxy*, a
Linux library that exports exactly the FMI functions the DLL exports and hands each call, over a pipe, to
flexlink's *call server* (``call_server.exe``, cross-compiled with MinGW-w64), which runs under Wine, has
loaded the DLL, and makes the same call there (C sources in ``wine/``: ``call_wire.h`` says what travels).  The
checks themselves are unchanged: each runs in its own process with its time limit per call, and what the
DLL does to its process (an exception, an ``exit``) the proxy does to the checker's, so a crash or a hang of
the DLL is the same finding as on linux64.

fmpy's own remoting (``fmpy.util.add_remoting``, win64 on linux64 over TCP) was tried first: its client covers
FMI 2.0 only, and under the checker it did not return from instantiations within the limit per call and
ended its server on the illegal calls (docs/check.md).

Wine runs in a private prefix made for the run (about 5 s the first time) with its ``wineserver`` kept
alive until the run ends, so that each check's first call starts the server in well under a second.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import subprocess
import tempfile
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

from flexlink.errors import FlexlinkError

SOURCES = Path(__file__).resolve().parent / "wine"
#: the platform folders of the binary a Linux importer loads and of the DLL, by FMI version
FOLDERS = {"2.0": ("linux64", "win64"), "3.0": ("x86_64-linux", "x86_64-windows")}
SERVER = "call_server.exe"
WINE_PACKAGES = "Debian/Ubuntu: apt-get install wine64 wine"


def wine() -> str | None:
    """The Wine command (``$FLEXLINK_WINE``, else ``wine64``, else ``wine``), or None."""
    named = os.environ.get("FLEXLINK_WINE", "").strip()
    if named:
        return shutil.which(named)
    return shutil.which("wine64") or shutil.which("wine")


def missing() -> str | None:
    """Why the win64 checks cannot run here (a missing cross-compiler or Wine), or None."""
    from flexlink.errors import BuildError
    from flexlink.export.cbuild import compiler

    try:
        compiler("win64")
    except BuildError as e:
        return str(e)
    if wine() is None:
        return f"--platform win64 runs the DLL under Wine, which is not installed ({WINE_PACKAGES})"
    return None


def dll_members(members: set[str], fmi_version: str, identifiers: set[str]) -> list[str]:
    """The DLLs the FMU must carry for ``identifiers``; a missing one is a one-line FlexlinkError."""
    folder = FOLDERS[fmi_version][1]
    wanted = [f"binaries/{folder}/{i}.dll" for i in sorted(identifiers)]
    for name in wanted:
        if name not in members:
            raise FlexlinkError(f"no {name}: --platform win64 checks the FMU's win64 binary")
    return wanted


def _run(command: list[str], what: str, **kwargs) -> subprocess.CompletedProcess:
    """Run ``command``; a failure is a one-line FlexlinkError saying ``what`` failed.

    Its output goes through files, not pipes: Wine's first process in a prefix starts helper processes
    (services, ...) that inherit the output and outlive it, so a pipe would never reach its end.
    """
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        try:
            res = subprocess.run(command, stdout=out, stderr=err, text=True, check=False, **kwargs)
        except subprocess.TimeoutExpired as e:
            raise FlexlinkError(f"{what} did not finish within {e.timeout:g} s") from None
        out.seek(0)
        err.seek(0)
        res.stdout, res.stderr = out.read(), err.read()
    if res.returncode != 0:
        tail = (res.stderr or res.stdout).strip().splitlines()[-1:] or ["no output"]
        raise FlexlinkError(f"{what} failed (exit status {res.returncode}): {tail[0]}")
    return res


def build_server(folder: Path) -> Path:
    """``call_server.exe``, cross-compiled with MinGW-w64 into ``folder``."""
    from flexlink.export.cbuild import compiler

    exe = folder / SERVER
    _run([*compiler("win64"), "-std=c99", "-O2", "-s", "-Wall", "-Wextra", str(SOURCES / "call_server.c"),
          "-o", str(exe)], "compiling the win64 call server")
    return exe


class DllNotLoaded(FlexlinkError):
    """The FMU's DLL does not load under Wine: a finding about the FMU (rule ``loads``), not bad input."""


def exports(server: Path, dll: Path, env: dict[str, str]) -> list[str]:
    """The FMI functions the DLL exports, read by the call server under Wine (which proves that it loads)."""
    try:
        out = _run([wine() or "wine", str(server), "--exports", "Z:" + str(dll).replace("/", "\\")],
                   f"loading {dll.name} under Wine", env=env, timeout=300).stdout
    except FlexlinkError as e:
        if "exit status 3" in str(e):          # call_server's status for a DLL that LoadLibrary refuses
            code = re.search(r"Windows error \d+", str(e))
            raise DllNotLoaded(f"binaries/{dll.parent.name}/{dll.name} does not load under Wine"
                               + (f" ({code.group(0)})" if code else "")) from None
        raise
    return sorted(n.strip() for n in out.splitlines() if n.strip().startswith(("fmi2", "fmi3")))


def build_proxy(folder: Path, names: list[str], fmi_version: str, out: Path) -> list[str]:
    """The call proxy as a Linux library at ``out``, exporting those of ``names`` it implements.

    A linker version script keeps every other symbol local, so that a function the DLL lacks is missing from
    the proxy too.  Returns the names the DLL exports that the proxy does not forward (none for a standard
    DLL).
    """
    from flexlink.export.cbuild import compiler, fmi_headers_dir

    api = "proxy_fmi3.c" if fmi_version == "3.0" else "proxy_fmi2.c"
    cc = [*compiler("linux64"), "-std=c99", "-O2", "-fPIC", "-Wall", "-Wextra", f"-I{fmi_headers_dir()}",
          f"-I{SOURCES}"]
    objects = []
    for source in ("call_proxy.c", api):
        objects.append(folder / source.replace(".c", ".o"))
        if not objects[-1].exists():
            _run([*cc, "-c", str(SOURCES / source), "-o", str(objects[-1])], "compiling the linux64 call proxy")
    defined = set(_run(["nm", "--defined-only", "-g", str(objects[-1])], "reading the call proxy").stdout.split())
    forwarded = [n for n in names if n in defined]
    script = folder / f"{out.stem}.map"
    script.write_text("{\n  global:\n" + "".join(f"    {n};\n" for n in forwarded) + "  local: *;\n};\n")
    _run([*cc, "-shared", *map(str, objects), f"-Wl,--version-script={script}", "-o", str(out)],
         "linking the linux64 call proxy")
    return [n for n in names if n not in defined]


def wine_environment(prefix: Path) -> dict[str, str]:
    """The environment of Wine in the run's private prefix, quiet, with ``$FLEXLINK_WINE`` set for the proxy."""
    return {**os.environ, "WINEPREFIX": str(prefix), "WINEDEBUG": "-all", "FLEXLINK_WINE": wine() or "wine"}


def repack(fmu: str, out: Path, folder: Path, env: dict[str, str]) -> None:
    """Re-pack the FMU at ``fmu`` to ``out`` for a Linux importer.

    The call proxy becomes its Linux binary, one per model identifier, and the call server goes beside its
    DLL.
    """
    import fmpy

    md = fmpy.read_model_description(fmu, validate=False)
    version = "3.0" if md.fmiVersion.startswith("3") else "2.0"
    linux, windows = FOLDERS[version]
    identifiers = {d.modelIdentifier for d in (md.coSimulation, md.modelExchange) if d is not None}
    with zipfile.ZipFile(fmu) as z:
        dlls = dll_members(set(z.namelist()), version, identifiers)
        unzipped = folder / "unzipped"
        z.extractall(unzipped)
    server = build_server(folder)
    proxies = {}
    for member in dlls:
        identifier = Path(member).stem
        names = [n for n in exports(server, unzipped / member, env) if n.startswith(f"fmi{version[0]}")]
        proxies[identifier] = folder / f"{identifier}.so"
        build_proxy(folder, names, version, proxies[identifier])
    with zipfile.ZipFile(fmu) as z, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as w:
        for item in z.infolist():
            if not item.filename.startswith(f"binaries/{linux}/"):
                w.writestr(item, z.read(item))
        for identifier, proxy in proxies.items():
            w.write(proxy, f"binaries/{linux}/{identifier}.so")
        w.write(server, f"binaries/{windows}/{SERVER}")


def _wineserver(env: dict[str, str], *options: str) -> None:
    """Run the prefix's ``wineserver`` with ``options`` (``-p``: stay alive until ``-k``; ``-k``: end it)."""
    command = shutil.which("wineserver") or str(Path(wine() or "wine").with_name("wineserver"))
    if os.path.exists(command):
        # the server goes on in the background: it must not hold a pipe of ours open
        subprocess.run([command, *options], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                       check=False, timeout=60)


@contextlib.contextmanager
def hosted(fmu: str) -> Iterator[str]:
    """The FMU re-packed with the call proxy (see the module docstring), in Wine's private prefix.

    While the context is open, ``os.environ`` holds the prefix (every check's process inherits it) and the
    prefix's ``wineserver`` stays alive; both end with it.
    """
    reason = missing()
    if reason is not None:
        raise FlexlinkError(reason)
    saved = {k: os.environ.get(k) for k in ("WINEPREFIX", "WINEDEBUG", "FLEXLINK_WINE")}
    folder = Path(tempfile.mkdtemp(prefix="flexlink-check-win64-"))
    (folder / "prefix").mkdir()
    env = wine_environment(folder / "prefix")
    try:
        _wineserver(env, "-p")
        out = folder / Path(fmu).name
        repack(fmu, out, folder, env)
        os.environ.update({k: env[k] for k in saved})
        yield str(out)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        _wineserver(env, "-k")          # ends the prefix's processes (a crashed DLL's server among them)
        _wineserver(env, "-w")          # and waits for them, before the prefix is removed
        _remove(folder)


def _remove(folder: Path) -> None:
    """Remove the run's folder for good.

    The ending wineserver may still write the prefix's registry after ``wineserver -w`` returns (seen in 3
    of about 15 runs), which recreates part of the folder.
    """
    for _ in range(10):
        shutil.rmtree(folder, ignore_errors=True)
        time.sleep(0.2)
        if not folder.exists():
            return
