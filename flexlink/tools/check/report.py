"""Reports of a check run: files, JSON for stdout, JUnit XML for CI.

``report.json`` and ``report.md`` (cross-check style table), JSON for stdout, and JUnit XML for CI (one test
case per check; an error finding is a failure, a skipped check skipped, warnings in the case's output).
"""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from pathlib import Path

from flexlink.tools.check.findings import RULES, CheckResult


def totals(results: list[CheckResult]) -> tuple[int, int]:
    """(errors, warnings) over all checks."""
    e = w = 0
    for r in results:
        a, b = r.counts()
        e, w = e + a, w + b
    return e, w


def passed(results: list[CheckResult], strict: bool = False) -> bool:
    """No error finding (and, if ``strict``, no warning either)."""
    errors, warnings = totals(results)
    return errors == 0 and not (strict and warnings)


def as_json(results: list[CheckResult], fmu: str, strict: bool = False) -> dict:
    """The run as a JSON object: the verdict, the counts, and every check with its findings."""
    errors, warnings = totals(results)
    return {"fmu": os.fspath(fmu), "passed": passed(results, strict), "strict": strict, "errors": errors,
            "warnings": warnings, "checks": [r.as_dict() for r in results]}


def write_report(results: list[CheckResult], directory: str | os.PathLike, fmu: str,
                 strict: bool = False) -> tuple[Path, Path]:
    """``report.json`` and ``report.md`` (a cross-check style table: input, reference, result, status)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    data = as_json(results, fmu, strict)
    j = d / "report.json"
    j.write_text(json.dumps(data, indent=2) + "\n")
    lines = [f"# flexlink check: {os.path.basename(fmu)}", "",
             f"Overall: **{'passed' if data['passed'] else 'FAILED'}** ({data['errors']} error(s), "
             f"{data['warnings']} warning(s))", "",
             "| check | input | reference | result | status | time (s) |", "| --- | --- | --- | --- | --- | --- |"]
    for r in results:
        cells = [r.name, r.input, r.reference, r.result, r.status.upper() if r.status == "fail" else r.status,
                 f"{r.seconds:.2f}"]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    for r in results:
        if r.findings:
            lines += ["", f"## {r.name}", ""]
            for x in r.findings:
                lines.append(f"- **{x.severity}**: {x.message}  \n  rule: {x.reference}"
                             + (f"  \n  calls: `{' ; '.join(x.sequence)}`" if x.sequence else "")
                             + (f"  \n  reproduce: `{x.reproduce}`" if x.reproduce else ""))
    cited = sorted({x.rule for r in results for x in r.findings})
    if cited:
        lines += ["", "## Rules cited", "", "Quoted from the FMI specifications (Modelica Association Project FMI, "
                  "CC-BY-SA 4.0).", ""]
        for rule in cited:
            lines.append(f"- `{rule}` ({RULES[rule].kind}): {RULES[rule].summary}")
            lines += [f"  - {s.cite()}" for s in RULES[rule].sources]
    m = d / "report.md"
    m.write_text("\n".join(lines) + "\n")
    return j, m


def write_junit(results: list[CheckResult], path: str | os.PathLike, fmu: str) -> Path:
    """JUnit XML: a test suite named after the FMU, a test case per check."""
    suite = ET.Element("testsuite", name=f"flexlink check {os.path.basename(fmu)}", tests=str(len(results)),
                       failures=str(sum(r.status == "fail" for r in results)),
                       skipped=str(sum(r.status == "skip" for r in results)),
                       time=f"{sum(r.seconds for r in results):.3f}")
    for r in results:
        case = ET.SubElement(suite, "testcase", classname="flexlink.check", name=r.name, time=f"{r.seconds:.3f}")
        if r.status == "skip":
            ET.SubElement(case, "skipped", message=r.result)
        bad = [x for x in r.findings if x.severity == "error"]
        if bad:
            fail = ET.SubElement(case, "failure", message=bad[0].message, type=bad[0].rule)
            fail.text = "\n".join(f"{x.line()}\n  {x.reference}\n  calls: {' ; '.join(x.sequence)}" for x in bad)
        warn = [x for x in r.findings if x.severity == "warning"]
        if warn:
            ET.SubElement(case, "system-out").text = "\n".join(x.line() for x in warn)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    root = ET.Element("testsuites")
    root.append(suite)
    ET.ElementTree(root).write(p, encoding="utf-8", xml_declaration=True)
    return p
