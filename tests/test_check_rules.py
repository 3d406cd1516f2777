"""Every rule ``flexlink check`` can cite carries the standard's own words: a quotation with its version and
section (flexlink/tools/check/findings.py), shown in docs/check.md.  With ``FMI_STANDARD_DOCS`` set to a
folder holding the specification's asciidoc sources (``v2.0.5/docs``, ``v3.0.2/docs``, from
github.com/modelica/fmi-standard) every quotation is also found there word for word."""

from __future__ import annotations

import ast
import os
import re
from pathlib import Path

import pytest

from flexlink.tools.check.findings import FLEXLINK, FMI2, FMI3, RECOMMENDATION, RULES, STANDARD

ROOT = Path(__file__).resolve().parents[1]
CHECK = ROOT / "flexlink" / "tools" / "check"


def _cited_rules() -> set[str]:
    """The rule of every ``Finding(...)`` the check modules can make: a string, either branch of an
    ``a if c else b``, a name bound to such an expression, or to a call of a function of the same module whose
    returns are such expressions."""
    def strings(node, names):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            return {node.value}
        if isinstance(node, ast.IfExp):
            return strings(node.body, names) | strings(node.orelse, names)
        if isinstance(node, ast.Name) and node.id in names:
            return names[node.id]
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) in names:
            return names[node.func.id]
        raise AssertionError(f"a Finding whose rule cannot be read: {ast.dump(node)}")

    def readable(node, names):
        try:
            return strings(node, names)
        except AssertionError:
            return None

    cited = set()
    for path in CHECK.glob("*.py"):
        tree = ast.parse(path.read_text())
        names: dict[str, set[str]] = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef):
                returns = [readable(r.value, {}) for r in ast.walk(node) if isinstance(r, ast.Return) and r.value]
                if returns and all(x is not None for x in returns):
                    names[node.name] = set().union(*returns)
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
                value = readable(node.value, names)
                if value is not None:
                    names[node.targets[0].id] = value
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Finding" and node.args:
                cited |= strings(node.args[0], names)
    return cited


def test_every_rule_a_finding_can_cite_is_defined_and_quoted():
    cited = _cited_rules()
    assert {"legal-call", "returns", "no-crash", "illegal-call", "state-machine"} <= cited
    assert cited <= set(RULES), cited - set(RULES)
    for rule in RULES.values():
        assert rule.kind in (STANDARD, RECOMMENDATION, FLEXLINK) and rule.severity in ("error", "warning")
        assert rule.sources, rule.id
        for s in rule.sources:
            assert s.standard in (FMI2, FMI3)
            assert re.fullmatch(r"§\d+(\.\d+)* \S.*", s.section), (rule.id, s.section)
            assert len(s.quote.split()) >= 5, (rule.id, s.quote)
        if rule.kind == STANDARD:
            assert rule.reference.startswith(("FMI 2.0 §", "FMI 3.0 §")), rule.reference


def test_docs_quote_every_rule_with_its_section():
    text = (ROOT / "docs" / "check.md").read_text()
    assert "CC-BY-SA 4.0" in text
    for rule in RULES.values():
        row = next((line for line in text.splitlines() if line.startswith(f"| `{rule.id}` | {rule.kind}, ")), None)
        assert row is not None, rule.id
        for s in rule.sources:
            assert f"{s.standard} {s.section}: \u201c{s.quote}\u201d" in row, (rule.id, s.section)


def _normalised(text: str) -> str:
    """Asciidoc to the words a reader sees: cross-references to their label, anchors, passthroughs, code
    quotes, italics and line continuations dropped; whitespace collapsed."""
    text = re.sub(r"<<[^,>]+,\s*`?([^`>]+)`?>>", r"\1", text)
    text = re.sub(r"<<([^>]+)>>", r"\1", text)
    text = re.sub(r"\[\[[^\]]*\]\]", "", text)
    text = re.sub(r"pass:\[([^\]]*)\]", r"\1", text)
    text = re.sub(r"latexmath:\[([^\]]*)\]", r"\1", text)
    text = text.replace("`", "").replace("_", " ").replace(" +\n", " ")
    return re.sub(r"\s+", " ", text)


@pytest.mark.skipif(not os.environ.get("FMI_STANDARD_DOCS"), reason="FMI_STANDARD_DOCS not set (the "
                    "specification's asciidoc sources are not part of this repository)")
def test_every_quotation_is_the_standards_own_words():
    root = Path(os.environ["FMI_STANDARD_DOCS"])
    texts = {version: _normalised(" ".join(p.read_text() for p in (root / folder / "docs").glob("*.adoc")))
             for version, folder in ((FMI2, "v2.0.5"), (FMI3, "v3.0.2"))}
    missing = []
    for rule in RULES.values():
        for s in rule.sources:
            for part in s.quote.replace("_", " ").split("\u2026"):
                part = re.sub(r"\s+", " ", part).strip(" []")
                if part and part not in texts[s.standard]:
                    missing.append((rule.id, s.standard, part))
    assert missing == []
