/* predictor_check.c -- SS22's Newton start (fmu_src/ss22.c: predict, choose_predictor) against closed forms,
 * for tests/test_ss22_predictor.py.  It includes ss22.c itself, to reach its static functions, and links the
 * hand-written nonlinear model (tests/c/nonlinear) for N_Q and the nominal scales.
 * Prints one line per check ("ok ..." or "FAIL ...") and exits 1 if any failed. */
#include <math.h>
#include <stdio.h>
#include "ss22.c"

static int failures;

static void check(int ok, const char *what, double value) {
    printf("%s %s %.3e\n", ok ? "ok" : "FAIL", what, value);
    if (!ok) failures++;
}

/* alpha_i(t) = c0 + c1 t + c2 t^2 (coefficients per coordinate) */
static double quadratic(int i, double t) { return (1.0 + i) - 0.5 * t + (3.0 - 2.0 * i) * t * t; }

/* A history of three steps of lengths dto, dtb, dtl ending at t = 0, each step's acceleration f at its middle
 * (as SS22 takes its constant acceleration), and the next step's length dt. */
static void history(SS22 *s, double (*f)(int, double), double dto, double dtb, double dtl) {
    memset(s, 0, sizeof(*s));
    s->history = 1;
    s->depth = 3;
    s->dt_older = dto;
    s->dt_before = dtb;
    s->dt_last = dtl;
    for (int i = 0; i < N_Q; i++) {
        s->alpha_last[i] = f(i, -0.5 * dtl);
        s->alpha_before[i] = f(i, -dtl - 0.5 * dtb);
        s->alpha_older[i] = f(i, -dtl - dtb - 0.5 * dto);
    }
}

static double worst(const double *a, double (*f)(int, double), double t) {
    double e = 0.0;
    for (int i = 0; i < N_Q; i++) e = fmax(e, fabs(a[i] - f(i, t)));
    return e;
}

static double omega_t(int i, double t) { return sin((1.0 + i) * t + 0.7); }

static double sol[N_Q], near[N_Q], far[N_Q];

/* One step's choice, the parabola having predicted parabola and the line line (start: the one s used) */
static void compare(SS22 *s, const double *parabola, const double *line) {
    choose_predictor(s, sol, s->parabola ? parabola : line, s->parabola ? line : parabola);
}

int main(void) {
    static SS22 s;
    double a[N_Q], other[N_Q];
    const double dto = 0.013, dtb = 0.007, dtl = 0.011, dt = 0.009, tn = 0.5 * dt;

    /* 1. unequal steps, a quadratic law: the parabola is exact, the line misses by c2 (tn - tl)(tn - tb) */
    history(&s, quadratic, dto, dtb, dtl);
    s.parabola = 1;
    int r = predict(&s, dt, s.alpha_last, a, other);
    check(r == 2, "three steps give both predictions", r);
    check(worst(a, quadratic, tn) <= 1e-13, "the parabola is exact on a quadratic", worst(a, quadratic, tn));
    double line_error = 0.0;
    for (int i = 0; i < N_Q; i++) {
        const double expected = (3.0 - 2.0 * i) * (tn + 0.5 * dtl) * (tn + dtl + 0.5 * dtb);
        line_error = fmax(line_error, fabs((quadratic(i, tn) - other[i]) - expected));
    }
    check(line_error <= 1e-13, "the line misses by c2 (tn - tl)(tn - tb)", line_error);
    s.parabola = 0;
    predict(&s, dt, s.alpha_last, a, other);
    check(worst(other, quadratic, tn) <= 1e-13 && worst(a, quadratic, tn) > 1e-6,
          "the line starts unless chosen, the parabola at hand", worst(other, quadratic, tn));
    s.depth = 2;
    check(predict(&s, dt, s.alpha_last, a, other) == 1, "two steps: the line only", 0.0);
    double moved[N_Q];
    memcpy(moved, s.alpha_last, sizeof(moved));
    moved[0] += 1e-9;
    check(predict(&s, dt, moved, a, other) == 0, "an acceleration not the last one returned: no prediction", 0.0);

    /* 2. a smooth law at equal steps h and h/2: the parabola's error falls like h^3, the line's like h^2 */
    double e_line[2], e_parabola[2];
    for (int k = 0; k < 2; k++) {
        const double h = 0.02 / (1 << k);
        history(&s, omega_t, h, h, h);
        s.parabola = 1;
        predict(&s, h, s.alpha_last, a, other);
        e_parabola[k] = worst(a, omega_t, 0.5 * h);
        e_line[k] = worst(other, omega_t, 0.5 * h);
    }
    check(fabs(log2(e_parabola[0] / e_parabola[1]) - 3.0) < 0.1, "parabola's order (h, h/2)",
          log2(e_parabola[0] / e_parabola[1]));
    check(fabs(log2(e_line[0] / e_line[1]) - 2.0) < 0.1, "line's order (h, h/2)", log2(e_line[0] / e_line[1]));

    /* 3. the choice follows the running mean of log(parabola's miss / line's miss), not one step */
    memset(&s, 0, sizeof(s));
    for (int i = 0; i < N_Q; i++) {
        sol[i] = 1.0;
        near[i] = 1.0 + 1e-6 * MODEL_NOMINAL_Q[i];
        far[i] = 1.0 + 1e-3 * MODEL_NOMINAL_Q[i];
    }
    compare(&s, near, far);                        /* the parabola 1e-6 off, the line 1e-3 */
    check(s.parabola == 1 && s.predictor_bias == -1.0 / SS22_PREDICTOR_MEMORY, "a better parabola takes over",
          s.predictor_bias);
    for (int k = 0; k < 9; k++) compare(&s, near, far);
    compare(&s, far, near);                        /* one step the other way */
    check(s.parabola == 1, "one contrary step after ten does not hand back", s.predictor_bias);
    for (int k = 0; k < 20; k++) compare(&s, far, near);
    check(s.parabola == 0, "a line better for many steps takes back", s.predictor_bias);
    return failures != 0;
}
