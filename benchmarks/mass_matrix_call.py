"""One call of the generated mass matrix: the Gram form of the foreshortening rates against CasADi's Hessian.

    python benchmarks/mass_matrix_call.py [--modes 32] [--repeats 5]

The second-order link of ``benchmarks/scaling.py`` (one link of 16 Hermite elements reduced to ``--modes``
modes) is assembled once; its mass matrix is formed two ways from the same kinetic energy: as the build makes
it (``ChainAssembly.mass_matrix_all``: on one body its composite-inertia form is CasADi's Hessian of T less
Σ w u̇²; plus 2 Aᵀ W A) and as CasADi's Hessian
of the whole T through the point sums (the form before issue 15's change).  Each is prepared as the build
prepares an off-step function (scalar code, or the matrix graph past REFRESH_EXPAND_MAX_OPERATIONS), written by
CasADi's code generator, compiled at -O2 with a loop that calls it, and timed in the same run: the median of
``--repeats`` loops, each the mean of many calls.  Prints operations (scalar count), bytes of C and µs a call,
and the largest difference between the two matrices at the state the loop uses.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

HARNESS = r"""
#include <stdio.h>
#include <time.h>
#include "f.h"
int main(void) {
  static double q[NQ], p[NP], out[NQ * NQ], w[SZ_W + 1]; static casadi_int iw[SZ_IW + 1];
  const double *arg[SZ_ARG] = {q, p}; double *res[SZ_RES] = {out};   /* the work arrays CasADi asks for */
  for (int k = 0; k < NQ; k++) q[k] = 1e-3 * ((k * 7919) % 97) / 97.0;
  for (int k = 0; k < NP; k++) p[k] = 1.0 + 0.1 * k;
  for (int r = 0; r < REPEATS; r++) {
    struct timespec a, b; clock_gettime(CLOCK_MONOTONIC, &a);
    for (int k = 0; k < CALLS; k++) FUNCTION(arg, res, iw, w, 0);
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%.17g\n", ((b.tv_sec - a.tv_sec) + 1e-9 * (b.tv_nsec - a.tv_nsec)) / CALLS);
  }
  for (int k = 0; k < NQ * NQ; k++) printf("%.17g\n", out[k]);
  return 0;
}
"""


def forms(modes: int) -> tuple[ca.Function, ca.Function]:
    """(Gram form, Hessian through the point sums) of the link's mass matrix, Functions of (qa, p)."""
    from scaling import modes_scene

    from flexlink.mechanics.assembly import ChainAssembly
    from flexlink.scene.loader import parse_scene

    chain = ChainAssembly(parse_scene(modes_scene(modes)))
    chain.assemble_kinematics()
    hessian = ca.substitute(ca.hessian(chain.T, chain.va)[0], chain.va, ca.DM.zeros(chain.va.numel()))
    return (ca.Function("mass_matrix", [chain.qa, chain.p], [ca.densify(chain.mass_matrix_all())]),
            ca.Function("mass_matrix", [chain.qa, chain.p], [ca.densify(hessian)]))


def call_cost(f: ca.Function, repeats: int, tmp: Path) -> dict:
    """Operations, bytes of C and seconds a call (median of ``repeats``) of ``f`` as the build generates it."""
    from flexlink.export.codegen import _prepare

    g = _prepare(f, "bench", True, off_step=True)
    cg = ca.CodeGenerator("f.c", {"with_header": True, "prefix": "f_", "casadi_real": "double"})
    cg.add(g.function)
    cg.generate(str(tmp) + "/")
    n_q, n_p = f.nnz_in(0), f.nnz_in(1)
    (tmp / "h.c").write_text(HARNESS)
    exe = tmp / "h"
    f2 = g.function
    sizes = [f"-DSZ_ARG={max(2, f2.sz_arg())}", f"-DSZ_RES={max(1, f2.sz_res())}", f"-DSZ_W={f2.sz_w()}",
             f"-DSZ_IW={f2.sz_iw()}"]
    subprocess.run(["gcc", "-O2", f"-DNQ={n_q}", f"-DNP={n_p}", f"-DREPEATS={repeats}", "-DCALLS=2000", *sizes,
                    f"-DFUNCTION={g.function.name()}", "-o", str(exe), str(tmp / "h.c"), str(tmp / "f.c"), "-lm"],
                   check=True)
    lines = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout.split()
    values = [float(x) for x in lines]
    return {"operations": g.operations, "matrix_graph": g.matrix_graph, "bytes": (tmp / "f.c").stat().st_size,
            "us": 1e6 * statistics.median(values[:repeats]), "matrix": np.array(values[repeats:])}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    gram, points = forms(args.modes)
    results = {}
    for name, f in (("gram", gram), ("hessian", points)):
        with tempfile.TemporaryDirectory() as tmp:
            results[name] = call_cost(f, args.repeats, Path(tmp))
    for name, r in results.items():
        form = "matrix graph" if r["matrix_graph"] else "scalar"
        print(f"{name:8s} {r['operations']:8d} operations ({form})  {r['bytes'] / 1e6:.3f} MB  {r['us']:.1f} us a call")
    a, b = results["gram"]["matrix"], results["hessian"]["matrix"]
    print(f"same-run ratio hessian/gram: {results['hessian']['us'] / results['gram']['us']:.2f}; "
          f"largest difference {np.max(np.abs(a - b)):.3g} of {np.max(np.abs(b)):.3g}")


if __name__ == "__main__":
    main()
