"""Each check in a child process, with a time limit on every FMI call.

An FMU that crashes would take the harness with it, and one that never returns from a call (``fmi2DoStep``
with a NaN step, in five of the six FMI 2 Reference FMUs) would show only as a whole-run timeout.  So the
harness loads no FMU itself: each check runs in ``python -m flexlink.tools.check --child ...``, whose every
FMI call (fmpy's one entry point ``_FMU._call``, patched in the child only) is written, before it is made,
to a small file shared with the parent (a memory map):

    bytes 0-8    the monotonic clock when the call in progress began (0: no call in progress)
    bytes 8-12   the check's progress marker (an item index; -1 before the first)
    bytes 12-16  the length of the text that follows
    bytes 16-    the last calls, one a line, the one in progress last

The parent polls it: a call older than the per-call limit is a finding (rule ``returns``) with its
seconds and the calls before it; a child killed by a signal is a finding (``no-crash``) naming the call
in progress.  A check that marks its progress (the illegal-call catalogue item by item, the fuzz sequence
by sequence) is then resumed after that item in a fresh child, so one bad call ends one item, not the
check; the finding names the item.  A child that reported its result and then died at its exit, exited with a
non-zero status, or did not exit within the per-call limit (an FMU library's exit handler), keeps its result, with
that as one more finding.
"""

from __future__ import annotations

import collections
import json
import mmap
import os
import signal
import struct
import subprocess
import sys
import tempfile
import time

from flexlink.tools.check.findings import CheckResult, Finding

SIZE = 1 << 14
_HEADER = struct.Struct("<dii")
_map: mmap.mmap | None = None
_recent: collections.deque[str] = collections.deque(maxlen=60)
_NO_COMPONENT = ("fmi2Instantiate", "fmi2GetTypesPlatform", "fmi2GetVersion")
FINISHED = -2               # the progress marker of a child that has reported its result (then only exits)


# ================================================================ in the child

def install(trace_path: str) -> None:
    """Map the trace file and route every fmpy FMI call through ``_traced``."""
    global _map
    from fmpy.fmi1 import _FMU

    fd = os.open(trace_path, os.O_RDWR)
    _map = mmap.mmap(fd, SIZE)
    os.close(fd)
    original = _FMU._call

    def _traced(self, fname, *args):
        _enter(_describe(fname, args))
        try:
            return original(self, fname, *args)
        finally:
            _leave()

    _FMU._call = _traced


def _value(a) -> str:
    if isinstance(a, float):
        return repr(a)
    if isinstance(a, (int, bool)) or a is None:
        return repr(a)
    if isinstance(a, bytes):
        return repr(a[:40].decode("utf-8", "replace"))
    if hasattr(a, "_length_"):                       # a ctypes array
        items = [_value(x) for x in list(a)[:6]]
        return "[" + ", ".join(items) + (", ..." if len(a) > 6 else "") + "]"
    if hasattr(a, "value") and not hasattr(a, "contents"):
        return _value(a.value)
    return "&" if type(a).__name__ == "CArgObject" else type(a).__name__


def _describe(fname: str, args) -> str:
    shown = args if fname in _NO_COMPONENT else args[1:]
    return f"{fname}({', '.join(_value(a) for a in shown)})"


def _enter(text: str) -> None:
    _recent.append(text)
    if _map is not None:
        data = "\n".join(_recent).encode()[-(SIZE - _HEADER.size):]
        _map[_HEADER.size:_HEADER.size + len(data)] = data
        struct.pack_into("<d", _map, 0, time.monotonic())
        struct.pack_into("<i", _map, 12, len(data))


def _leave() -> None:
    if _map is not None:
        struct.pack_into("<d", _map, 0, 0.0)


def recent(n: int = 6) -> list[str]:
    """The last n FMI calls of this process (for a finding's call sequence)."""
    return list(_recent)[-n:]


def emit(found: list[Finding]) -> None:
    """Print findings as they are made (``FINDING <json>`` lines).

    A check that is killed later, by a hang or a crash, keeps them.
    """
    for x in found:
        print("FINDING " + json.dumps(x.as_dict()), flush=True)


def finished() -> None:
    """Mark the check as reported: from now on the child only exits, and must within the per-call limit.

    The parent times that from when it sees the mark; a call made during the exit is timed as any call.
    """
    if _map is not None:
        struct.pack_into("<i", _map, 8, FINISHED)


def progress(k: int) -> None:
    """Mark item k of a resumable check as begun (the parent resumes after it if it hangs or crashes)."""
    _recent.clear()
    if _map is not None:
        struct.pack_into("<i", _map, 8, k)


# ================================================================ in the parent

def _read(trace: str) -> tuple[float, int, list[str]]:
    with open(trace, "rb") as fh:
        raw = fh.read(SIZE)
    began, marker, n = _HEADER.unpack_from(raw)
    text = raw[_HEADER.size:_HEADER.size + max(0, min(n, SIZE))].decode("utf-8", "replace")
    return began, marker, [x for x in text.splitlines() if x]


def _launch(name: str, fmu: str, options: dict, trace: str, out, err) -> subprocess.Popen:
    with open(trace, "wb") as fh:
        fh.write(_HEADER.pack(0.0, -1, 0) + bytes(SIZE - _HEADER.size))
    cmd = [sys.executable, "-m", "flexlink.tools.check", "--child", name, fmu, trace, json.dumps(options)]
    # the child's temporary files (the unzipped FMU, fmpy's) go under the parent's folder, which is removed
    # even when the child is killed and cannot clean up after itself
    env = {**os.environ, "TMPDIR": os.path.dirname(trace)}
    return subprocess.Popen(cmd, stdout=out, stderr=err, text=True, env=env)


def _watch(p: subprocess.Popen, trace: str, call_limit: float, deadline: float) -> Finding | None:
    """Wait for the child; kill it on a call older than call_limit or at the deadline."""
    reported_at = None          # when the child was first seen to have reported its result
    while p.poll() is None:
        began, marker, calls = _read(trace)
        now = time.monotonic()
        if marker == FINISHED and reported_at is None:
            reported_at = now
        if reported_at is not None and began == 0.0 and (now - reported_at > call_limit or now > deadline):
            p.kill()
            p.wait()
            return Finding("returns", f"the process did not exit within {now - reported_at:.1f} s of reporting "
                                      f"its result (an exit handler; last call: {calls[-1] if calls else 'none'})",
                           sequence=calls)
        if began > 0.0 and now - began > call_limit:
            p.kill()
            p.wait()
            last = calls[-1] if calls else "an FMI call"
            return Finding("returns", f"{last} did not return within {now - began:.1f} s", sequence=calls)
        if now > deadline:
            p.kill()
            p.wait()
            return Finding("returns", f"the check did not finish within its limit (last call: "
                                      f"{calls[-1] if calls else 'none'})", sequence=calls)
        time.sleep(0.05)
    began, marker, calls = _read(trace)
    if not calls:
        where = "before any FMI call"
    elif began > 0.0:
        where = f"in {calls[-1]}"
    else:                       # between calls: in Python, or at the exit (an FMU's library destructors)
        where = f"after {calls[-1]} returned"
    if p.returncode < 0:
        sig = signal.Signals(-p.returncode).name if -p.returncode in signal.valid_signals() else p.returncode
        return Finding("no-crash", f"the process died of {sig} {where}", sequence=calls)
    if p.returncode > 0 and marker == FINISHED:
        # it reported, then something at its exit (an FMU library's exit handler calling exit()) changed the
        # status the harness would otherwise have taken for a clean exit
        return Finding("no-crash", f"the process exited with status {p.returncode} {where}", sequence=calls)
    return None


def _last_words(stderr: str, n: int = 3) -> str:
    """The last lines a crashed child wrote to stderr.

    glibc's "free(): invalid pointer", "Fatal Python error: ...", an FMU's own message: what tells one abort
    from another.
    """
    lines = [x.strip() for x in stderr.splitlines() if x.strip()][-n:]
    return "; its last words on stderr: " + " | ".join(x[:200] for x in lines) if lines else ""


def run_isolated(name: str, fmu: str, options: dict, *, call_limit: float, limit: float,
                 item: str | None = None, replay=None, carry=None) -> CheckResult:
    """Run check ``name`` in a child process; see the module docstring.

    ``item``: what a resumable check counts its progress in ("sequence", "catalogue item"; None: not
    resumable); ``replay(k)``: the options that replay it up to item k, for the reproduction;
    ``carry(found)``: the options that hand a resumed child what the earlier ones found (the fuzz's limit on
    repeated findings holds for the whole check).
    """
    t0 = time.monotonic()
    found: list[Finding] = []
    bad_items: list[str] = []
    resumable = item is not None
    result = None
    at_exit = ""               # "crashed", "hung" or "exited with status N": what the process did after reporting
    with tempfile.TemporaryDirectory(prefix="flexlink-check-child-") as tmp:
        trace = os.path.join(tmp, "trace")
        first = 0
        while True:
            with open(os.path.join(tmp, "out"), "w+") as out, open(os.path.join(tmp, "err"), "w+") as err:
                resumed = {"first": first, **(carry(found) if carry is not None and first else {})}
                p = _launch(name, fmu, {**options, **(resumed if resumable else {})}, trace, out, err)
                bad = _watch(p, trace, call_limit, t0 + limit)
                out.seek(0)
                err.seek(0)
                stdout, stderr = out.read(), err.read()
            lines = [x for x in stdout.splitlines() if x.startswith("RESULT ")]
            reported = _read(trace)[1] == FINISHED
            if lines and (bad is None or bad.rule == "no-crash" or reported):
                result = CheckResult.from_dict(json.loads(lines[-1][len("RESULT "):]))
            if result is not None and bad is not None:
                # the check had finished and reported; the process died or hung at its exit (an FMU library's
                # exit handlers: PythonFMU's reads memory an earlier handler freed, valgrind): kept, and a finding
                if bad.rule == "no-crash":
                    bad.message += f", at its exit (the check had finished){_last_words(stderr)}"
                bad.reproduce = f"flexlink check {fmu} --only {name} --call-timeout {call_limit:g}"
                found.append(bad)
                at_exit = "hung" if bad.rule == "returns" else "crashed" if p.returncode < 0 else \
                    f"exited with status {p.returncode}"
            if result is not None:
                break
            if bad is None:
                tail = (stdout + stderr).strip().splitlines()[-1:] or ["no output"]
                bad = Finding("no-crash", f"the check's process ended with exit status {p.returncode}: {tail[0]}")
            found += [Finding.from_dict(json.loads(x[len("FINDING "):])) for x in stdout.splitlines()
                      if x.startswith("FINDING ")]
            marker = _read(trace)[1]
            extra = f" {replay(marker)}" if replay is not None and marker >= 0 else ""
            bad.reproduce = f"flexlink check {fmu} --only {name}{extra} --call-timeout {call_limit:g}"
            if resumable and marker >= 0:
                bad.message += f" ({item} {marker})"
            # decided on the harness's own message (the deadline's names its limit), not on the FMU's stderr
            resume = resumable and marker >= first and time.monotonic() < t0 + limit and "limit" not in bad.message
            if bad.rule == "no-crash" and p.returncode < 0:
                bad.message += _last_words(stderr)
            found.append(bad)
            bad_items.append(str(marker))
            if not resume:
                break
            first = marker + 1
    if result is None:
        result = CheckResult(name, "-", "-", "ended early", seconds=0.0)
    if found:
        result.findings = found + result.findings
        result.details = [x.message for x in found] + result.details
        result.status = result.judged()
        where = f" ({item} {', '.join(bad_items)}; resumed after each)" if resumable and bad_items else ""
        if bad_items:
            result.result = f"{result.result}; {len(bad_items)} call(s) that hang or crash{where}"
        if at_exit:
            result.result = f"{result.result}; its process {at_exit} at the exit"
    result.seconds = time.monotonic() - t0
    return result
