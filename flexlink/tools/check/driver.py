"""The checks in order, each in its own child process (:mod:`flexlink.tools.check.isolation`).

The parent reads the model description only (to choose checks and arguments); it never loads the FMU's
binary, so nothing the FMU does can take the harness down.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from flexlink.tools.check.coverage import not_covered
from flexlink.tools.check.findings import CheckResult, skipped

CI_FUZZ = 60             # random legal call sequences of the fuzz check by default (full size: 5000)
CALL_LIMIT = 10.0        # seconds one FMI call may take before it is reported as not returning
CHECK_LIMIT = 1800.0     # seconds one check may take in all


@dataclass(frozen=True)
class Check:
    """A check of the harness: its name, where it is, and how it runs."""

    name: str
    function: str            # "module:function" under flexlink.tools.check
    isolated: bool = True    # False: the check starts its own processes (the importers)
    item: str | None = None  # what it marks its progress in, so a hang or crash ends one (see isolation.py)
    fmi3: bool | str = True  # runs on FMI 3.0 FMUs too; a string: why it does not (then reported as skipped)


CHECKS = [
    Check("model-description", "description:check_model_description"),
    Check("me-vs-cs", "me_vs_cs:check_me_vs_cs"),
    Check("fuzz", "fuzz:check_fuzz", item="sequence"),
    Check("fmu-state", "state:check_fmu_state"),
    Check("directional-derivatives", "derivatives:check_directional_derivatives"),
    Check("illegal-calls", "illegal:check_illegal_calls", item="catalogue item"),
    Check("libcosim", "importer_checks:check_libcosim", isolated=False,
          fmi3="libcosim (libcosimpy 0.0.6) does not import FMI 3.0: loading an FMI 3.0 FMU kills its process "
               "(SIGSEGV)"),
    Check("fmutool", "importer_checks:check_fmutool", isolated=False),
]
NAMES = [c.name for c in CHECKS]


def function(check: Check):
    """The function that runs the check."""
    import importlib

    module, name = check.function.split(":")
    return getattr(importlib.import_module(f"flexlink.tools.check.{module}"), name)


def _options(name: str, fuzz: int, seed: int, stop_time: float | None, tolerance: float | None) -> dict:
    options: dict[str, dict] = {"me-vs-cs": {"stop_time": stop_time, "tolerance": tolerance},
                                "fuzz": {"n": fuzz, "seed": seed}}
    return options.get(name, {})


def run_child(name: str, fmu: str, options: dict) -> CheckResult:
    """In the child process: one check on the FMU (``options`` hold its arguments and ``interfaces``)."""
    from flexlink.tools.check.fmu import Fmu

    check = next(c for c in CHECKS if c.name == name)
    f = Fmu(fmu, tuple(options.pop("interfaces")))
    try:
        return function(check)(f, **options)
    finally:
        f.close()


def _name_the_dll(result: CheckResult, repacked: str, original: str) -> None:
    """Findings of a win64 check name the DLL and the command that reproduces them, not the call proxy."""
    import re

    def named(text: str) -> str:
        text = re.sub(r"binaries/linux64/(\w+)\.so", r"binaries/win64/\1.dll", text)
        return re.sub(r"binaries/x86_64-linux/(\w+)\.so", r"binaries/x86_64-windows/\1.dll", text)

    result.details = [named(d) for d in result.details]
    result.result = named(result.result)
    for x in result.findings:
        x.message = named(x.message)
        x.reproduce = x.reproduce.replace(repacked, f"{original} --platform win64")


def check_fmu(path: str | os.PathLike, *, fuzz: int = CI_FUZZ, seed: int = 0, importers: bool = True,
              stop_time: float | None = None, tolerance: float | None = None,
              interfaces: tuple[str, ...] = ("CS", "ME"), only: list[str] | None = None,
              skip: list[str] | None = None, call_limit: float = CALL_LIMIT,
              platform: str = "linux64") -> list[CheckResult]:
    """Run the checks on the FMU at ``path`` (all, or ``only`` those, less ``skip``).

    ``platform`` "win64": on the FMU's win64 DLL under Wine (:mod:`flexlink.tools.check.win64`).  See the
    package docstring.
    """
    if platform == "win64":
        from flexlink.tools.check.findings import Finding
        from flexlink.tools.check.win64 import DllNotLoaded, hosted

        original = os.path.abspath(os.fspath(path))
        try:
            with hosted(original) as repacked:
                results = check_fmu(repacked, fuzz=fuzz, seed=seed, importers=importers, stop_time=stop_time,
                                    tolerance=tolerance, interfaces=interfaces, only=only, skip=skip,
                                    call_limit=call_limit)
        except DllNotLoaded as e:                # nothing can run: one failing row that says why
            return [CheckResult("model-description", "the win64 DLL", "loads under Wine", "does not load",
                                details=[str(e)], findings=[Finding("loads", str(e))])]
        for r in results:
            _name_the_dll(r, repacked, original)
        return results
    from flexlink.tools.check.fmu import Fmu
    from flexlink.tools.check.isolation import run_isolated

    # fmpy changes into the binary's folder to load it and does not always come back (a library that fails
    # to load): the caller's working directory is restored whatever happens
    cwd = os.getcwd()
    fmu = os.path.abspath(os.fspath(path))
    f = Fmu(fmu, interfaces)
    results = not_covered(f)
    try:
        for check in CHECKS:
            if (only and check.name not in only) or check.name in (skip or []):
                continue
            if not check.isolated and not importers:
                continue
            if f.fmi3 and check.fmi3 is not True:
                results.append(skipped(check.name, f"FMI 2.0 only: {check.fmi3}"))
                continue
            if not check.isolated:
                results.append(function(check)(f))
                continue
            options = {**_options(check.name, fuzz, seed, stop_time, tolerance), "interfaces": list(interfaces)}
            fuzzing = check.name == "fuzz"
            replay = (lambda k: f"--fuzz {k + 1} --seed {seed}") if fuzzing else None
            carry = (lambda found: {"earlier": [x.message for x in found]}) if fuzzing else None
            results.append(run_isolated(check.name, fmu, options, call_limit=call_limit, limit=CHECK_LIMIT,
                                        item=check.item, replay=replay, carry=carry))
    finally:
        f.close()
        os.chdir(cwd)
    return results
