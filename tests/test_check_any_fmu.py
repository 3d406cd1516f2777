"""``flexlink check`` on FMUs that flexlink did not build (tests/check_fmus.py, from tests/c/check_fmu/model.c):
correct ones of every shape pass with no error, and each planted defect is caught by the check that claims
it, with the rule it breaks; the command line's options, output formats and exit codes."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from check_fmus import BALL, CAPABILITIES, LOW_BALL_HEIGHT, build

from flexlink.cli import main
from flexlink.tools.check import check_fmu

CALL_LIMIT = 3.0


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("check_fmus")
    cache = {}

    def get(name, **kwargs):
        if name not in cache:
            cache[name] = build(d, name, **kwargs)
        return cache[name]

    return get


def _by_name(results):
    return {r.name: r for r in results}


def _run(path, **kwargs):
    kwargs = {"fuzz": 16, "importers": False, "call_limit": CALL_LIMIT, **kwargs}
    return _by_name(check_fmu(path, **kwargs))


@pytest.mark.parametrize("variant, interfaces", [
    ("oscillator", ("CS", "ME")), ("oscillator", ("CS",)), ("oscillator", ("ME",)), ("typed", ("CS", "ME")),
    ("nostates", ("CS", "ME")), ("stair", ("CS", "ME")), ("ball", ("CS", "ME"))])
def test_a_correct_fmu_passes_with_no_finding(fmus, variant, interfaces):
    """Every shape the issue names: CS-only, ME-only, Integer/Boolean/Enumeration/String variables, no states
    and no Real outputs, a discrete model with time events, a model with state events (the bouncing ball).  No
    finding at all (not even a warning)."""
    path = fmus(f"{variant}_{''.join(interfaces)}", variant=variant, interfaces=interfaces)
    res = _run(path)
    for r in res.values():
        assert r.status in ("pass", "skip"), (r.name, r.result, [x.line() for x in r.findings])
    ran = {n for n, r in res.items() if r.status == "pass"}
    assert {"model-description", "fuzz", "fmu-state", "illegal-calls"} <= ran
    assert ("me-vs-cs" in ran) == (len(interfaces) == 2)


def test_what_is_not_declared_is_not_called(fmus):
    """Without providesDirectionalDerivative and FMU state capabilities those checks skip, saying why, and no
    check calls them: the binary (NO_OPTIONAL) returns fmi2Error from them, as it may."""
    path = fmus("plain", capabilities=("canHandleVariableCommunicationStepSize",), defects=("NO_OPTIONAL",))
    res = _run(path)
    assert res["directional-derivatives"].status == "skip"
    assert "providesDirectionalDerivative" in res["directional-derivatives"].result
    assert res["fmu-state"].status == "pass" and "not declared" in res["fmu-state"].input
    assert all(r.status != "fail" for r in res.values()) and not any(r.findings for r in res.values())
    declared = _run(fmus("plain_but_declared", defects=("NO_OPTIONAL",)), only=["fuzz", "fmu-state"])
    assert all(r.status == "fail" for r in declared.values())          # the same binary, flags true


def test_a_fixed_communication_step_is_respected(fmus):
    """Without canHandleVariableCommunicationStepSize every check steps by the default experiment's 0.01 s,
    which this binary (FIXED_COMM_STEP) insists on; the same binary declaring the flag fails the fuzz."""
    fixed = _run(fmus("fixed_step", defects=("FIXED_COMM_STEP",), capabilities=CAPABILITIES[1:]))
    assert all(r.status in ("pass", "skip") for r in fixed.values()), [(r.name, r.result) for r in fixed.values()]
    assert not any(r.findings for r in fixed.values())
    variable = _run(fmus("fixed_step_declared_variable", defects=("FIXED_COMM_STEP",)), only=["fuzz"])
    assert variable["fuzz"].status == "fail"


def test_the_fuzz_locates_state_events(fmus, monkeypatch):
    """The ball from 1 mm (check_fmus.LOW_BALL_HEIGHT) reaches the floor within a fuzz sequence; it refuses a
    completed integrator step below the floor (fmi2Error: a state event stepped over).  The fuzz's Model
    Exchange steps locate the zero crossing of its event indicator and handle the event: no finding, events
    located, and each sequence's first one at the analytic time of the fall, sqrt(2 h / (g - u)) with the
    input u of 0 or 0.1 the fuzz may set.  With the crossings not looked for (in-process, the fuzz's crossing
    test switched off) the same sequences step over the floor and the ball says so."""
    from flexlink.tools.check import fuzz
    from flexlink.tools.check.fmu import Fmu

    n = 30
    path = fmus("low_ball", variant="low_ball")
    r = _run(path, only=["fuzz"], fuzz=n)["fuzz"]
    assert not r.findings, [x.line() for x in r.findings]
    assert int(r.result.rsplit(", ", 1)[1].split(" state event")[0]) >= 3
    f = Fmu(path, ("CS", "ME"))
    try:
        fuzzer = fuzz.Fuzzer(f, 0)
        for k in range(n):
            fuzzer.legal_sequence(k)
        assert not fuzzer.findings
        first = {}
        for k, t in fuzzer.state_events:
            first.setdefault(k, t)
        falls = [np.sqrt(2 * LOW_BALL_HEIGHT / (BALL["g"] - u)) for u in (0.0, 0.1)]
        assert len(first) >= 3 and all(falls[0] - 1e-9 <= t <= falls[1] + 1e-9 for t in first.values()), first
        monkeypatch.setattr(fuzz, "_crossing", lambda z0, z: np.zeros(len(z), dtype=bool))
        blind = fuzz.check_fuzz(f, n, 0)
    finally:
        f.close()
    assert blind.findings and blind.findings[0].message.endswith("completedIntegratorStep: status 3")


def test_a_call_that_never_returns_is_reported_with_its_seconds(fmus, tmp_path, monkeypatch):
    """fmi2DoStep(t, NaN) loops for ever: one error naming the call and its seconds, the rest of the
    catalogue still run (resumed after it); the killed child's temporary files are removed all the same."""
    import tempfile

    path = fmus("nan_hang", defects=("DEFECT_NAN_HANG",))
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setenv("TMPDIR", str(scratch))
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    res = _run(path, only=["illegal-calls"])
    assert list(scratch.iterdir()) == []
    r = res["illegal-calls"]
    assert r.status == "fail"
    (hang,) = [x for x in r.findings if x.rule == "returns"]
    assert hang.message.startswith("fmi2DoStep(0.0, nan") and "did not return within" in hang.message
    assert float(hang.message.split("within ")[1].split(" s")[0]) >= CALL_LIMIT
    assert hang.sequence[-1].startswith("fmi2DoStep(0.0, nan")
    assert r.counts() == (1, 0)                        # nothing else is wrong with it
    assert "1 call(s) that hang or crash" in r.result


def test_a_legal_call_that_hangs_ends_one_fuzz_sequence_not_the_fuzz(fmus):
    """The fixture's third fmi2DoStep after instantiation sleeps for ever (DEFECT_STEP_HANG, STEP_HANG 3 in
    model.c), a legal call: each sequence that reaches it is one error naming that call, its seconds and its
    sequence, and the fuzz goes on in a fresh process with the next sequence, to the last one.  The hung
    sequences are exactly the CS ones (even indices) with three doSteps in one instance; the reproduction
    replays the first alone (each sequence has its own seeded generator)."""
    n = 30
    path = fmus("step_hang", defects=("DEFECT_STEP_HANG",))
    r = _run(path, only=["fuzz"], fuzz=n)["fuzz"]
    hangs = [x for x in r.findings if x.rule == "returns"]
    assert r.findings == hangs and len(hangs) >= 2
    items = []
    for x in hangs:
        assert x.message.startswith("fmi2DoStep(") and "did not return within" in x.message
        assert float(x.message.split("within ")[1].split(" s")[0]) >= CALL_LIMIT
        items.append(int(x.message.rsplit("(sequence ", 1)[1].rstrip(")")))
        calls = x.sequence[max(i for i, c in enumerate(x.sequence) if c.startswith(("fmi2Instantiate",
                                                                                     "fmi2Reset"))):]
        assert calls[0].startswith("fmi2Instantiate") and calls[-1] == x.message.split(" did not")[0]
        assert sum(c.startswith("fmi2DoStep") for c in calls) == 3
    assert all(k % 2 == 0 for k in items) and items == sorted(set(items))
    assert f"sequences {items[-1] + 1}..{n - 1} in the last process" in r.result
    assert f"{len(hangs)} call(s) that hang or crash (sequence {', '.join(map(str, items))}" in r.result
    assert hangs[0].reproduce.endswith(f"--only fuzz --fuzz {items[0] + 1} --seed 0 --call-timeout {CALL_LIMIT:g}")
    replay = _run(path, only=["fuzz"], fuzz=items[0] + 1)["fuzz"]
    assert [x.message.split(" did not")[0] for x in replay.findings] == [hangs[0].message.split(" did not")[0]]
    assert not _run(fmus("oscillator_CSME", variant="oscillator"), only=["fuzz"], fuzz=n)["fuzz"].findings


def test_a_repeated_finding_is_reported_once_across_resumed_processes(fmus):
    """A binary that hangs in its third doStep (DEFECT_STEP_HANG) and refuses the directional derivatives it
    declares (NO_OPTIONAL): the fuzz resumes in a fresh process after each hang, and
    each kind of refusal (call and status) is still reported once for the whole fuzz, not once per process:
    the later processes are handed what the earlier ones found, and the limit on findings counts them too."""
    path = fmus("hang_and_refuse", defects=("DEFECT_STEP_HANG", "NO_OPTIONAL"),
                capabilities=("canHandleVariableCommunicationStepSize", "providesDirectionalDerivative"))
    r = _run(path, only=["fuzz"], fuzz=60, seed=1)["fuzz"]          # seed 1: hangs in 3 sequences
    hangs = [x for x in r.findings if x.rule == "returns"]
    assert len(hangs) >= 2, r.result                                 # three processes at least
    refusals = [x.message.split(": ", 1)[1] for x in r.findings if x.rule != "returns"]
    kinds = [m.split("(")[0] + m.rsplit(":", 1)[1] if m.endswith(tuple("01234")) else m for m in refusals]
    assert sum(k.startswith("getDirectionalDerivative") for k in kinds) == 1, refusals   # 3 without the carry
    assert len(kinds) == len(set(kinds)), refusals


def test_a_crash_ends_one_item_not_the_harness(fmus):
    """fmi2GetReal of an unknown value reference segfaults: an error naming the signal and the call; the
    other checks run and pass."""
    res = _run(fmus("crash", defects=("DEFECT_CRASH",)))
    r = res["illegal-calls"]
    (crash,) = [x for x in r.findings if x.rule == "no-crash"]
    assert "SIGSEGV" in crash.message and "fmi2GetReal([1000007]" in crash.message
    assert r.counts() == (1, 0)
    assert all(res[n].status == "pass" for n in ("model-description", "fuzz", "fmu-state", "me-vs-cs"))


def test_a_wrong_directional_derivative_is_caught(fmus):
    res = _run(fmus("wrong_derivative", defects=("DEFECT_WRONG_DERIVATIVE",)), only=["directional-derivatives"])
    r = res["directional-derivatives"]
    assert r.status == "fail"
    assert {x.rule for x in r.findings} == {"directional-derivative"}
    assert any("directional 4, differences -4" in x.message for x in r.findings)


def test_a_state_restore_that_does_not_restore_is_caught(fmus):
    res = _run(fmus("state_restore", defects=("DEFECT_STATE_RESTORE",)), only=["fmu-state"])
    messages = [x.message for x in res["fmu-state"].findings]
    assert res["fmu-state"].status == "fail"
    assert any(m.startswith("CS: get/set FMU state does not reproduce") for m in messages)
    assert any(m.startswith("ME: a serialized FMU state does not restore") for m in messages)


def test_an_accepted_illegal_call_is_a_warning_and_counts_with_strict(fmus, tmp_path, capsys):
    """doStep before initialization returns fmi2OK: a warning (FMI 2.0 leaves the calling sequence to the
    importer), exit 0; exit 1 with --strict."""
    path = fmus("accepts_illegal", defects=("DEFECT_ACCEPTS_ILLEGAL",))
    res = _run(path, only=["illegal-calls"])
    r = res["illegal-calls"]
    assert r.status == "warn" and r.counts()[0] == 0
    assert any("doStep before initialization" in x.message and x.rule == "illegal-call" for x in r.findings)
    args = [str(path), "--only", "illegal-calls", "--call-timeout", str(CALL_LIMIT)]
    assert main(["check", *args]) == 0
    assert main(["check", *args, "--strict"]) == 1
    assert "warnings count" in capsys.readouterr().out


def test_a_wrong_guid_accepted_is_a_warning(fmus):
    r = _run(fmus("any_guid", defects=("DEFECT_ANY_GUID",)), only=["illegal-calls"])["illegal-calls"]
    assert [x.rule for x in r.findings] == ["wrong-guid"]


def test_me_vs_cs_is_measured_unless_a_tolerance_is_given(fmus):
    """The oscillator's CS is explicit Euler at 1 ms: ME and CS differ by about 1e-3 of the peak.  Without a
    tolerance that is reported, not judged; --tolerance 1e-2 passes it and 1e-4 fails it."""
    path = fmus("oscillator_CSME", variant="oscillator")
    measured = _run(path, only=["me-vs-cs"])["me-vs-cs"]
    assert measured.status == "pass" and "not judged" in measured.reference
    worst = float(measured.result.split(": ")[1].split(" ")[0])
    assert 1e-4 < worst < 1e-2
    assert _run(path, only=["me-vs-cs"], tolerance=1e-2)["me-vs-cs"].status == "pass"
    strict = _run(path, only=["me-vs-cs"], tolerance=1e-4)["me-vs-cs"]
    assert strict.status == "fail" and {x.rule for x in strict.findings} == {"me-vs-cs"}


def _bounces(stop: float, u: float) -> tuple[list[float], object]:
    """The ball of check_fmus.BALL under gravity less the input u: its bounce times before ``stop`` and its
    height h(t) (free fall from rest, each flight 2 e^k v1 / g long, v1 = g t1)."""
    g, e, h0 = BALL["g"] - u, BALL["restitution"], BALL["height"]
    t1 = (2.0 * h0 / g) ** 0.5
    times = [t1]
    while times[-1] + 2.0 * e ** len(times) * t1 < stop:
        times.append(times[-1] + 2.0 * e ** len(times) * t1)

    def height(t):
        t = np.asarray(t, float)
        out = h0 - 0.5 * g * t**2
        for k, tb in enumerate(times, 1):
            after = t >= tb
            v = e**k * g * t1                      # speed upwards after the k-th bounce
            out = np.where(after, v * (t - tb) - 0.5 * g * (t - tb) ** 2, out)
        return out

    return times, height


def test_me_vs_cs_locates_state_events(fmus):
    """A bouncing ball (one event indicator, its height; model.c's BALL): the ME run of me-vs-cs (fmpy: CVODE
    root finding, then the event iteration with fmi2NewDiscreteStates) locates every bounce at its analytic
    time, and its heights follow the analytic parabolas through the bounces.  An integration that ignored the
    indicator would let the ball fall through the floor (h(2 s) = -18.4 m instead of 0.12 m).  CS (explicit
    Euler at 1 ms, bouncing after the step that crosses the floor) is measured against it, not judged."""
    from flexlink.tools.check.fmu import Fmu
    from flexlink.tools.check.me_vs_cs import _simulate

    path = fmus("ball_CSME", variant="ball")
    stop, u = 2.0, 0.1                             # the harness's excitation: the input at start + 0.1
    times, height = _bounces(stop, u)
    r = _run(path, only=["me-vs-cs"], stop_time=stop)["me-vs-cs"]
    assert r.status == "pass" and "not judged" in r.reference and f"ME: {len(times)} state event(s)" in r.result
    located = [float(t) for t in r.details[0].split("t = ")[1].split(", ")]
    assert len(times) == 4 and np.allclose(located, times, rtol=0, atol=1e-7), (located, times)
    f = Fmu(path)
    try:
        me, cs, events = _simulate(f, stop, stop / 500, {"u": u}, None, 0.0, 1e-9)
    finally:
        f.close()
    assert np.allclose(events, times, rtol=0, atol=1e-7)
    assert np.max(np.abs(me["x"] - height(me["time"]))) < 1e-6
    assert 1e-3 < np.max(np.abs(cs["x"] - height(cs["time"]))) < 5e-2       # Euler at 1 ms: measured only


def test_json_and_junit_output(fmus, tmp_path, capsys):
    path = fmus("state_restore", defects=("DEFECT_STATE_RESTORE",))
    junit = tmp_path / "junit.xml"
    code = main(["check", str(path), "--skip", "fuzz,me-vs-cs,libcosim,fmutool", "--interface", "cs", "--json",
                 "--junit", str(junit)])
    assert code == 1
    data = json.loads(capsys.readouterr().out)
    assert not data["passed"] and data["errors"] >= 1
    state = next(c for c in data["checks"] if c["name"] == "fmu-state")
    assert state["findings"][0]["reference"].startswith("FMI 2.0 §2.1.8")
    assert state["findings"][0]["quotes"][0] == {"standard": "FMI 2.0.5", "section": "§2.1.8 Getting and Setting "
                                                 "the Complete FMU State", "text": "fmi2SetFMUstate copies the content "
                                                 "of the previously copied FMUstate back and uses it as actual new FMU "
                                                 "state."}
    assert {c["name"] for c in data["checks"]} == {"model-description", "fmu-state", "directional-derivatives",
                                                   "illegal-calls"}
    suite = ET.parse(junit).getroot().find("testsuite")
    cases = {c.get("name"): c for c in suite.findall("testcase")}
    assert cases["fmu-state"].find("failure") is not None
    assert cases["model-description"].find("failure") is None


@pytest.mark.parametrize("args, message", [
    (["--only", "nonsense"], "unknown check nonsense"),
    (["--interface", "cs"], "has no CS interface"),
    (["--tolerance", "0"], "--tolerance 0.0: must be a positive number"),
    (["--call-timeout", "-1"], "--call-timeout -1.0: must be a positive number of seconds"),
])
def test_bad_input_is_one_line_and_exit_2(fmus, capsys, args, message):
    path = fmus("oscillator_ME", variant="oscillator", interfaces=("ME",))
    assert main(["check", str(path), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_not_an_fmu_is_one_line_and_exit_2(tmp_path, capsys):
    junk = tmp_path / "junk.fmu"
    junk.write_text("not a zip")
    assert main(["check", str(junk)]) == 2
    assert "not an FMU" in capsys.readouterr().err


def test_an_importers_known_parser_bug_is_not_a_failure(fmus):
    """FMI Library (in libcosim) asks for a start value on the independent `time` variable, which FMI 2.0
    forbids: with every other start present that line is known noise and the run passes."""
    pytest.importorskip("libcosimpy")
    r = _run(fmus("oscillator_CSME", variant="oscillator"), only=["libcosim"], importers=True)["libcosim"]
    assert r.status == "pass", [x.line() for x in r.findings]
    assert any("Start attribute is required" in d and "(known:" in d for d in r.details)


def test_the_same_log_line_is_a_warning_when_a_start_is_really_missing(fmus):
    """The input u without its start value: the same FMI Library line may now be about u, so it counts."""
    pytest.importorskip("libcosimpy")
    path = fmus("no_start", xml_edit=lambda x: x.replace('valueReference="4" causality="input" '
                                                         'variability="continuous"><Real start="0"/>',
                                                         'valueReference="4" causality="input" '
                                                         'variability="continuous"><Real/>'))
    r = _run(path, only=["libcosim"], importers=True)["libcosim"]
    assert r.status == "warn"
    assert {x.rule for x in r.findings} == {"importer-warning"}
    assert any("Start attribute is required" in x.message for x in r.findings)


def test_docs_name_every_check_and_rule():
    """docs/check.md's tables cover every check of the driver and every rule a finding may name."""
    from pathlib import Path

    from flexlink.tools.check.driver import NAMES
    from flexlink.tools.check.findings import RULES

    text = (Path(__file__).resolve().parents[1] / "docs" / "check.md").read_text()
    assert [n for n in NAMES if f"| `{n}` |" not in text] == []
    assert [r for r in RULES if f"| `{r}` |" not in text] == []


def test_an_unreadable_or_unrunnable_fmu_is_one_line_and_exit_2(fmus, tmp_path, capsys):
    """Broken XML; no binary for this platform (nothing could be run, so no check could pass honestly)."""
    import zipfile

    bad_xml = fmus("bad_xml", xml_edit=lambda x: x.replace("</ModelVariables>", "</ModelVariable>"))
    good = fmus("oscillator_CSME", variant="oscillator")
    no_binary = tmp_path / "no_binary.fmu"
    with zipfile.ZipFile(good) as zin, zipfile.ZipFile(no_binary, "w") as zout:
        for item in zin.infolist():
            if not item.filename.startswith("binaries/"):
                zout.writestr(item, zin.read(item.filename))
    for path, message in ((bad_xml, "unreadable modelDescription.xml"), (no_binary, "no binaries/linux64/")):
        assert main(["check", str(path)]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1


def test_a_value_reference_the_binary_does_not_know_is_caught(fmus, tmp_path):
    """y's value reference changed to 40 in the XML only (fmpy's validation cannot notice): the read-back
    through the binary names it, in each interface; the report gives the rule's FMI reference."""
    from flexlink.tools.check import write_report

    path = fmus("bad_vr", xml_edit=lambda x: x.replace('name="y" valueReference="6"', 'name="y" valueReference="40"'))
    results = check_fmu(path, only=["model-description"], importers=False)
    r = results[0]
    assert r.status == "fail"
    assert sorted(x.message.split(":")[0] for x in r.findings if x.rule == "value-reference") == ["CS", "ME"]
    assert all("40 of y (Real)" in x.message for x in r.findings)
    write_report(results, tmp_path / "report", str(path))
    md = (tmp_path / "report" / "report.md").read_text()
    assert "FAILED" in md and "rule: FMI 2.0 §2.2.7" in md
    assert "FMI 2.0.5 §2.2.7 Definition of Model Variables (ModelVariables): \u201cThe only guarantee is" in md


@pytest.fixture(scope="module")
def foreign_fmi3(tmp_path_factory):
    """``foreign_fmi3(defect)``: examples/rotating_link.toml as an FMI 3.0 FMU that does not say it is flexlink's
    (generationTool changed, so only FMI 3.0's own rules apply), its binary rebuilt from its own sources with
    ``defect`` (C code) at the start of fmi3DoStep."""
    import re
    import zipfile

    from conftest import EXAMPLES

    from flexlink.export.cbuild import compile_shared_library
    from flexlink.export.fmu import build_fmu

    d = tmp_path_factory.mktemp("foreign_fmi3")
    original = build_fmu(EXAMPLES / "rotating_link.toml", d / "rotating_link.fmu", fmi_version=3).fmu

    def get(name: str, defect: str = ""):
        src = d / name
        with zipfile.ZipFile(original) as z:
            z.extractall(src)
        xml = src / "modelDescription.xml"
        xml.write_text(re.sub(r'generationTool="[^"]*"', 'generationTool="another tool"', xml.read_text()))
        if defect:
            c = src / "sources" / "fmi3Functions.c"
            text = c.read_text()
            head = re.search(r"fmi3Status fmi3DoStep\(fmi3Instance instance,[^{]*\{\n", text)
            c.write_text(text[:head.end()] + f"    {defect}\n" + text[head.end():])
            so = next((src / "binaries").glob("*/*.so"))
            compile_shared_library(sorted((src / "sources").glob("*.c")), [src / "sources"], so)
        fmu = d / f"{name}.fmu"
        with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as z:
            for p in sorted(src.rglob("*")):
                if p.is_file():
                    z.write(p, p.relative_to(src).as_posix())
        return fmu

    return get


def test_fmi3_an_accepted_illegal_call_is_an_error(foreign_fmi3):
    """FMI 3.0 §2.2.4: "When detecting illegal arguments or a function call not allowed in the current state
    ..., the FMU must return fmi3Error."  The FMI 3.0 FMU, not recognised as flexlink's, refuses every call of
    the catalogue (no finding); with fmi3DoStep accepting a zero step it is one error of rule state-machine
    (under FMI 2.0 the same acceptance would be a warning)."""
    from flexlink.tools.check.findings import RULES

    clean = _run(foreign_fmi3("clean"), only=["illegal-calls"])["illegal-calls"]
    assert clean.status == "pass" and not clean.findings, [x.line() for x in clean.findings]
    assert "forbidden calls on CS, ME" in clean.input
    bad = _run(foreign_fmi3("zero_step", "if (communicationStepSize == 0.0) return fmi3OK;"),
               only=["illegal-calls"])["illegal-calls"]
    assert [(x.rule, x.severity) for x in bad.findings] == [("state-machine", "error")]
    assert "'doStep with a zero step' (CS): expected fmi3Error (3), got 0" in bad.findings[0].message
    assert "must return fmi3Error" in RULES["state-machine"].sources[0].quote


CLOCKED_FMI3 = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="clocked" instantiationToken="{clocked}">
  <CoSimulation modelIdentifier="clocked" hasEventMode="true"/>
  <ScheduledExecution modelIdentifier="clocked"/>
  <ModelVariables>
    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>
    <UInt64 name="n" valueReference="1" causality="structuralParameter" variability="fixed" start="3"/>
    <Clock name="tick" valueReference="2" causality="input" intervalVariability="constant" intervalDecimal="0.1"/>
    <Float64 name="y" valueReference="3" causality="output" variability="discrete" clocks="2"/>
  </ModelVariables>
  <ModelStructure><Output valueReference="3"/></ModelStructure>
</fmiModelDescription>
"""


def test_what_fmi3_declares_and_no_check_covers_is_said(fmus, tmp_path):
    """An FMI 3.0 model description with a Clock, a clocked output, a structural parameter and Scheduled
    Execution (a hand-written XML, no binary: nothing of it is run): the report has one ``skip`` row for each
    of the three features, naming what is declared and why no check covers it; they are notes and change
    nothing in the exit status.  An FMI 2.0 FMU gets none."""
    import zipfile

    from flexlink.tools.check.driver import NAMES
    from flexlink.tools.check.report import passed

    path = tmp_path / "clocked.fmu"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("modelDescription.xml", CLOCKED_FMI3)
    res = check_fmu(path, skip=NAMES)
    assert [(r.name, r.status) for r in res] == [("clocks", "skip"), ("configuration-mode", "skip"),
                                                 ("scheduled-execution", "skip")]
    clocks, configuration, scheduled = (r.result for r in res)
    assert "1 Clock(s) (tick), 1 clocked variable(s): not covered" in clocks
    assert "1 structural parameter(s) (n)" in configuration and "fmi3EnterConfigurationMode" in configuration
    assert "<ScheduledExecution> declared: not covered" in scheduled
    assert passed(res) and not any(r.findings for r in res)
    assert check_fmu(fmus("oscillator_CSME", variant="oscillator"), skip=NAMES) == []
