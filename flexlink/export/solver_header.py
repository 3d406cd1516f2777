"""``fmu_src/solver_settings.h`` from :mod:`flexlink.scene.solver`, the one owner of the solver's numbers.

The C glue's slots and limits of the solver settings (Θ range, orders, the Richardson bound, sub-step and
doStep limits, Newton iterations and rounding floor, the static equilibrium's iterations) are the same
numbers as the scene loader's and the FMU variables'; the header is written from the Python module rather
than kept equal by hand.  It is committed (the fixed C of every FMU, hand-written test models included,
compiles against it) and ``tests/test_solver_settings.py`` fails when it differs from :func:`render`.
Regenerate with ``python -m flexlink.export.solver_header``.
"""

from __future__ import annotations

from string import Template

from flexlink.export.cbuild import fmu_src_dir
from flexlink.scene import solver

HEADER = "solver_settings.h"


def _c_double(x: float) -> str:
    """A C double literal that reads back as ``x`` (``repr`` round-trips; integers get a decimal point)."""
    text = repr(float(x))
    return text if any(c in text for c in ".eE") else text + ".0"


def render() -> str:
    """The text of ``solver_settings.h`` for the settings of :mod:`flexlink.scene.solver`."""
    defaults = solver.SolverSettings()
    template = Template((fmu_src_dir() / "templates" / f"{HEADER}.in").read_text())
    return template.substitute(
        slots=", ".join(s.c_name for s in solver.SETTINGS),
        theta_min=_c_double(solver.THETA_MIN), theta_max=_c_double(solver.THETA_MAX),
        order_ss22=solver.ORDER_SS22, order_richardson=solver.ORDER_RICHARDSON,
        default_theta=_c_double(defaults.theta[0]), default_tolerance=_c_double(defaults.tolerance),
        richardson_max_omega_step=_c_double(solver.RICHARDSON_MAX_OMEGA_STEP),
        substep_max=solver.SUBSTEP_MAX, dostep_max_internal_steps=_c_double(solver.DOSTEP_MAX_INTERNAL_STEPS),
        newton_max_iterations=solver.NEWTON_MAX_ITERATIONS,
        newton_rounding_factor=_c_double(solver.NEWTON_ROUNDING_FACTOR),
        static_max_iterations=solver.STATIC_MAX_ITERATIONS)


def main() -> None:
    """Write ``fmu_src/solver_settings.h`` (run after changing :mod:`flexlink.scene.solver`)."""
    path = fmu_src_dir() / HEADER
    path.write_text(render())
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
