"""``flexlink check --platform win64``: every check of the harness on the FMU's win64 DLL under Wine.

The reference is the same harness on the same FMU's linux64 binary, built from the same sources: the win64
check must give the same rows with the same status, and the same findings on deliberately broken DLLs (a
doStep that poisons the state with NaN, a missing ``fmi2DoStep``, a doStep that dereferences NULL), where the
linux64 library built from the same broken sources is the independent witness of what the harness must
report.  A DLL that crashes must end the check's process as a native library would (SIGSEGV, the call
named), which is what tells the call server's transport apart from the FMU.

CI size: rotating_link, FMI 2.0 and 3.0, at a reduced fuzz and ME-vs-CS length; ``FLEXLINK_FULL=1`` adds the
two-link example (fast_two_link) and the default sizes.  Needs ``x86_64-w64-mingw32-gcc`` and Wine (skipped
with the reason otherwise; installed by .ci/run).  Without them the command is one line and exit status 2,
tested everywhere.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import pytest

from flexlink.export import cbuild
from flexlink.export.cbuild import compile_shared_library
from flexlink.export.fmu import build_fmu
from flexlink.tools.check import check_fmu
from flexlink.tools.check import win64 as check_win64

ROOT = Path(__file__).resolve().parent.parent
FULL = os.environ.get("FLEXLINK_FULL") == "1"
MISSING = check_win64.missing()
need_wine = pytest.mark.skipif(MISSING is not None, reason=MISSING or "")
#: CI size (the defaults under FLEXLINK_FULL=1): fuzz sequences and the ME-vs-CS length
SIZE = {} if FULL else {"fuzz": 20, "stop_time": 0.1}


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """``both(name, fmi)``: the example built with its linux64 and win64 binaries (once per module)."""
    if MISSING is not None:
        pytest.skip(MISSING)
    root = tmp_path_factory.mktemp("win64_check")
    out: dict[tuple[str, int], Path] = {}

    def get(name: str, fmi: int = 2) -> Path:
        if (name, fmi) not in out:
            path = root / f"{name}-fmi{fmi}.fmu"
            build_fmu(ROOT / "examples" / f"{name}.toml", path, platforms="linux64,win64", fmi_version=fmi)
            out[name, fmi] = path
        return out[name, fmi]
    return get


def _rows(results) -> dict[str, tuple[str, int, int]]:
    return {r.name: (r.status, *r.counts()) for r in results}


CASES = [("rotating_link", 2), ("rotating_link", 3),
         pytest.param("fast_two_link", 2, marks=pytest.mark.skipif(not FULL, reason="FLEXLINK_FULL=1 only"))]


@need_wine
@pytest.mark.parametrize(("name", "fmi"), CASES)
def test_win64_check_passes_the_rows_linux64_passes(both, name, fmi):
    """Same rows, same statuses, no finding; the deterministic rows (the seeded fuzz's call count, the
    illegal-call catalogue, the model description, the importers' final values) give the same text, and on
    the rotating link the ME-vs-CS deviation too."""
    fmu = both(name, fmi)
    linux = check_fmu(fmu, **SIZE)
    windows = check_fmu(fmu, platform="win64", **SIZE)
    assert [r.name for r in windows] == [r.name for r in linux]
    assert _rows(windows) == _rows(linux)
    assert all(r.status in ("pass", "skip") for r in windows), [(r.name, r.status, r.details) for r in windows]
    same_text = {"model-description", "fuzz", "fmu-state", "illegal-calls", "libcosim", "fmutool"}
    if name == "rotating_link":
        # the two-link arm's ME run under CVode does not keep the 1-ulp sincos differences of the two C
        # libraries at 1e-16: its worst ME-vs-CS deviation measured 7.50e-2 of the peak on linux64 and
        # 1.01e-1 on win64 (both within the FMU's tolerance, so both pass); equal text only on the link
        same_text.add("me-vs-cs")
    for w, k in zip(windows, linux, strict=True):
        if w.name in same_text:
            assert w.result == k.result, w.name


def _broken(fmu: Path, out: Path, file: str, anchor: str, text: str, *, replace: bool = False) -> Path:
    """The FMU with both binaries rebuilt from its own sources, ``text`` put before ``anchor`` in ``file``
    (or instead of it)."""
    src = out.with_suffix(".d")
    with zipfile.ZipFile(fmu) as z:
        z.extractall(src)
    c = src / "sources" / file
    source = c.read_text()
    assert anchor in source
    c.write_text(source.replace(anchor, text + ("" if replace else anchor), 1))
    sources = sorted((src / "sources").glob("*.c"))
    for platform, suffix in (("linux64", ".so"), ("win64", ".dll")):
        library = next((src / "binaries" / platform).glob(f"*{suffix}"))
        compile_shared_library(sources, [src / "sources"], library, platform=platform)
    with zipfile.ZipFile(out, "w") as z:
        for p in sorted(src.rglob("*")):
            if p.is_file():
                z.write(p, p.relative_to(src).as_posix())
    shutil.rmtree(src)
    return out


DO_STEP = "    return fmu_finish(inst, fmu_do_step(inst, currentCommunicationPoint"
BROKEN = {
    # the state poisoned at the end of every step (as tests/test_check.py does to the linux64 binary)
    "nan": ("cs_step.c", "    d->time = t_end;\n", "    d->q[0] = NAN;\n", False, ["me-vs-cs"]),
    # fmi2DoStep not exported: the definition renamed to an unused static function
    "missing": ("fmi2Functions.c", "fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint",
                "__attribute__((unused)) static fmi2Status fmi2DoStep_absent(fmi2Component c, "
                "fmi2Real currentCommunicationPoint", True, ["model-description", "fmu-state"]),
    # an access violation in every doStep
    "crash": ("fmi2Functions.c", DO_STEP, "    *(volatile int *)0 = 1;\n", False, ["fmu-state"]),
}


@need_wine
@pytest.mark.parametrize("kind", sorted(BROKEN))
def test_broken_win64_dll_is_caught_as_on_linux64(both, tmp_path, kind):
    file, anchor, text, replace, only = BROKEN[kind]
    bad = _broken(both("rotating_link"), tmp_path / f"{kind}.fmu", file, anchor, text, replace=replace)
    linux = check_fmu(bad, importers=False, only=only, **SIZE)
    windows = check_fmu(bad, importers=False, only=only, platform="win64", **SIZE)
    assert _rows(windows) == _rows(linux)
    assert all(r.status == "fail" for r in windows)
    details = [d for r in windows for d in r.details]
    if kind == "nan":
        assert any("NaN" in d for d in details), details
    if kind == "missing":
        assert any("binaries/win64/rotating_link.dll: undefined symbol: fmi2DoStep" in d for d in details), details
    if kind == "crash":
        assert any("died of SIGSEGV in fmi2DoStep" in d for d in details), details
    reproduce = [x.reproduce for r in windows for x in r.findings if x.reproduce]
    assert all(f"{bad} --platform win64" in x for x in reproduce), reproduce


@need_wine
def test_a_dll_that_hangs_is_reported_and_its_server_ends(both, tmp_path, monkeypatch):
    """A doStep that never returns: the call is reported as not returning, and the Wine process serving it
    ends with the check's process (no server left spinning).  The run's temporary folders (and so the
    server's command line) are under tmp_path, so that only this run's servers are looked for."""
    bad = _broken(both("rotating_link"), tmp_path / "hang.fmu", "fmi2Functions.c", DO_STEP,
                  "    for (;;) { static volatile int spin; spin++; }\n")
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    windows = check_fmu(bad, importers=False, only=["fmu-state"], call_limit=3.0, platform="win64")
    assert [r.status for r in windows] == ["fail"]
    assert any("fmi2DoStep(0.0, 0.001, 1) did not return within" in d for d in windows[0].details)
    assert _servers_under(tmp_path) == []


def _servers_under(folder: Path) -> list[str]:
    """The command lines of running call servers whose files are under ``folder`` (read from /proc)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            text = cmdline.read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:                       # the process ended meanwhile
            continue
        if "call_server" in text and str(folder) in text:
            found.append(text)
    return found


@need_wine
def test_fmu_without_a_win64_binary_is_a_usage_error(both, tmp_path):
    linux_only = tmp_path / "linux_only.fmu"
    with zipfile.ZipFile(both("rotating_link")) as z, zipfile.ZipFile(linux_only, "w") as w:
        for item in z.infolist():
            if "/win64/" not in item.filename:
                w.writestr(item, z.read(item))
    res = subprocess.run([sys.executable, "-m", "flexlink.cli", "check", str(linux_only), "--platform", "win64"],
                         capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        f"flexlink: error: {linux_only}: no binaries/win64/rotating_link.dll: --platform win64 checks the FMU's "
        "win64 binary"]


@pytest.mark.parametrize("missing", ["mingw", "wine"])
def test_without_wine_or_mingw_the_command_is_one_line_and_exit_2(example_fmu, tmp_path, missing):
    """PATH without Wine (and, for ``mingw``, without the cross-compiler either): one line naming the
    package, exit status 2, before anything is built."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    mingw = shutil.which(cbuild.MINGW_CC)
    if missing == "wine":
        if mingw is None:
            pytest.skip(f"{cbuild.MINGW_CC} is not installed: the Wine message needs it present")
        (bin_dir / cbuild.MINGW_CC).symlink_to(mingw)
    env = {k: v for k, v in os.environ.items() if k not in ("FLEXLINK_WINE", "FLEXLINK_MINGW_CC")}
    res = subprocess.run([sys.executable, "-m", "flexlink.cli", "check", str(example_fmu("rotating_link")),
                          "--platform", "win64"], capture_output=True, text=True, timeout=120,
                         env={**env, "PATH": str(bin_dir)}, check=False)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    expected = "gcc-mingw-w64-x86-64" if missing == "mingw" else "apt-get install wine64 wine"
    assert expected in lines[0]


@need_wine
def test_a_dll_windows_cannot_load_is_a_failing_row(both, tmp_path, capsys):
    """A truncated DLL: LoadLibrary refuses it under Wine (ERROR_BAD_EXE_FORMAT, 193), which is a finding
    about the FMU (rule ``loads``, exit status 1), not bad input."""
    from flexlink.cli import main

    bad = tmp_path / "truncated.fmu"
    with zipfile.ZipFile(both("rotating_link")) as z, zipfile.ZipFile(bad, "w") as w:
        for item in z.infolist():
            data = z.read(item)
            w.writestr(item, data[:5000] if item.filename.endswith(".dll") else data)
    assert main(["check", str(bad), "--platform", "win64"]) == 1
    out = capsys.readouterr().out
    assert "binaries/win64/rotating_link.dll does not load under Wine (Windows error 193) [loads]" in out
