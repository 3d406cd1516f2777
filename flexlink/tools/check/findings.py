"""Findings and the rules they rest on.

A finding is one thing wrong with the FMU: its severity (``error`` or ``warning``), the rule it rests on,
what was seen, the call sequence that shows it and a short reproduction.  A rule is either a requirement
of the FMI 2.0 standard (section and a brief paraphrase: the standard's own words are not reproduced here)
or a robustness recommendation that goes beyond it; only errors change the exit code, unless ``--strict``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

ERROR, WARNING = "error", "warning"


@dataclass(frozen=True)
class Rule:
    id: str
    severity: str          # the default severity of a finding against this rule
    reference: str         # "FMI 2.0 §x.y: ..." or "robustness recommendation: ..."


RULES = {r.id: r for r in [
    Rule("schema", ERROR, "FMI 2.0 §2.2: modelDescription.xml follows the schema and its rules "
                          "(as checked by fmpy validate)"),
    Rule("value-reference", ERROR, "FMI 2.0 §2.2.7: a variable's valueReference identifies it in the "
                                   "fmi2Get/Set functions of the binary"),
    Rule("outputs-listed", ERROR, "FMI 2.0 §2.2.8: ModelStructure/Outputs lists every variable of causality "
                                  "output"),
    Rule("derivatives-listed", ERROR, "FMI 2.0 §2.2.8: ModelStructure/Derivatives lists every state derivative"),
    Rule("loads", ERROR, "FMI 2.0 §2.1/§2.3: the binary exports the interface's functions and instantiates with "
                         "the GUID of its model description"),
    Rule("legal-call", ERROR, "FMI 2.0 §3.2.3 (ME) and §4.2.4 (CS): a call allowed by the state machine, with "
                              "legal arguments, does not fail (fmi2Error/fmi2Fatal)"),
    Rule("wrong-guid", WARNING, "FMI 2.0 §2.1.5: fmi2Instantiate checks the GUID; a wrong one should give NULL"),
    Rule("illegal-call", WARNING, "robustness recommendation: a call the state machine (§3.2.3, §4.2.4) or the "
                                  "argument rules forbid returns fmi2Error, after which fmi2Reset revives the "
                                  "instance (§2.1.3: after fmi2Error only fmi2Reset/fmi2FreeInstance)"),
    Rule("flexlink-contract", ERROR, "flexlink's own contract (flexlink FMUs only): every forbidden call returns "
                                     "fmi2Error, every parameter is range-checked"),
    Rule("returns", ERROR, "robustness recommendation: every call returns (§2.1.3: a function reports its outcome "
                           "as a status; one that never returns leaves the importer nothing to act on)"),
    Rule("no-crash", ERROR, "robustness recommendation: no call crashes the importer's process, whatever its "
                            "arguments (§2.1.3 gives fmi2Error and fmi2Fatal for what goes wrong)"),
    Rule("fmu-state", ERROR, "FMI 2.0 §2.1.8: fmi2SetFMUstate restores the state fmi2GetFMUstate copied, and a "
                             "deserialized state is that state (canGetAndSetFMUstate, canSerializeFMUstate)"),
    Rule("reset", ERROR, "FMI 2.0 §2.1.6: fmi2Reset brings the instance to the state after fmi2Instantiate"),
    Rule("directional-derivative", ERROR, "FMI 2.0 §2.1.9: fmi2GetDirectionalDerivative returns the partial "
                                          "derivatives of the unknowns w.r.t. the knowns "
                                          "(providesDirectionalDerivative)"),
    Rule("me-vs-cs", ERROR, "consistency: Model Exchange and Co-Simulation of one FMU describe the same model "
                            "(tolerance from the FMU's own solver or --tolerance)"),
    Rule("finite", ERROR, "robustness recommendation: outputs stay finite in a legal run"),
    Rule("importer", ERROR, "interoperability: an independent importer runs the FMU"),
    Rule("importer-warning", WARNING, "interoperability: an independent importer warns about the FMU"),
]}


@dataclass
class Finding:
    rule: str                      # a key of RULES
    message: str                   # what was seen
    severity: str = ""             # error | warning; default: the rule's
    sequence: list[str] = field(default_factory=list)     # the FMI calls that show it, last one last
    reproduce: str = ""            # a short reproduction

    def __post_init__(self):
        if not self.severity:
            self.severity = RULES[self.rule].severity

    @property
    def reference(self) -> str:
        return RULES[self.rule].reference

    def as_dict(self) -> dict:
        return {"severity": self.severity, "rule": self.rule, "reference": self.reference,
                "message": self.message, "sequence": self.sequence, "reproduce": self.reproduce}

    @classmethod
    def from_dict(cls, d: dict) -> Finding:
        return cls(d["rule"], d["message"], d["severity"], list(d.get("sequence", [])), d.get("reproduce", ""))

    def line(self) -> str:
        """One line for the terminal."""
        return f"{self.severity}: {self.message} [{self.rule}]"


@dataclass
class CheckResult:
    """One row of the report, in the style of the FMI cross-check results (input, reference, result), with
    the findings behind its status: ``fail`` with an error, ``warn`` with warnings only, ``skip`` when the
    FMU does not declare what the check needs (``result`` says why)."""

    name: str
    input: str
    reference: str
    result: str
    status: str = ""               # pass | warn | fail | skip; default: from the findings
    seconds: float = 0.0
    details: list[str] = field(default_factory=list)         # measurements, for the reader
    findings: list[Finding] = field(default_factory=list)

    def __post_init__(self):
        if not self.status:
            self.status = self.judged()

    def judged(self) -> str:
        if any(f.severity == ERROR for f in self.findings):
            return "fail"
        return "warn" if self.findings else "pass"

    def counts(self) -> tuple[int, int]:
        return (sum(f.severity == ERROR for f in self.findings), sum(f.severity == WARNING for f in self.findings))

    def as_dict(self) -> dict:
        return {"name": self.name, "input": self.input, "reference": self.reference, "result": self.result,
                "status": self.status, "seconds": self.seconds, "details": self.details,
                "findings": [f.as_dict() for f in self.findings]}

    @classmethod
    def from_dict(cls, d: dict) -> CheckResult:
        return cls(d["name"], d["input"], d["reference"], d["result"], d["status"], d["seconds"],
                   list(d["details"]), [Finding.from_dict(x) for x in d["findings"]])


def skipped(name: str, why: str) -> CheckResult:
    return CheckResult(name, "-", "-", why, "skip")
