"""The check harness's watch over a child process (flexlink/tools/check/isolation.py), on children that end
the way a crashing FMU ends them: killed by a signal while a call is in progress, or between two calls (in
Python, or in an FMU library's destructor at the exit).  The expected values are what the child was made to
do: the signal it raises, the call it writes to the trace, the line it writes to stderr."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from flexlink.tools.check import isolation

# a child that writes one call to the trace (in progress or returned), a line to stderr, and aborts
CHILD = """
import os, signal, sys, time
from flexlink.tools.check import isolation
isolation.install(sys.argv[1])
isolation._enter("fmi2Instantiate('wrong', 1)")
if sys.argv[2] == "after":
    isolation._leave()
sys.stderr.write("noise\\nfree(): invalid pointer\\n")
sys.stderr.flush()
os.kill(os.getpid(), signal.SIGABRT)
"""


@pytest.mark.parametrize("when, where", [("in", "in fmi2Instantiate('wrong', 1)"),
                                         ("after", "after fmi2Instantiate('wrong', 1) returned")])
def test_a_crash_names_the_call_it_happened_in_or_after(tmp_path, when, where):
    """A call is said to have crashed only if it had begun and not returned; the child's stderr is kept."""
    trace = tmp_path / "trace"
    trace.write_bytes(isolation._HEADER.pack(0.0, -1, 0) + bytes(isolation.SIZE - isolation._HEADER.size))
    with open(tmp_path / "err", "w+") as err:
        p = subprocess.Popen([sys.executable, "-c", CHILD, str(trace), when], stderr=err, text=True)
        bad = isolation._watch(p, str(trace), call_limit=30.0, deadline=time.monotonic() + 60.0)
        err.seek(0)
        stderr = err.read()
    assert bad is not None and bad.rule == "no-crash"
    assert bad.message == f"the process died of SIGABRT {where}"
    assert isolation._last_words(stderr, 1) == "; its last words on stderr: free(): invalid pointer"


def test_a_silent_crash_adds_nothing():
    assert isolation._last_words("\n  \n") == ""


def test_a_crash_whose_stderr_says_limit_does_not_end_a_resumable_check(tmp_path, monkeypatch):
    """The harness resumes after a crashed item unless its own deadline ended the check; an FMU's stderr
    ("stack size limit reached") is not the harness's deadline (the independent review of 2026-11-27)."""
    crashes = []

    def launch(name, fmu, options, trace, out, err):
        first = options.get("first", 0)
        crashes.append(first)
        with open(trace, "wb") as fh:              # the trace's empty header, as the real launch writes it
            fh.write(isolation._HEADER.pack(0.0, -1, 0) + bytes(isolation.SIZE - isolation._HEADER.size))
        code = (CHILD_ITEMS % (trace, first)) if first < 3 else (CHILD_DONE % name)
        return subprocess.Popen([sys.executable, "-c", code], stdout=out, stderr=err, text=True)

    monkeypatch.setattr(isolation, "_launch", launch)
    result = isolation.run_isolated("fuzz", "x.fmu", {}, call_limit=30.0, limit=120.0, item="sequence")
    assert crashes == [0, 1, 2, 3]
    assert [x.rule for x in result.findings] == ["no-crash"] * 3
    assert all("stack size limit reached" in x.message for x in result.findings)


# a child that marks item `first` as begun, says "limit" on stderr and aborts; one that reports a result
CHILD_ITEMS = """
import os, signal, sys
from flexlink.tools.check import isolation
isolation.install(%r)
isolation.progress(%d)
sys.stderr.write("stack size limit reached\\n")
sys.stderr.flush()
os.kill(os.getpid(), signal.SIGABRT)
"""
CHILD_DONE = """
import json
from flexlink.tools.check.findings import CheckResult
print("RESULT " + json.dumps(CheckResult(%r, "-", "-", "done", seconds=0.0).as_dict()))
"""


# a child that reports its result, then aborts at its exit (an FMU library's exit handler, as PythonFMU's)
CHILD_DONE_THEN_ABORT = """
import atexit, json, os, signal, sys, time
from flexlink.tools.check import isolation
from flexlink.tools.check.findings import CheckResult
isolation.install(%r)
isolation._enter("fmi2FreeInstance()")
isolation._leave()
if sys.argv[1] == "abort":
    atexit.register(lambda: (sys.stderr.write("corrupted double-linked list\\n"), sys.stderr.flush(),
                             os.kill(os.getpid(), signal.SIGABRT)))
elif sys.argv[1] == "exit":
    atexit.register(lambda: (sys.stderr.write("library: shutting down\\n"), sys.stderr.flush(), os._exit(3)))
else:
    atexit.register(lambda: time.sleep(60))
print("RESULT " + json.dumps(CheckResult(%r, "-", "-", "done", seconds=0.0).as_dict()), flush=True)
isolation.finished()
"""


def _finished_then(monkeypatch, how: str, call_limit: float):
    """run_isolated on a child that reports its result and then aborts or hangs at its exit; its launches."""
    launches = []

    def launch(name, fmu, options, trace, out, err):
        launches.append(options)
        with open(trace, "wb") as fh:
            fh.write(isolation._HEADER.pack(0.0, -1, 0) + bytes(isolation.SIZE - isolation._HEADER.size))
        return subprocess.Popen([sys.executable, "-c", CHILD_DONE_THEN_ABORT % (trace, name), how], stdout=out,
                                stderr=err, text=True)

    monkeypatch.setattr(isolation, "_launch", launch)
    result = isolation.run_isolated("fmu-state", "x.fmu", {}, call_limit=call_limit, limit=120.0, item="sequence")
    return result, launches


@pytest.mark.parametrize("how, ended, message", [
    ("abort", "crashed", "the process died of SIGABRT after fmi2FreeInstance() returned, at its exit (the check "
                         "had finished); its last words on stderr: corrupted double-linked list"),
    ("exit", "exited with status 3", "the process exited with status 3 after fmi2FreeInstance() returned, at its "
                                     "exit (the check had finished); its last words on stderr: library: shutting down"),
], ids=["signal", "exit-status"])
def test_an_end_at_the_exit_keeps_the_finished_checks_result(monkeypatch, how, ended, message):
    """A child that printed its result and then died at its exit (SIGABRT) or exited with status 3 (an exit
    handler calling exit(3), no signal; the review of 2026-11-29): the result is kept (nothing is lost), the
    end is one no-crash finding that says so, with the child's last words, and the check is not resumed."""
    result, launches = _finished_then(monkeypatch, how, 30.0)
    assert len(launches) == 1
    assert result.result == f"done; its process {ended} at the exit"
    (bad,) = result.findings
    assert bad.rule == "no-crash" and bad.message == message
    assert bad.reproduce == "flexlink check x.fmu --only fmu-state --call-timeout 30"


def test_a_hang_at_the_exit_keeps_the_finished_checks_result(monkeypatch):
    """A child that printed its result and then does not exit (an exit handler that waits, here 60 s): killed
    after the per-call limit, not the check's, its result kept and the hang one finding (the review of
    2026-11-29)."""
    t0 = time.monotonic()
    result, launches = _finished_then(monkeypatch, "hang", 1.0)
    assert time.monotonic() - t0 < 30.0 and len(launches) == 1
    assert result.result == "done; its process hung at the exit"
    (bad,) = result.findings
    assert bad.rule == "returns" and bad.message.startswith("the process did not exit within ")
    assert bad.message.endswith(" s of reporting its result (an exit handler; last call: fmi2FreeInstance())")
