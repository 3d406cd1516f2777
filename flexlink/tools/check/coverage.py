"""What an FMU declares that no check covers, said in the report rather than passed over in silence.

The checks drive FMI 3.0 FMUs through the FMI 2 state machine's FMI 3 counterparts (:mod:`.fmu`): they never
enter Configuration Mode, activate a Clock or run the Scheduled Execution interface.  An FMU that declares
Clocks, structural parameters or Scheduled Execution therefore gets a row per such feature, status ``skip``,
that names what it declares and why it is not checked: a pass of the other checks says nothing about it.
These rows are notes, not findings; they never change the exit status.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from flexlink.tools.check.findings import CheckResult, skipped

if TYPE_CHECKING:
    from flexlink.tools.check.fmu import Fmu

#: (row name, why the harness leaves it out)
CLOCKS = ("clocks", "not covered: FMI 3.0 Clocks are never activated or read (fmi3GetClock, "
                    "fmi3SetClock, clocked partitions in Event Mode are not called), so clocked variables keep "
                    "their start values and what depends on a Clock is not checked")
CONFIGURATION = ("configuration-mode", "not covered: structural parameters are set in Configuration Mode "
                                       "(fmi3EnterConfigurationMode), which no check enters, "
                                       "so they keep their start values (array sizes too)")
SCHEDULED = ("scheduled-execution", "not covered: the Scheduled Execution interface (FMI 3.0 §5) is not run; "
                                    "only Model Exchange and Co-Simulation are checked")


def _names(variables, limit: int = 5) -> str:
    names = [v.name for v in variables]
    return ", ".join(names[:limit]) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def not_covered(f: Fmu) -> list[CheckResult]:
    """One ``skip`` row for each FMI 3.0 feature the FMU declares and the harness leaves out.

    An FMI 2.0 FMU has none of them, and gets no row.
    """
    if not f.fmi3:
        return []
    variables = f.md.modelVariables
    clocks = [v for v in variables if v.type == "Clock"]
    clocked = [v for v in variables if getattr(v, "clocks", None)]
    structural = [v for v in variables if v.causality == "structuralParameter"]
    rows = []
    if clocks or clocked:
        what = f"{len(clocks)} Clock(s) ({_names(clocks)})" if clocks else "no Clock variable"
        rows.append(skipped(CLOCKS[0], f"{what}, {len(clocked)} clocked variable(s): {CLOCKS[1]}"))
    if structural:
        rows.append(skipped(CONFIGURATION[0], f"{len(structural)} structural parameter(s) ({_names(structural)}): "
                                              f"{CONFIGURATION[1]}"))
    if getattr(f.md, "scheduledExecution", None) is not None:
        rows.append(skipped(SCHEDULED[0], f"<ScheduledExecution> declared: {SCHEDULED[1]}"))
    return rows
