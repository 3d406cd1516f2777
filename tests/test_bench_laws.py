"""``flexlink bench``'s CasADi and SciPy comparisons on a model driven by a built-in law (issue 22's two-link FE
row, ``benchmarks/chain_speed.py``): the law enters their ODE as the function of time the FMU evaluates.

The check is a convergence study between two implementations: the FMU's SS22 (generated C, the law evaluated
in the FMU's C) converges at order 2 to CVODES on the CasADi ODE at a tight tolerance, across a segment end of
the law where its acceleration jumps.  A CasADi ODE that held the law at its value at the start of each
interval would stay O(1) away.  The start state (a static sag) is checked against strength of materials, and a
host-driven law the comparison cannot follow is one FlexlinkError.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from flexlink.errors import FlexlinkError
from flexlink.export.cache import cached_fmu
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import parse_scene
from flexlink.tools.bench import (
    BenchCase,
    _outputs,
    bench_scipy,
    bench_ss22,
    casadi_states,
    default_case,
    reference_outputs,
    relative_error,
)

# θ = t² until 0.3 s, then the line that continues it (θ, θ̇ continuous; θ̈ jumps from 2 to 0 rad/s²)
LAW = {"segments": [{"until": 0.3, "poly": [0.0, 0.0, 1.0]}, {"until": math.inf, "poly": [-0.09, 0.6]}]}
LINK = {"name": "arm", "length": 1.0, "linear_density": 0.349, "EI": 93.72, "deformation": ["v"],
        "shapes": {"kind": "clamped-free", "count": 2}, "kinematics": "second-order",
        "initial_deformation": "static"}


def scene(trajectory: dict | None = LAW):
    joint = {"name": "hub", "axis": [0.0, 0.0, 1.0], "drive": "position"}
    if trajectory is not None:
        joint["trajectory"] = trajectory
    return parse_scene({"name": "law_link", "gravity": [0.0, -9.81, 0.0], "joint": [joint], "link": [LINK]})


@pytest.fixture(scope="module")
def law_case():
    sc = scene()
    model = build_model(sc)
    case = default_case(model, stop=0.5, sample=0.01)
    _, X = casadi_states(case, "cvodes", 1e-10, repeats=1)
    return sc, model, case, _outputs(case, X), X


def test_start_state_is_the_static_sag(law_case):
    """Every method starts from the FMU's state: the arm sagging under gravity, tip q L⁴ / (8 EI)."""
    _, _, case, y, _ = law_case
    q = LINK["linear_density"] * 9.81
    sag = q * LINK["length"] ** 4 / (8 * LINK["EI"])
    # two clamped-free modes: the static shape is not exactly in their span (the 2-mode Rayleigh–Ritz sag is
    # about 0.1 % short); the undeformed start the comparison used to take would be 100 % off
    assert y["arm.tip.v"][0] == pytest.approx(-sag, rel=3e-3)


def test_fmu_converges_to_the_law_driven_casadi_ode(law_case):
    """SS22's error against CVODES (rtol 1e-10) on the law-driven ODE falls 4× per halving of the step (from
    0.5 ms: the second mode, 57 Hz, is resolved, ω Δt ≤ 0.18)."""
    sc, model, case, y, _ = law_case
    fmu = cached_fmu(sc, model=model)
    rows = bench_ss22(case, fmu, [5e-4, 2.5e-4, 1.25e-4], [(0.5, 0.5)], y, repeats=1)
    errors = [r.error for r in rows]
    assert all(r.failure is None for r in rows), rows
    orders = [math.log2(a / b) for a, b in zip(errors[:-1], errors[1:], strict=True)]
    assert all(1.8 < p < 2.2 for p in orders), (errors, orders)
    assert errors[-1] < 1e-4, errors
    # both outputs move: the tip and the torque that drives the law
    assert np.ptp(y["arm.tip.v"]) > 1e-3 and np.ptp(y["hub.tau"]) > 1e-2


def test_other_routes_agree(law_case):
    """IDAS, SciPy's Radau and the reference (simulate_reference) integrate the same equations."""
    _, _, case, y, _ = law_case
    _, X = casadi_states(case, "idas", 1e-10, repeats=1)
    assert relative_error(case, _outputs(case, X), y) < 1e-7
    assert relative_error(case, reference_outputs(case, 1e-10), y) < 1e-7
    (row,) = bench_scipy(case, "Radau", [1e-8], y, repeats=1)
    assert row.error < 1e-5


def test_a_law_past_its_segment_end_is_far_off(law_case):
    """The study above can fail: the law's first segment kept past 0.3 s (θ = t² forever) agrees until 0.3 s
    (the time-dependent law itself) and is far off after it."""
    _, _, case, y, _ = law_case
    frozen = BenchCase(build_model(scene({"segments": [{"until": math.inf, "poly": [0.0, 0.0, 1.0]}]})),
                       case.stop, case.times, [], case.outputs)
    _, X = casadi_states(frozen, "cvodes", 1e-9, repeats=1)
    y_frozen = _outputs(frozen, X)
    before = case.times < 0.3 - 1e-9          # at 0.3 s itself the law is the second segment (θ̈ = 0)

    def off(mask):
        return max(np.sqrt(np.mean((y_frozen[n][mask] - y[n][mask]) ** 2) / np.mean(y[n] ** 2)) for n in y)

    assert off(before) < 1e-6
    assert off(~before) > 1e-2


def test_a_host_driven_law_that_moves_is_one_error():
    """The FMU extends a host-driven law in time from each call: the comparisons refuse it, one FlexlinkError."""
    model = build_model(scene(None))
    times = np.round(np.arange(11) * 0.01, 12)
    moving = BenchCase(model, 0.1, times, [(0.0, {"hub.omega_ref": 1.0})], ["arm.tip.v", "hub.tau"])
    with pytest.raises(FlexlinkError, match="hub.*host"):
        casadi_states(moving, "cvodes", 1e-6, repeats=1)
    with pytest.raises(FlexlinkError, match="hub.*host"):
        bench_scipy(moving, "Radau", [1e-6], {}, repeats=1)
    held = BenchCase(model, 0.1, times, [(0.0, {"hub.theta_ref": 0.0})], ["arm.tip.v", "hub.tau"])
    _, X = casadi_states(held, "cvodes", 1e-8, repeats=1)
    assert np.all(np.isfinite(X))


def test_chain_speed_renders_the_two_link_row(capsys):
    """``benchmarks/chain_speed.py --from-json`` renders the committed two-link run (docs/performance.md): the law's
    window in its header, the three error levels, and a bad ``--tolerances`` is one usage error."""
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root / "benchmarks"))
    try:
        import chain_speed
    finally:
        sys.path.remove(str(root / "benchmarks"))
    chain_speed.main(["--from-json", str(root / "benchmarks" / "chain_speed_two_links.json")])
    out = capsys.readouterr().out
    assert out.startswith("steel_beam_two_links (20 coordinates), its built-in law from 0 to 0.05 s")
    levels = [ln.split(" | ")[0] for ln in out.splitlines() if ln.startswith(("| 0.001 ", "| 0.0001 ", "| 1e-05 "))]
    assert levels[:3] == ["| 0.001", "| 0.0001", "| 1e-05"]        # the levels (then the split's 1 ms row)
    with pytest.raises(SystemExit) as exc:
        chain_speed.main(["--tolerances", "1e-3,often"])
    assert exc.value.code == 2
    assert "not a comma-separated list of numbers" in capsys.readouterr().err
