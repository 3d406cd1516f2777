"""Findings and the rules they rest on.

A finding is one thing wrong with the FMU: its severity (``error`` or ``warning``), the rule it rests on,
what was seen, the call sequence that shows it and a short reproduction.  A rule is either a requirement
of the FMI standard or a robustness recommendation that goes beyond it (or flexlink's own contract); either
way it carries the sentences of the standard it rests on, quoted with their section (:class:`Source`).
Only errors change the exit code, unless ``--strict``.

The quotations are from the FMI 2.0.5 and FMI 3.0.2 specifications (github.com/modelica/fmi-standard,
tags v2.0.5 and v3.0.2, the asciidoc sources), by the Modelica Association Project FMI, licensed CC-BY-SA
4.0; asciidoc markup (cross-references, code quotes) is dropped and "…" marks a cut.
"""

from __future__ import annotations

from dataclasses import dataclass, field

ERROR, WARNING = "error", "warning"
STANDARD, RECOMMENDATION, FLEXLINK = "standard", "robustness recommendation", "flexlink's contract"
FMI2, FMI3 = "FMI 2.0.5", "FMI 3.0.2"


@dataclass(frozen=True)
class Source:
    """A sentence of the standard, quoted: which version, which section (number and title), its words."""

    standard: str          # FMI2 or FMI3
    section: str           # "§2.1.8 Getting and Setting the Complete FMU State"
    quote: str

    def cite(self) -> str:
        """The quotation with its version and section, for a report."""
        return f"{self.standard} {self.section}: \u201c{self.quote}\u201d"


@dataclass(frozen=True)
class Rule:
    """A rule a finding rests on: its default severity, its kind and the standard's sentences behind it."""

    id: str
    severity: str          # the default severity of a finding against this rule
    kind: str              # STANDARD, RECOMMENDATION or FLEXLINK
    summary: str           # what the harness checks, in our words
    sources: tuple[Source, ...]

    @property
    def reference(self) -> str:
        """The rule in one line, with its first source's section.

        "FMI 2.0 §x.y: summary" for a requirement of the standard, "robustness recommendation: summary
        (§x.y)" for the others.
        """
        first = self.sources[0]
        number = first.section.split(" ", 1)[0]
        if self.kind == STANDARD:
            return f"{first.standard[:7]} {number}: {self.summary}"
        return f"{self.kind}: {self.summary} ({first.standard[:7]} {number})"

    def quotes(self) -> list[dict]:
        """The quotations as JSON objects (standard, section, text)."""
        return [{"standard": x.standard, "section": x.section, "text": x.quote} for x in self.sources]


def _rule(id, severity, kind, summary, *sources) -> Rule:
    return Rule(id, severity, kind, summary, tuple(Source(*x) for x in sources))


_STATUS2 = "§2.1.3 Status Returned by Functions"
_STATUS3 = "§2.2.4 Status Returned by Functions"
_ME_SM2 = "§3.2.3 State Machine of Calling Sequence"
_CS_SM2 = "§4.2.4 State Machine of Calling Sequence from Master to Slave"
_STATES3 = "§2.3.1 Super State: FMU State Settable"
_STRUCTURE2 = "§2.2.8 Definition of the Model Structure (ModelStructure)"

RULES = {r.id: r for r in [
    _rule("schema", ERROR, STANDARD, "modelDescription.xml follows the schema and its rules (as checked by fmpy "
          "validate)",
          (FMI2, "§2.2 FMI Description Schema", "The normative definition are the above mentioned schema files"),
          (FMI3, "§2.4 FMI Description Schema", "All static information related to the core functionality of an "
           "FMU is stored in the text file modelDescription.xml in XML format as specified by the XML schema file "
           "fmi3ModelDescription.xsd.")),
    _rule("value-reference", ERROR, STANDARD, "a variable's valueReference identifies it in the get/set functions "
          "of the binary",
          (FMI2, "§2.2.7 Definition of Model Variables (ModelVariables)", "The only guarantee is that valueReference "
           "is sufficient to identify the respective variable value in the call of the C functions."),
          (FMI3, "§2.4.7.4 Variable Attributes", "A handle of the variable to identify the variable value in the "
           "C-API functions and for references within the modelDescription.xml.")),
    _rule("outputs-listed", ERROR, STANDARD, "ModelStructure/Outputs lists every variable of causality output",
          (FMI2, _STRUCTURE2, 'every variable with causality="output" must be listed here')),
    _rule("derivatives-listed", ERROR, STANDARD, "ModelStructure/Derivatives lists every state derivative of a "
          "Model Exchange FMU",
          (FMI2, _STRUCTURE2, "A ModelExchange FMU must expose all derivatives of its continuous-time states in "
           "element Derivatives.")),
    _rule("loads", ERROR, STANDARD, "the binary exports the interface's functions and instantiates with the GUID "
          "of its model description",
          (FMI2, "§2.3 FMU Distribution", "Specifically it is required that all functions specified for Model "
           "Exchange and/or Co-Simulation are present, even if they are only needed for capabilities that the FMU "
           "does not support."),
          (FMI3, _STATES3, "It must be passed unchanged to the FMU.")),
    _rule("legal-call", ERROR, STANDARD, "a call allowed by the state machine, with legal arguments, does not fail "
          "(error or fatal)",
          (FMI2, _ME_SM2, "Every implementation of the FMI must support calling sequences of the functions "
           "according to the following state chart"),
          (FMI2, _CS_SM2, "The following state machine defines the supported calling sequences."),
          (FMI3, "§2.3 State Machine and Semantics", "To define allowed calling sequences of FMI functions, state "
           "machines are used.")),
    _rule("wrong-guid", WARNING, RECOMMENDATION, "fmi2Instantiate checks the GUID and gives NULL for a wrong one",
          (FMI2, "§2.1.5 Creation, Destruction and Logging of FMU Instances", "It must be identical to the one "
           "stored inside the fmi2Instantiate function; otherwise the C code and the XML file of the FMU are not "
           "consistent with each other."),
          (FMI3, _STATES3, "instantiationToken can be used by the FMU to check that the modelDescription.xml file "
           "… is compatible with the implementation of the FMU.")),
    _rule("illegal-call", WARNING, RECOMMENDATION, "a call the state machine or the argument rules forbid returns "
          "fmi2Error, after which fmi2Reset revives the instance (FMI 2.0 leaves the behaviour undefined)",
          (FMI2, _ME_SM2, "Calling sequences not accepted by the state chart are not supported by the FMI. The "
           "behavior of an FMU is undefined for such a calling sequence."),
          (FMI2, _STATUS2, "It is also possible to reset the instance of the FMU by calling fmi2Reset.")),
    _rule("state-machine", ERROR, STANDARD, "a call the state machine or the argument rules forbid "
          "returns fmi3Error",
          (FMI3, _STATUS3, "When detecting illegal arguments or a function call not allowed in the current state "
           "according to the respective state machine, the FMU must return fmi3Error."),
          (FMI3, "§4.2.1 State: Step Mode", "communicationStepSize must be > 0.0."),
          (FMI3, "§4.2.1 State: Step Mode", "At the first call of fmi3DoStep, currentCommunicationPoint must be "
           "equal to the argument startTime of fmi3EnterInitializationMode.")),
    _rule("flexlink-contract", ERROR, FLEXLINK, "flexlink FMUs only: every forbidden call returns an error (FMI 3.0's "
          "rule, applied to flexlink's FMI 2.0 FMUs too), every parameter is range-checked",
          (FMI3, _STATUS3, "When detecting illegal arguments or a function call not allowed in the current state "
           "according to the respective state machine, the FMU must return fmi3Error.")),
    _rule("returns", ERROR, RECOMMENDATION, "every call returns: a function reports its outcome as a status, one "
          "that never returns leaves the importer nothing to act on",
          (FMI2, _STATUS2, "This section defines the status flag (an enumeration of type fmi2Status defined in file "
           "fmi2FunctionTypes.h ) that is returned by all functions to indicate the success of the function call"),
          (FMI3, _STATUS3, "This section defines the return values the C-API functions indicating success or "
           "failure of the function call.")),
    _rule("no-crash", ERROR, RECOMMENDATION, "no call crashes the importer's process, whatever its arguments: the "
          "standard has fmi2Fatal for a run-time exception",
          (FMI2, _STATUS2, "fmi2Fatal - the model computations are irreparably corrupted for all FMU instances. "
           "[For example, due to a run-time exception such as access violation or integer division by zero during "
           "the execution of an fmi function]"),
          (FMI3, _STATUS3, "The state of all instances of the model is irreparably corrupted. [For example, due to "
           "a runtime exception such as access violation or integer division by zero during the execution of an "
           "FMI function.]")),
    _rule("fmu-state", ERROR, STANDARD, "setting the FMU state restores the state that was got, and a deserialized "
          "state is that state (canGetAndSetFMUstate, canSerializeFMUstate)",
          (FMI2, "§2.1.8 Getting and Setting the Complete FMU State", "fmi2SetFMUstate copies the content of the "
           "previously copied FMUstate back and uses it as actual new FMU state."),
          (FMI2, "§2.1.8 Getting and Setting the Complete FMU State", "fmi2DeSerializeFMUstate deserializes the "
           "byte vector serializedState of length size, constructs a copy of the FMU state and returns FMUstate, "
           "the pointer to this copy."),
          (FMI3, "§2.2.7.4 Getting and Setting the Complete FMU State", "FMUState must contain all information "
           "required to allow continuing the simulation from the current FMU state without additional FMI C-API "
           "calls.")),
    _rule("reset", ERROR, STANDARD, "reset brings the instance to the state after instantiation",
          (FMI2, "§2.1.6 Initialization, Termination, and Resetting an FMU", "The FMU goes into the same state as "
           "if fmi2Instantiate would have been called. All variables have their default values."),
          (FMI3, _STATES3, "The FMU goes into the same state as if fmi3Instantiate would have been called. All "
           "variables have their default values.")),
    _rule("directional-derivative", ERROR, STANDARD, "the directional derivative function returns the partial "
          "derivatives of the unknowns w.r.t. the knowns (providesDirectionalDerivative)",
          (FMI2, "§2.1.9 Getting Partial Derivatives", "This function computes the directional derivatives of an "
           "FMU."),
          (FMI3, "§2.2.12 Getting Partial Derivatives", "There are two access functions for partial derivatives: … "
           "fmi3GetDirectionalDerivative to compute the directional derivatives …")),
    _rule("me-vs-cs", ERROR, RECOMMENDATION, "consistency: Model Exchange and Co-Simulation of one FMU describe the "
          "same model (tolerance from the FMU's own solver or --tolerance)",
          (FMI2, _STRUCTURE2, "[For example, when exporting a model both in Model Exchange and Co-Simulation "
           "format; then the model structure is identical in both cases. … In both cases the model has the same "
           "continuous-time states.")),
    _rule("finite", ERROR, RECOMMENDATION, "outputs stay finite in a legal run: a numerical failure is reported "
          "by a status",
          (FMI3, _STATUS3, "[Examples for usage of fmi3Discard are … signal numerical problems "
           "during model evaluation forcing smaller step sizes.]")),
    _rule("importer", ERROR, RECOMMENDATION, "interoperability: an independent importer runs the FMU",
          (FMI2, "§1 Overview", "The FMI functions are used (called) by a simulation environment to create one or "
           "more instances of the FMU and to simulate them, typically together with other models."),
          (FMI3, "§1.2 Overview", "The API is used by a simulation environment, the importer, to create one or "
           "more instances of an FMU and to simulate them, typically together with other models.")),
    _rule("importer-warning", WARNING, RECOMMENDATION, "interoperability: an independent importer warns about the "
          "FMU",
          (FMI2, "§1 Overview", "The FMI functions are used (called) by a simulation environment to create one or "
           "more instances of the FMU and to simulate them, typically together with other models.")),
]}


@dataclass
class Finding:
    """One thing wrong with the FMU (see the module docstring)."""

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
        """The rule's one-line reference."""
        return RULES[self.rule].reference

    def as_dict(self) -> dict:
        """The finding as a JSON object, with its rule's reference and quotations."""
        return {"severity": self.severity, "rule": self.rule, "reference": self.reference,
                "quotes": RULES[self.rule].quotes(), "message": self.message, "sequence": self.sequence,
                "reproduce": self.reproduce}

    @classmethod
    def from_dict(cls, d: dict) -> Finding:
        """The finding of ``as_dict``'s object (from a child process's ``FINDING`` line)."""
        return cls(d["rule"], d["message"], d["severity"], list(d.get("sequence", [])), d.get("reproduce", ""))

    def line(self) -> str:
        """One line for the terminal."""
        return f"{self.severity}: {self.message} [{self.rule}]"


@dataclass
class CheckResult:
    """One row of the report, in the style of the FMI cross-check results (input, reference, result).

    It carries the findings behind its status: ``fail`` with an error, ``warn`` with warnings only, ``skip``
    when the FMU does not declare what the check needs (``result`` says why).
    """

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
        """The status the findings give: ``fail``, ``warn`` or ``pass``."""
        if any(f.severity == ERROR for f in self.findings):
            return "fail"
        return "warn" if self.findings else "pass"

    def counts(self) -> tuple[int, int]:
        """The numbers of error and of warning findings."""
        return (sum(f.severity == ERROR for f in self.findings), sum(f.severity == WARNING for f in self.findings))

    def as_dict(self) -> dict:
        """The row as a JSON object, with its findings."""
        return {"name": self.name, "input": self.input, "reference": self.reference, "result": self.result,
                "status": self.status, "seconds": self.seconds, "details": self.details,
                "findings": [f.as_dict() for f in self.findings]}

    @classmethod
    def from_dict(cls, d: dict) -> CheckResult:
        """The row of ``as_dict``'s object (from a child process's ``RESULT`` line)."""
        return cls(d["name"], d["input"], d["reference"], d["result"], d["status"], d["seconds"],
                   list(d["details"]), [Finding.from_dict(x) for x in d["findings"]])


def skipped(name: str, why: str) -> CheckResult:
    """A ``skip`` row that says why."""
    return CheckResult(name, "-", "-", why, "skip")
