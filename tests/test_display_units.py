"""Model description polish: display units on the variables a user reads or sets (angles in deg, rates in
deg/s with rpm offered, tip deflections in mm), and generationTool / generationDateAndTime, checked by fmpy's
validation (the FMI 2.0 schema types generationDateAndTime as xs:dateTime; fmpy reports undefined display
units) and against conversion factors computed here."""

from __future__ import annotations

import math
from datetime import datetime

import fmpy
import pytest
from fmpy.validation import validate_fmu

import flexlink
from flexlink.errors import BuildError
from flexlink.export.description import generation_date_and_time

SCENES = ["rotating_link", "flexible_pendulum"]
FACTORS = {"deg": math.degrees(1.0), "deg/s": math.degrees(1.0), "rpm": 60.0 / (2.0 * math.pi), "mm": 1000.0}


@pytest.mark.parametrize("name", SCENES)
def test_display_units_are_defined_and_convert_correctly(example_fmu, name):
    fmu = example_fmu(name)
    assert validate_fmu(str(fmu)) == []
    md = fmpy.read_model_description(str(fmu))
    factor = {(u.name, d.name): d.factor for u in md.unitDefinitions for d in u.displayUnits}
    shown = {}
    for v in md.modelVariables:
        if v.causality == "local":
            assert v.displayUnit is None, v.name            # the Model Exchange states stay as they are
            continue
        expected = {"rad": "deg", "rad/s": "deg/s"}.get(v.unit)
        if v.unit == "m" and "deflection" in (v.description or ""):
            expected = "mm"
        assert v.displayUnit == expected, v.name
        if expected:
            shown[v.name] = expected
            assert float(factor[(v.unit, expected)]) == pytest.approx(FACTORS[expected], rel=1e-15)
    assert float(factor[("rad/s", "rpm")]) == pytest.approx(FACTORS["rpm"], rel=1e-15)
    # the variables a user reads are among them: the first joint's angle and rate, a tip deflection
    joint = next(v.name for v in md.modelVariables if v.name.endswith(".theta") and v.causality == "output")
    assert shown[joint] == "deg" and shown[joint.replace(".theta", ".omega")] == "deg/s"
    assert "mm" in shown.values()


@pytest.mark.parametrize("name", SCENES)
def test_generation_tool_and_date(example_fmu, name):
    md = fmpy.read_model_description(str(example_fmu(name)))
    assert md.generationTool == f"flexlink {flexlink.__version__}"
    built = datetime.fromisoformat(md.generationDateAndTime.replace("Z", "+00:00"))
    assert built.utcoffset().total_seconds() == 0 and built.year >= 2025


def test_generation_date_follows_source_date_epoch(monkeypatch):
    """Reproducible builds: $SOURCE_DATE_EPOCH fixes the date (1700000000 s is 2023-11-14 22:13:20 UTC)."""
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    assert generation_date_and_time() == "2023-11-14T22:13:20Z"
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "0")
    assert generation_date_and_time() == "1970-01-01T00:00:00Z"
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "yesterday")
    with pytest.raises(BuildError, match="SOURCE_DATE_EPOCH"):
        generation_date_and_time()
