"""The cases of a sweep: a full grid of parameter axes, or seeded Monte Carlo draws (``flexlink sweep``).

Apart from the rest of :mod:`controllers.sweep` because a case list is pure arithmetic on the spec's text: it
needs no scene and no FMU, the same arguments always give the same cases (which is what lets a journal be
resumed, :func:`case_key`), and both the spec's checks (:mod:`controllers.sweep_spec`) and the workers
(:mod:`controllers.sweep_worker`) use it.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from flexlink.errors import FlexlinkError

__all__ = ["DISTRIBUTIONS", "Distribution", "case_key", "make_cases"]

DISTRIBUTIONS = ("uniform", "normal", "loguniform")


def _num(text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise FlexlinkError(f"{what}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise FlexlinkError(f"{what}: expected a finite number, got {text!r}")
    return v


def _parse_grid_axis(name: str, spec) -> list[float]:
    """``"LO:HI:N"`` (N evenly spaced values, ends included), ``"V1,V2,..."``, ``"V"``, or a sequence."""
    what = f"--param {name}"
    if isinstance(spec, str):
        text = spec.strip()
        if ":" in text:
            parts = text.split(":")
            if len(parts) != 3:
                raise FlexlinkError(f"{what}={text}: expected LO:HI:N (N values from LO to HI), V1,V2,... or V")
            lo, hi = _num(parts[0], what), _num(parts[1], what)
            try:
                n = int(parts[2])
            except ValueError:
                raise FlexlinkError(f"{what}={text}: N = {parts[2]!r} is not a whole number") from None
            if n < 1:
                raise FlexlinkError(f"{what}={text}: N must be at least 1")
            return [lo] if n == 1 else [float(v) for v in np.linspace(lo, hi, n)]
        values = [_num(p, what) for p in text.split(",") if p.strip()]
    elif isinstance(spec, int | float):
        values = [_num(str(spec), what)]
    else:
        values = [_num(str(v), what) for v in spec]
    if not values:
        raise FlexlinkError(f"{what}: no values")
    return values


@dataclass(frozen=True)
class Distribution:
    """One parameter's law in a Monte Carlo sweep, drawn for every case from the sweep's seeded generator.

    ``uniform(lo, hi)``, ``normal(mean, std)`` truncated to ``[lo, hi]``, ``loguniform(lo, hi)``, or a constant
    (``kind="fixed"``, ``a`` the value).
    """

    kind: str
    a: float
    b: float = math.nan
    lo: float = -math.inf
    hi: float = math.inf

    def draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` values of this law from ``rng`` (the sweep's seeded generator: the same seed, the same cases)."""
        if self.kind == "fixed":
            return np.full(n, self.a)
        if self.kind == "uniform":
            return rng.uniform(self.a, self.b, n)
        if self.kind == "loguniform":
            return np.exp(rng.uniform(math.log(self.a), math.log(self.b), n))
        out = rng.normal(self.a, self.b, n)          # normal, truncated by redrawing what falls outside
        for _ in range(1000):
            bad = (out < self.lo) | (out > self.hi)
            if not bad.any():
                return out
            out[bad] = rng.normal(self.a, self.b, int(bad.sum()))
        raise FlexlinkError(f"normal({self.a}, {self.b}) truncated to [{self.lo}, {self.hi}]: almost no mass "
                            "inside the bounds")


def _parse_distribution(name: str, spec, option: str = "--distribution") -> Distribution:
    """``uniform:LO:HI``, ``normal:MEAN:STD[:LO:HI]``, ``loguniform:LO:HI``, ``LO:HI`` (uniform) or ``V``."""
    if isinstance(spec, Distribution):
        return spec
    what = f"{option} {name}"
    if isinstance(spec, int | float):
        return Distribution("fixed", _num(str(spec), what))
    if not isinstance(spec, str):
        raise FlexlinkError(f"{what}: expected a string such as 'normal:MEAN:STD' or 'uniform:LO:HI'")
    parts = [p.strip() for p in spec.strip().split(":")]
    kind = parts[0].lower() if parts and parts[0][:1].isalpha() else None
    if kind is None:       # LO:HI or V
        if len(parts) == 1:
            return Distribution("fixed", _num(parts[0], what))
        if len(parts) == 2:
            kind = "uniform"
            parts = ["uniform", *parts]
        else:
            raise FlexlinkError(f"{what}={spec}: with --samples, give LO:HI (uniform) or a value; grids "
                                "(LO:HI:N) are for sweeps without --samples")
    if kind not in DISTRIBUTIONS:
        raise FlexlinkError(f"{what}={spec}: unknown distribution {parts[0]!r}; expected one of {DISTRIBUTIONS}")
    nums = [_num(p, what) for p in parts[1:]]
    if kind in ("uniform", "loguniform"):
        if len(nums) != 2 or not nums[0] < nums[1]:
            raise FlexlinkError(f"{what}={spec}: expected {kind}:LO:HI with LO < HI")
        if kind == "loguniform" and nums[0] <= 0:
            raise FlexlinkError(f"{what}={spec}: loguniform needs 0 < LO < HI")
        return Distribution(kind, nums[0], nums[1], nums[0], nums[1])
    if len(nums) not in (2, 4) or not nums[1] > 0:
        raise FlexlinkError(f"{what}={spec}: expected normal:MEAN:STD or normal:MEAN:STD:LO:HI with STD > 0")
    lo, hi = (nums[2], nums[3]) if len(nums) == 4 else (-math.inf, math.inf)
    if not lo < hi:
        raise FlexlinkError(f"{what}={spec}: expected LO < HI")
    return Distribution("normal", nums[0], nums[1], lo, hi)


def make_cases(params: Mapping[str, object] | None = None, *, samples: int | None = None, seed: int = 0,
               distributions: Mapping[str, object] | None = None) -> tuple[str, list[dict[str, float]]]:
    """The cases of a sweep, each the FMU parameters it sets, and whether they form a grid or a Monte Carlo set.

    ``("grid", [...])`` is the full product of the ``params`` axes, last name varying fastest; with
    ``samples``, ``("monte-carlo", [...])`` holds ``samples`` draws (seeded) of ``params`` (``LO:HI`` uniform,
    or a value) and ``distributions`` (:func:`_parse_distribution`).  The same arguments always give the same
    cases, which is what lets a journal be resumed.
    """
    params = dict(params or {})
    distributions = dict(distributions or {})
    both = set(params) & set(distributions)
    if both:
        raise FlexlinkError(f"{sorted(both)}: given both as --param and --distribution")
    if samples is None:
        if distributions:
            raise FlexlinkError("--distribution needs --samples N (a Monte Carlo sweep)")
        if not params:
            raise FlexlinkError("nothing to sweep: give at least one --param NAME=LO:HI:N")
        axes = {name: _parse_grid_axis(name, spec) for name, spec in params.items()}
        names = list(axes)
        return "grid", [dict(zip(names, combo, strict=True)) for combo in itertools.product(*axes.values())]
    if isinstance(samples, bool) or not isinstance(samples, int | np.integer) or samples < 1:
        raise FlexlinkError(f"--samples must be a positive whole number, got {samples!r}")
    dists = {name: _parse_distribution(name, spec, "--param") for name, spec in params.items()}
    dists.update({name: _parse_distribution(name, spec) for name, spec in distributions.items()})
    if not dists:
        raise FlexlinkError("--samples needs at least one --param NAME=LO:HI or --distribution NAME=...")
    rng = np.random.default_rng(seed)
    drawn = {name: d.draw(rng, int(samples)) for name, d in dists.items()}
    return "monte-carlo", [{name: float(drawn[name][i]) for name in dists} for i in range(int(samples))]


def case_key(params: Mapping[str, float]) -> str:
    """The identity of a case in a journal: its parameter names and exact values."""
    return ";".join(f"{name}={float(v)!r}" for name, v in params.items())
