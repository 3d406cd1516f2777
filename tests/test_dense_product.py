"""The dense product loop the generated code uses in place of CasADi's (fmu_src/templates/dense_product.c.in).

The reference is CasADi's own ``casadi_mtimes_dense``, taken from the C that CasADi generates for a product
by a constant dense matrix (the form :func:`flexlink.mechanics.points.dense_map` leaves as a call).  Ours
must give the same values to the bit -- the same sums in the same order, only several entries carried side by
side in registers -- for every shape (the blocks of 8 rows and 4 columns, and the rows and columns left over),
both the plain and the transposed product, several right-hand sides, and at every optimisation level; and the
plain loops of the complex-step twins (``FLEXLINK_COMPLEX_UNIT``) too; under the build's compiler and clang.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import casadi as ca
import pytest

from flexlink.export.cbuild import compiler, fmu_src_dir

HARNESS = r"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#define casadi_real double
#define casadi_int long long int
#define casadi_mtimes_dense reference_mtimes_dense
%(reference)s
#undef casadi_mtimes_dense
%(ours)s
#if !FLEXLINK_PAIRS && !defined(FLEXLINK_COMPLEX_UNIT)
#error "the pairs are not compiled: this would test the plain loops only"
#endif

static double value(void) {                  /* mixed signs and magnitudes, so that rounding shows */
    double r = (double)rand() / RAND_MAX - 0.5;
    return r * (rand() %% 3 == 0 ? 1e6 : rand() %% 2 ? 1.0 : 1e-6);
}

int main(void) {
    static double x[40 * 40], y[40 * 3], z0[40 * 3], z1[40 * 3];
    int cases = 0;
    srand(22);
    for (int nrow = 1; nrow <= 35; nrow++)
        for (int ncol = 1; ncol <= 35; ncol++)
            for (int ncol_y = 1; ncol_y <= 3; ncol_y += 2)
                for (int tr = 0; tr <= 1; tr++) {
                    for (int k = 0; k < nrow * ncol; k++) x[k] = value();
                    for (int k = 0; k < 40 * ncol_y; k++) y[k] = value();
                    for (int k = 0; k < 40 * ncol_y; k++) z0[k] = z1[k] = value();
                    reference_mtimes_dense(x, nrow, ncol, y, ncol_y, z0, tr);
                    casadi_mtimes_dense(x, nrow, ncol, y, ncol_y, z1, tr);
                    if (memcmp(z0, z1, sizeof z0) != 0) {
                        printf("differs: nrow %%d ncol %%d ncol_y %%d tr %%d\n", nrow, ncol, ncol_y, tr);
                        return 1;
                    }
                    cases++;
                }
    printf("%%d\n", cases);
    return 0;
}
"""


def _casadi_loop() -> str:
    """CasADi's casadi_mtimes_dense, as its code generator writes it for a product by a constant matrix."""
    x = ca.MX.sym("x", 9)
    f = ca.Function("product", [x], [ca.mtimes(ca.DM.rand(9, 9), x)])
    code = ca.CodeGenerator("product.c")
    code.add(f)
    text = code.dump()
    start = text.index("\nvoid casadi_mtimes_dense(")
    return text[start:text.index("\n}\n", start) + 3]


def _compilers() -> list[list[str]]:
    """The build's compiler, and clang where it is installed (importers compile the FMU's sources with it)."""
    found = [compiler()]
    if shutil.which("clang"):
        found.append(["clang"])
    return found


@pytest.mark.parametrize("cc", _compilers(), ids=lambda c: Path(c[0]).name)
@pytest.mark.parametrize("level, complex_unit", [("-O0", False), ("-O2", False), ("-O3", False), ("-O2", True)])
def test_our_dense_product_is_casadis_to_the_bit(tmp_path, cc, level, complex_unit):
    ours = (fmu_src_dir() / "templates" / "dense_product.c.in").read_text()
    source = tmp_path / "dense_product_check.c"
    source.write_text(HARNESS % {"reference": _casadi_loop(), "ours": ours})
    exe = tmp_path / "dense_product_check"
    defines = ["-DFLEXLINK_COMPLEX_UNIT=1"] if complex_unit else []
    subprocess.run([*cc, level, "-std=c99", "-Wall", "-Wextra", "-Werror", *defines, str(source),
                    "-o", str(exe)], check=True, capture_output=True, text=True)
    run = subprocess.run([str(exe)], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout
    assert int(run.stdout) == 35 * 35 * 2 * 2
