"""A progress bar for long runs: simulated time against the stop time, with an estimate of what remains.

A run of many simulated seconds can take minutes; without a sign of life it looks hung. The bar goes to
stderr only (stdout stays the command's answer, whatever it is piped into), appears only after
``DELAY`` seconds of wall time (a short run prints nothing), and only on a terminal unless asked.
"""

from __future__ import annotations

import sys

DELAY = 2.0          # s of wall time before the bar appears: runs shorter than this stay silent


def wanted(option: bool | None) -> bool:
    """``--progress``/``--no-progress`` as given, else only when stderr is a terminal (not in a log file)."""
    return sys.stderr.isatty() if option is None else option


class RunProgress:
    """fmpy's ``step_finished(time, recorder)`` callback drawing a tqdm bar in simulated seconds.

    tqdm's remaining-time estimate is (stop − t) / (simulated seconds per wall second), which is what a user
    waits for. Use as a context manager so that the bar is closed (and its line ended) even on an error.
    """

    def __init__(self, stop_time: float, *, delay: float = DELAY, force: bool = False):
        from tqdm import tqdm

        self.stop_time = stop_time
        self._last = 0.0
        self.bar = tqdm(total=stop_time, unit="s", unit_scale=False, file=sys.stderr, delay=0.0 if force else delay,
                        desc="simulating", dynamic_ncols=True,
                        bar_format="{desc} {bar} {n:.3g}/{total:.3g} s simulated [{elapsed}<{remaining}]")

    def __call__(self, time: float, recorder=None) -> bool:
        """Advance the bar to ``time``; True lets fmpy go on."""
        t = min(float(time), self.stop_time)
        if t > self._last:
            self.bar.update(t - self._last)
            self._last = t
        return True                 # fmpy stops the run on False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.bar.close()
