/* The runtime of generated C source: the source waveforms (pulse, sine,
   sffm, expo, pwl, with their time derivatives), ngspice's level-1 diode, a dense
   solve, the damped Newton of algebraic loops and the implicit tangents of
   their unknowns.

   codegen::c copies everything below the marker line into every generated
   file, byte for byte: generated code calls these functions by name and
   argument order. A unit test compiles this file as ISO C99 with all
   warnings as errors. */
/* ---- everything below is copied into generated source ---- */

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* ISO C has no M_PI or M_E (POSIX does). */
#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif
#ifndef M_E
#define M_E 2.71828182845904523536
#endif

static inline double pulse(double t, int o, double v1, double v2, double td, double tr, double tf, double pw, double per) {
    if (t < td) return o == 0 ? v1 : 0.0;
    double tt = t - td;
    if (per > 0.0 && (o == 0 ? tt > per : tt >= per)) tt -= floor(tt / per) * per;
    double val, s;
    if (tt < tr) { s = (v2 - v1) / tr; val = v1 + (v2 - v1) * (tt / tr); }
    else if (tt < tr + pw) { s = 0.0; val = v2; }
    else if (tt < tr + pw + tf) { s = (v1 - v2) / tf; val = v2 + (v1 - v2) * ((tt - tr - pw) / tf); }
    else { s = 0.0; val = v1; }
    if (!isfinite(s)) s = 0.0;
    return o == 0 ? val : (o == 1 ? s : 0.0);
}

static inline double sine(double t, int o, double vo, double va, double freq, double td, double theta, double phase) {
    double ph = phase * M_PI / 180.0;
    if (t < td) return o == 0 ? vo + va * sin(ph) : 0.0;
    double s = t - td, w = 2.0 * M_PI * freq, cr = 1.0, ci = 0.0;
    for (int k = 0; k < o; k++) { double nr = -cr * theta - ci * w, ni = cr * w - ci * theta; cr = nr; ci = ni; }
    double d = va * exp(-theta * s) * (cr * sin(w * s + ph) + ci * cos(w * s + ph));
    return o == 0 ? vo + d : d;
}

/* SFFM: the Taylor coefficients of sin(wc t + mdi sin(ws t)) up to order o
   (at most 31; a higher order gives NaN). */
static inline double sffm(double t, int o, double vo, double va, double fc, double mdi, double fs) {
    if (o > 31) return NAN;
    int n = o + 1;
    double wc = 2.0 * M_PI * fc, ws = 2.0 * M_PI * fs, si[32], ci[32], phi[32], y[32], z[32];
    si[0] = sin(ws * t); ci[0] = cos(ws * t);
    for (int k = 1; k < n; k++) { si[k] = ws * ci[k - 1] / k; ci[k] = -ws * si[k - 1] / k; }
    for (int k = 0; k < n; k++) phi[k] = mdi * si[k] + (k == 0 ? wc * t : (k == 1 ? wc : 0.0));
    y[0] = sin(phi[0]); z[0] = cos(phi[0]);
    for (int k = 1; k < n; k++) {
        double sy = 0.0, sz = 0.0;
        for (int j = 1; j <= k; j++) { sy += j * phi[j] * z[k - j]; sz -= j * phi[j] * y[k - j]; }
        y[k] = sy / k; z[k] = sz / k;
    }
    double f = 1.0;
    for (int k = 2; k < n; k++) f *= k;
    double d = va * y[n - 1] * f;
    return o == 0 ? vo + d : d;
}

static inline double expo(double t, int o, double v1, double v2, double td1, double tau1, double td2, double tau2) {
    double val = o == 0 ? v1 : 0.0;
    if (t >= td1) { double e = exp(-(t - td1) / tau1); val += o == 0 ? (v2 - v1) * (1.0 - e) : -(v2 - v1) * pow(-1.0 / tau1, o) * e; }
    if (t >= td2) { double e = exp(-(t - td2) / tau2); val += o == 0 ? (v1 - v2) * (1.0 - e) : -(v1 - v2) * pow(-1.0 / tau2, o) * e; }
    return val;
}

static inline double pwl(double t, int o, const double *ts, const double *ys, int n) {
    if (n == 0) return 0.0;
    if (isnan(t)) return NAN;
    if (t < ts[0]) return o == 0 ? ys[0] : 0.0;
    int k = 0;
    while (k < n && ts[k] <= t) k++;
    if (k >= n) return o == 0 ? ys[n - 1] : 0.0;
    double s = ts[k] > ts[k - 1] ? (ys[k] - ys[k - 1]) / (ts[k] - ts[k - 1]) : 0.0;
    return o == 0 ? ys[k - 1] + s * (t - ts[k - 1]) : (o == 1 ? s : 0.0);
}

static inline double diode(int part, int o, double v, double is, double vte, double bv, double g, double cjo, double vj, double m, double fc, double tt) {
    double id[3], vlin = 50.0 * vte;
    if (v > vlin) { double e = exp(vlin / vte); id[0] = is * (e * (1.0 + (v - vlin) / vte) - 1.0) + g * v; id[1] = is * e / vte + g; id[2] = 0.0; }
    else if (v >= -3.0 * vte) { double e = exp(v / vte); id[0] = is * (e - 1.0) + g * v; id[1] = is * e / vte + g; id[2] = is * e / (vte * vte); }
    else if (v >= -bv) { double a = 3.0 * vte / (v * M_E), arg = a * a * a; id[0] = -is * (1.0 + arg) + g * v; id[1] = 3.0 * is * arg / v + g; id[2] = -12.0 * is * arg / (v * v); }
    else { double e = exp(-(bv + v) / vte); id[0] = -is * e + g * v; id[1] = is * e / vte + g; id[2] = -is * e / (vte * vte); }
    if (part == 0) return id[o];
    double q[3] = {tt * id[0], tt * id[1], tt * id[2]};
    if (cjo != 0.0) {
        double d = fc * vj;
        if (v < d) { double arg = 1.0 - v / vj, sarg = exp(-m * log(arg)); q[0] += vj * cjo * (1.0 - arg * sarg) / (1.0 - m); q[1] += cjo * sarg; q[2] += cjo * m / vj * sarg / arg; }
        else { double f1 = vj * (1.0 - pow(1.0 - fc, 1.0 - m)) / (1.0 - m), f2 = pow(1.0 - fc, 1.0 + m), f3 = 1.0 - fc * (1.0 + m), c = cjo / f2;
            q[0] += cjo * f1 + c * (f3 * (v - d) + m / (2.0 * vj) * (v * v - d * d)); q[1] += c * (f3 + m * v / vj); q[2] += c * m / vj; }
    }
    return q[o];
}

typedef void (*resid_fn)(double, const double *, const double *, double *, double *);

/* Solve a x = b in place (b becomes x): Gaussian elimination with partial pivoting. */
static inline void lin_solve(int n, double *a, double *b) {
    for (int k = 0; k < n; k++) {
        int piv = k; for (int i = k + 1; i < n; i++) if (fabs(a[i * n + k]) > fabs(a[piv * n + k])) piv = i;
        for (int j = 0; j < n; j++) { double s = a[k * n + j]; a[k * n + j] = a[piv * n + j]; a[piv * n + j] = s; }
        double s = b[k]; b[k] = b[piv]; b[piv] = s;
        for (int i = k + 1; i < n; i++) { double q = a[i * n + k] / a[k * n + k]; for (int j = k; j < n; j++) a[i * n + j] -= q * a[k * n + j]; b[i] -= q * b[k]; }
    }
    for (int k = n - 1; k >= 0; k--) { double s = b[k]; for (int j = k + 1; j < n; j++) s -= a[k * n + j] * b[j]; b[k] = s / a[k * n + k]; }
}

typedef void (*tan_fn)(double, const double *, const double *, const double *, double *, double *);

/* Damped Newton on the tearing variables. The Jacobian is exact: `tan` gives
   the residuals' tangents along one tear at a time (a finite difference loses
   a femtofarad capacitance's column to rounding); `nv` is the number of
   variables, the size of its tangent scratch. */
static inline void newton(int n, const int *tears, double t, const double *y, const double *p, double *v, resid_fn f, tan_fn tan, int nv) {
    double *r = malloc(sizeof(double) * (size_t)(4 * n + n * n));
    double *dv = calloc((size_t)nv, sizeof(double));
    if (!r || !dv) { free(r); free(dv); for (int j = 0; j < n; j++) v[tears[j]] = NAN; return; }
    double *r1 = r + n, *dx = r + 2 * n, *x0 = r + 3 * n, *a = r + 4 * n;
    for (int it = 0; it < 100; it++) {
        f(t, y, p, v, r);
        double base = 0.0; for (int i = 0; i < n; i++) base += r[i] * r[i];
        if (base == 0.0) break;
        for (int j = 0; j < n; j++) {
            dv[tears[j]] = 1.0; tan(t, y, p, v, dv, r1); dv[tears[j]] = 0.0;
            for (int i = 0; i < n; i++) a[i * n + j] = r1[i];
        }
        memcpy(dx, r, sizeof(double) * (size_t)n);
        lin_solve(n, a, dx);
        for (int j = 0; j < n; j++) x0[j] = v[tears[j]];
        double lambda = 1.0;
        for (;;) {
            for (int j = 0; j < n; j++) v[tears[j]] = x0[j] - lambda * dx[j];
            f(t, y, p, v, r1);
            double nn = 0.0; for (int i = 0; i < n; i++) nn += r1[i] * r1[i];
            if (nn < base || lambda < 1e-8) break;
            lambda *= 0.5;
        }
        int small = 1; for (int j = 0; j < n; j++) if (fabs(lambda * dx[j]) > 1e-14 * (1.0 + fabs(x0[j]))) small = 0;
        if (small) break;
    }
    free(r);
    free(dv);
}

/* The tangents of a loop's unknowns by implicit differentiation: f writes the
   tangents inside the loop and of its residuals, which are affine in the
   tears' tangents; they are solved for dr = 0. */
static inline void tangent_solve(int n, const int *tears, double t, const double *y, const double *p, const double *v, double *dv, tan_fn f, int nv) {
    double *b = malloc(sizeof(double) * (size_t)(2 * n + n * n));
    double *z = calloc((size_t)nv, sizeof(double));
    if (!b || !z) { free(b); free(z); for (int j = 0; j < n; j++) dv[tears[j]] = NAN; return; }
    double *c = b + n, *a = b + 2 * n;
    for (int j = 0; j < n; j++) dv[tears[j]] = 0.0;
    f(t, y, p, v, dv, b);
    /* The coefficients from a scratch with no input tangents (a difference
       with the inputs' residual would cancel them to rounding). */
    for (int j = 0; j < n; j++) {
        z[tears[j]] = 1.0; f(t, y, p, v, z, c); z[tears[j]] = 0.0;
        for (int i = 0; i < n; i++) a[i * n + j] = c[i];
    }
    lin_solve(n, a, b);
    for (int j = 0; j < n; j++) dv[tears[j]] = -b[j];
    f(t, y, p, v, dv, c);
    free(b);
    free(z);
}
