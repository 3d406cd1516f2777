"""``flexlink check FMU``: a compliance harness for FMI 2.0 and 3.0 FMUs.

It checks flexlink's FMUs and any other (docs/check.md).

Like fmpy's validation it collects problems instead of stopping at the first one.  Every check gives a row
in the style of the FMI cross-check results (input, reference, result, status) and the findings behind it,
each naming its rule and severity (:mod:`.findings`).  Only what the FMU declares is tested (:mod:`.fmu`);
each check runs in a child process with a time limit per FMI call (:mod:`.isolation`):

a. ``model-description`` (:mod:`.description`): fmpy's validation plus value references through the binary.
b. ``me-vs-cs`` (:mod:`.me_vs_cs`): both interfaces run by fmpy and compared.
c. ``fuzz`` (:mod:`.fuzz`): seeded random legal call sequences.
d. ``fmu-state`` (:mod:`.state`): get/set/serialize round trips and reset.
e. ``directional-derivatives`` (:mod:`.derivatives`): against central differences.
f. ``illegal-calls`` (:mod:`.illegal`): forbidden calls give fmi2Error; a wrong GUID is refused.
g. ``libcosim``, ``fmutool`` (:mod:`.importer_checks`): independent importers.

An FMI 3.0 FMU that declares Clocks, structural parameters or Scheduled Execution, which no check covers,
gets a ``skip`` row saying so for each (:mod:`.coverage`).

The fuzz size is small by default (CI); the full-size run is ``flexlink check OUT.fmu --fuzz 5000``.
``--platform win64`` runs every check on the FMU's win64 DLL under Wine, through a call proxy and server
(:mod:`.win64`).
"""

from flexlink.tools.check.command import add_parser, run_check
from flexlink.tools.check.driver import CHECKS, CI_FUZZ, check_fmu
from flexlink.tools.check.findings import CheckResult, Finding
from flexlink.tools.check.report import write_junit, write_report

__all__ = ["CHECKS", "CI_FUZZ", "CheckResult", "Finding", "add_parser", "check_fmu", "run_check", "write_junit",
           "write_report"]
