"""SS22's Newton start: the line through the last two accelerations, the parabola through three, or the scheme's own
linear recurrence.

``fmu_src/predictor.c`` starts each step's Newton iteration from an extrapolation of the accelerations it returned
(each taken at its step's middle), or from SS22's linear recurrence J (a₊ − 2a + a₋) = −Δt C d − Δt² K (a₋ + (½ +
Θ₁) d) with its own misses fed back. The checks in tests/c/predictor_check.c (which includes ss22.c and predictor.c,
to reach their static functions) compare them with closed forms: on unequal steps the parabola reproduces a
quadratic law exactly and the line misses it by exactly c2 (t_n − t_l)(t_n − t_b); on a smooth law their errors fall
like h³ and h² (measured orders, ±0.1); and the choice between them follows a running mean of which one missed by
less, not one step's. And through ``ss22_step_from`` on the hand-written nonlinear model (a smooth motion with
restarts, given starts and shorter steps mixed in): whenever the history is three deep it is the last three
accelerations returned and their steps, the parabola leads, and every step is within its tolerance of its own
solution by full Newton, and the steps accepted on a matrix's kept rate between two measures of it grow past 4. The
cadence of those measures on its own: 4 steps, doubled by each measure in a row that finds the rate within the one
the steps were accepted on, up to 32, and back to 4 on one that does not (unless its second increment is within 100
tolerances, where the ratio may be rounding noise). The recurrence, with the test model's inputs held: on the linear
model (k3 = 0) it predicts each step's solution to rounding (the scheme's algebra: 1e-9 of the line's miss), on an
unresolved stiff mode (ω Δt = 10) too, where the line misses by the mode's whole swing; on the hardening spring its
start, with its misses fed back, is within a tenth of the line's miss; every step stays within its tolerance of full
Newton; and it is never formed while the supports' laws move (the inputs' second difference it leaves out).
tests/test_ss22_numerics.py audits the examples' steps the same way.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from flexlink.export import cbuild

TESTS_C = Path(__file__).parent / "c"


def test_the_predictors_against_closed_forms(tmp_path):
    exe = tmp_path / "predictor_check"
    src = cbuild.fmu_src_dir()
    subprocess.run([*cbuild.compiler(), "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2",
                    f"-I{TESTS_C / 'nonlinear'}", f"-I{src}", f"-I{cbuild.fmi_headers_dir()}",
                    str(TESTS_C / "predictor_check.c"), str(TESTS_C / "nonlinear" / "model.c"), str(src / "linalg.c"),
                    "-o", str(exe), "-lm"], check=True, capture_output=True, text=True)
    run = subprocess.run([str(exe)], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout
    assert run.stdout.count("ok ") == 51, run.stdout
