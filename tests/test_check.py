"""``flexlink check``: every example FMU passes at CI size, and deliberately broken FMUs are caught and
reported (a wrong value reference in the XML, an output missing from ModelStructure, a doStep that
returns NaN)."""

from __future__ import annotations

import json
import os
import re
import shutil
import zipfile
from pathlib import Path

import pytest

from flexlink.cli import main
from flexlink.export.cbuild import compile_shared_library
from flexlink.tools.check import check_fmu, write_report

pytestmark = pytest.mark.usefixtures("check_harness_lock")   # conftest.py: never beside the other

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
NAMES = sorted(p.stem for p in EXAMPLES.glob("*.toml"))
FULL = os.environ.get("FLEXLINK_FULL") == "1"


@pytest.fixture(scope="module")
def rotating(example_fmu):
    return example_fmu("rotating_link")


@pytest.mark.parametrize("name", NAMES)
def test_every_example_passes_the_check(tmp_path, example_fmu, name):
    """CI size: 40 fuzz sequences, ME vs CS over 0.1 s; FLEXLINK_FULL=1: the defaults (60, 0.5 s)."""
    fmu = example_fmu(name)
    size = [] if FULL else ["--fuzz", "40", "--me-vs-cs-stop", "0.1"]
    assert main(["check", str(fmu), "--report", str(tmp_path / "report"), *size]) == 0
    data = json.loads((tmp_path / "report" / "report.json").read_text())
    assert data["passed"]
    names = [c["name"] for c in data["checks"]]
    assert names[:5] == ["model-description", "me-vs-cs", "fuzz", "fmu-state", "directional-derivatives"]
    md = (tmp_path / "report" / "report.md").read_text()
    assert "| check | input | reference | result | status |" in md


def _rewrite(src: Path, dst: Path, edit) -> Path:
    """A copy of the FMU with some members edited: edit(name, bytes) -> bytes."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            zout.writestr(item, edit(item.filename, zin.read(item.filename)))
    return dst


def _status(results):
    return {r.name: r for r in results}


def test_wrong_value_reference_in_the_xml_is_caught(rotating, tmp_path):
    def edit(name, data):
        if name == "modelDescription.xml":
            text = data.decode()
            text = re.sub(r'(name="arm.tip.v" valueReference=")\d+"', r'\g<1>4000"', text)
            return text.encode()
        return data

    bad = _rewrite(rotating, tmp_path / "bad_vr.fmu", edit)
    res = _status(check_fmu(bad, fuzz=4, importers=False))
    assert res["model-description"].status == "fail"
    assert any("4000" in d and "arm.tip.v" in d for d in res["model-description"].details)
    write_report(list(res.values()), tmp_path / "rep", str(bad))
    assert "FAILED" in (tmp_path / "rep" / "report.md").read_text()


def test_output_missing_from_model_structure_is_caught(rotating, tmp_path):
    def edit(name, data):
        if name == "modelDescription.xml":
            text = data.decode()
            outputs = text[text.index("<Outputs>"):text.index("</Outputs>")]
            first = re.search(r"\s*<Unknown [^>]*/>", outputs).group(0)
            return text.replace(outputs, outputs.replace(first, "", 1)).encode()
        return data

    bad = _rewrite(rotating, tmp_path / "bad_structure.fmu", edit)
    res = _status(check_fmu(bad, fuzz=4, importers=False))
    assert res["model-description"].status == "fail"
    assert any("hub.theta" in d for d in res["model-description"].details)


def test_do_step_returning_nan_is_caught(rotating, tmp_path):
    """Rebuild the binary from the FMU's own sources with doStep poisoning the state.  The FMU's energy guard
    refuses the poisoned step itself (its balance has a NaN term); the harness reports the CS run ending early
    with the FMU's reason, and ME against CS fails."""
    src = tmp_path / "src"
    with zipfile.ZipFile(rotating) as z:
        z.extractall(src)
    c = src / "sources" / "cs_step.c"
    text = c.read_text()
    anchor = "    d->time = t_end;\n"
    assert anchor in text
    c.write_text(text.replace(anchor, "    d->q[0] = NAN;\n" + anchor))
    so = next((src / "binaries" / "linux64").glob("*.so"))
    sources = sorted((src / "sources").glob("*.c"))          # the generic glue, model.c and its units
    compile_shared_library(sources, [src / "sources"], so)
    bad = tmp_path / "nan_step.fmu"
    with zipfile.ZipFile(bad, "w") as z:
        for p in sorted(src.rglob("*")):
            if p.is_file():
                z.write(p, p.relative_to(src).as_posix())
    shutil.rmtree(src)
    results = check_fmu(bad, fuzz=4, importers=False)
    res = _status(results)
    assert res["me-vs-cs"].status == "fail"
    assert any("NaN" in d for d in res["me-vs-cs"].details), res["me-vs-cs"].details
    assert main(["check", str(bad), "--fuzz", "4", "--no-importers"]) == 1


def test_check_of_a_missing_file_is_a_usage_error(tmp_path, capsys, rotating):
    assert main(["check", str(tmp_path / "nope.fmu")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["check", str(rotating), "--me-vs-cs-stop", "-1"]) == 2
    assert "must be a positive number of seconds" in capsys.readouterr().err
