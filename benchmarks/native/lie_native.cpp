// A plain, vectorised C++ baseline for benchmarks/native.py: the operations of every group
// (SO2, SE2, SO3, SE3, Sim3, SE23) written from the formulas of MATH.md as flat loops over arrays
// of parameters (the same row layout as microlie: SO3 (qx,qy,qz,qw), SE3 (tx,ty,tz,qx,qy,qz,qw),
// tangents translation first (rho, phi); the other layouts at their sections below).
//
// Built by benchmarks/native.py into a shared library (called through ctypes, timed interleaved
// with microlie):  g++ -O3 -march=native -fno-math-errno -fopenmp-simd -shared -fPIC -lmvec
// The "declare simd" lines let GCC call glibc's libmvec for tan/atan2 inside vectorised loops
// without -ffast-math (IEEE semantics kept).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

extern "C" {
#pragma omp declare simd notinbranch
double exp(double);
#pragma omp declare simd notinbranch
double expm1(double);
#pragma omp declare simd notinbranch
double log(double);
#pragma omp declare simd notinbranch
double tan(double);
#pragma omp declare simd notinbranch
double atan2(double, double);
}

static inline void cross(const double a[3], const double b[3], double c[3]) {
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

// sin(t/2)/t and cos(t/2) from t^2 (Taylor below 1e-8)
#pragma omp declare simd notinbranch
static inline void half(double t2, double *k, double *ch) {
    bool small = t2 < 1e-8;
    double t = std::sqrt(small ? 1.0 : t2);
    double u = tan(0.25 * t), u2 = u * u, r = 1.0 / (1.0 + u2);
    *k = small ? 0.5 - t2 / 48.0 : 2.0 * r * u / t;
    *ch = small ? 1.0 - 0.125 * t2 : (1.0 - u2) * r;
}

static inline void qrot(const double q[4], const double v[3], double out[3]) {
    double u[3] = {q[0], q[1], q[2]}, c[3], d[3];
    cross(u, v, c);
    for (int i = 0; i < 3; i++) c[i] *= 2.0;
    cross(u, c, d);
    for (int i = 0; i < 3; i++) out[i] = v[i] + q[3] * c[i] + d[i];
}

static inline void qmul(const double a[4], const double b[4], double o[4]) {
    o[0] = a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1];
    o[1] = a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0];
    o[2] = a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3];
    o[3] = a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2];
}

static inline void qlog(const double q[4], double phi[3]) {
    double n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
    bool small = n2 < 1e-16;
    double n = std::sqrt(small ? 1.0 : n2);
    double aw = std::fabs(q[3]);
    double kl = small ? 2.0 + n2 / 3.0 : 2.0 * atan2(n, aw) / n;
    if (q[3] < 0) kl = -kl;
    for (int i = 0; i < 3; i++) phi[i] = kl * q[i];
}

static void so3_exp(const double *tau, double *q, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *w = tau + 3 * i;
        double k, ch;
        half(w[0] * w[0] + w[1] * w[1] + w[2] * w[2], &k, &ch);
        double *o = q + 4 * i;
        o[0] = k * w[0]; o[1] = k * w[1]; o[2] = k * w[2]; o[3] = ch;
    }
}

static void so3_log(const double *q, double *phi, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) qlog(q + 4 * i, phi + 3 * i);
}

// (t - sin t)/t^3 from the half-angle functions
static inline double coef_b(double t2, double k, double ch) {
    return t2 < 1e-4 ? 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 : (1.0 - 2.0 * k * ch) / t2;
}

// (1 - (t/2) cot(t/2)) / t^2
static inline double coef_c(double t2, double k, double ch) {
    return t2 < 1e-4 ? 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0 : (1.0 - ch / (2.0 * k)) / t2;
}

static void se3_exp(const double *tau, double *p, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *rho = tau + 6 * i, *phi = rho + 3;
        double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2], k, ch;
        half(t2, &k, &ch);
        double a = 2.0 * k * k, b = coef_b(t2, k, ch), c[3], d[3];
        cross(phi, rho, c);
        cross(phi, c, d);
        double *o = p + 7 * i;
        for (int j = 0; j < 3; j++) o[j] = rho[j] + a * c[j] + b * d[j];
        o[3] = k * phi[0]; o[4] = k * phi[1]; o[5] = k * phi[2]; o[6] = ch;
    }
}

static void se3_log(const double *p, double *tau, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *t = p + 7 * i, *q = t + 3;
        double *rho = tau + 6 * i, *phi = rho + 3;
        qlog(q, phi);
        double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2];
        double s = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        double th = std::sqrt(t2);
        double k = t2 < 1e-16 ? 0.5 : s / th, ch = std::fabs(q[3]);
        double c = coef_c(t2, k, ch), a[3], b[3];
        cross(phi, t, a);
        cross(phi, a, b);
        for (int j = 0; j < 3; j++) rho[j] = t[j] - 0.5 * a[j] + c * b[j];
    }
}

static void se3_compose(const double *p, const double *q, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *a = p + 7 * i, *b = q + 7 * i;
        double *r = o + 7 * i, t[3];
        qrot(a + 3, b, t);
        for (int j = 0; j < 3; j++) r[j] = a[j] + t[j];
        qmul(a + 3, b + 3, r + 3);
    }
}

static void so3_compose(const double *p, const double *q, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) qmul(p + 4 * i, q + 4 * i, o + 4 * i);
}

static void so3_act(const double *q, const double *v, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) qrot(q + 4 * i, v + 3 * i, o + 3 * i);
}

static void se3_act(const double *p, const double *v, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *a = p + 7 * i;
        double t[3];
        qrot(a + 3, v + 3 * i, t);
        for (int j = 0; j < 3; j++) o[3 * i + j] = a[j] + t[j];
    }
}

static inline void qmat(const double q[4], double R[9]) {
    double x = q[0], y = q[1], z = q[2], w = q[3];
    R[0] = 1 - 2 * (y * y + z * z); R[1] = 2 * (x * y - w * z); R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z); R[4] = 1 - 2 * (x * x + z * z); R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y); R[7] = 2 * (y * z + w * x); R[8] = 1 - 2 * (x * x + y * y);
}

// act with Jacobians: d/dT (right) = [R, -R hat(v)] (3x6), d/dv = R (3x3)
static void se3_act_jac(const double *p, const double *v, double *o, double *JT, double *Jv,
                        long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *a = p + 7 * i, *x = v + 3 * i;
        double R[9];
        qmat(a + 3, R);
        for (int r = 0; r < 3; r++) {
            o[3 * i + r] = a[r] + R[3 * r] * x[0] + R[3 * r + 1] * x[1] + R[3 * r + 2] * x[2];
            double *J = JT + 18 * i + 6 * r;
            J[0] = R[3 * r]; J[1] = R[3 * r + 1]; J[2] = R[3 * r + 2];
            // -R hat(x): row r = -(R_r x hat(x)) = R_r cross ... (R_r . hat(x))_j
            J[3] = -(R[3 * r + 1] * x[2] - R[3 * r + 2] * x[1]);
            J[4] = -(R[3 * r + 2] * x[0] - R[3 * r] * x[2]);
            J[5] = -(R[3 * r] * x[1] - R[3 * r + 1] * x[0]);
            for (int c = 0; c < 3; c++) Jv[9 * i + 3 * r + c] = R[3 * r + c];
        }
    }
}

// SO3 right Jacobian I + a hat(w) + b hat(w)^2 into a 6x6 (row stride 6) block
static inline void so3_ihat(double a, double b, const double w[3], double *J, int ld) {
    double t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            J[r * ld + c] = (r == c ? 1.0 - b * t2 : 0.0) + b * w[r] * w[c];
    J[0 * ld + 1] -= a * w[2]; J[0 * ld + 2] += a * w[1];
    J[1 * ld + 0] += a * w[2]; J[1 * ld + 2] -= a * w[0];
    J[2 * ld + 0] -= a * w[1]; J[2 * ld + 1] += a * w[0];
}

// Q(rho, phi) (Barfoot's left-Jacobian block, MATH.md section 4) from the half-angle functions
// of |phi|: (t^2 + 2 cos t - 2)/(2 t^4) and (2 t - 3 sin t + t cos t)/(2 t^5) from k and ch
static inline void q_block(const double rho[3], const double phi[3], double t2, double k,
                           double ch, double Q[9]) {
    double b = coef_b(t2, k, ch);
    double c3 = t2 < 1e-4 ? 1.0 / 24.0 - t2 / 720.0 : (1.0 - 4.0 * k * k) / (2.0 * t2);
    double c4 = t2 < 1e-4 ? 1.0 / 120.0 - t2 / 2520.0
                          : (3.0 - 6.0 * k * ch - 2.0 * k * k * t2) / (2.0 * t2 * t2);
    double P[9] = {0, -rho[2], rho[1], rho[2], 0, -rho[0], -rho[1], rho[0], 0};
    double F[9] = {0, -phi[2], phi[1], phi[2], 0, -phi[0], -phi[1], phi[0], 0};
    double FP[9], PF[9], FPF[9], FF[9], FFP[9], PFF[9], FPFF[9], FFPF[9];
    auto mm = [](const double *A, const double *B, double *C) {
        for (int r = 0; r < 3; r++)
            for (int s = 0; s < 3; s++)
                C[3 * r + s] = A[3 * r] * B[s] + A[3 * r + 1] * B[3 + s] + A[3 * r + 2] * B[6 + s];
    };
    mm(F, P, FP); mm(P, F, PF); mm(FP, F, FPF); mm(F, F, FF); mm(FF, P, FFP); mm(PF, F, PFF);
    mm(FPF, F, FPFF); mm(F, FPF, FFPF);
    for (int e = 0; e < 9; e++)
        Q[e] = 0.5 * P[e] + b * (FP[e] + PF[e] + FPF[e]) + c3 * (FFP[e] + PFF[e] - 3.0 * FPF[e])
               + c4 * (FPFF[e] + FFPF[e]);
}

// SE3 exp with its right Jacobian Jr = [[Jr(phi), Q(-rho,-phi)], [0, Jr(phi)]]
static void se3_exp_jac(const double *tau, double *p, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *rho = tau + 6 * i, *phi = rho + 3;
        double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2], k, ch;
        half(t2, &k, &ch);
        double a = 2.0 * k * k, b = coef_b(t2, k, ch), c[3], d[3];
        cross(phi, rho, c);
        cross(phi, c, d);
        double *o = p + 7 * i;
        for (int j = 0; j < 3; j++) o[j] = rho[j] + a * c[j] + b * d[j];
        o[3] = k * phi[0]; o[4] = k * phi[1]; o[5] = k * phi[2]; o[6] = ch;
        double *Ji = J + 36 * i;
        so3_ihat(-a, b, phi, Ji, 6);
        so3_ihat(-a, b, phi, Ji + 21, 6);
        double mr[3] = {-rho[0], -rho[1], -rho[2]}, mp[3] = {-phi[0], -phi[1], -phi[2]}, Q[9];
        q_block(mr, mp, t2, k, ch, Q);  // Q(-rho, -phi)
        for (int r = 0; r < 3; r++)
            for (int s = 0; s < 3; s++) {
                Ji[6 * r + 3 + s] = Q[3 * r + s];
                Ji[6 * (r + 3) + s] = 0.0;
            }
    }
}

// ------------------------------------------------------------ more Jacobian operations
// (the acceptance list of issue 11: exp, minus, between, act with jac=True, SO3 and SE3)

static inline void qconj(const double q[4], double o[4]) {
    o[0] = -q[0]; o[1] = -q[1]; o[2] = -q[2]; o[3] = q[3];
}

// I + a hat(w) + b hat(w)^2 into a 3x3 block with row stride ld, times s
static inline void ihat(double a, double b, const double w[3], double *J, int ld) {
    so3_ihat(a, b, w, J, ld);
}

static void so3_exp_jac(const double *tau, double *q, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *w = tau + 3 * i;
        double t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2], k, ch;
        half(t2, &k, &ch);
        double *o = q + 4 * i;
        o[0] = k * w[0]; o[1] = k * w[1]; o[2] = k * w[2]; o[3] = ch;
        ihat(-2.0 * k * k, coef_b(t2, k, ch), w, J + 9 * i, 3);
    }
}

// R v, d/dR (right) = -R hat(v), d/dv = R
static void so3_act_jac(const double *q, const double *v, double *o, double *JR, double *Jv,
                        long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *x = v + 3 * i;
        double R[9];
        qmat(q + 4 * i, R);
        for (int r = 0; r < 3; r++) {
            o[3 * i + r] = R[3 * r] * x[0] + R[3 * r + 1] * x[1] + R[3 * r + 2] * x[2];
            double *J = JR + 9 * i + 3 * r;
            J[0] = -(R[3 * r + 1] * x[2] - R[3 * r + 2] * x[1]);
            J[1] = -(R[3 * r + 2] * x[0] - R[3 * r] * x[2]);
            J[2] = -(R[3 * r] * x[1] - R[3 * r + 1] * x[0]);
            for (int c = 0; c < 3; c++) Jv[9 * i + 3 * r + c] = R[3 * r + c];
        }
    }
}

// z = p^-1 q and d z / d p = -Ad(z^-1) = -R(z)^T (d z / d q = I is not written)
static void so3_between_jac(const double *p, const double *q, double *z, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double c[4], R[9];
        qconj(p + 4 * i, c);
        double *o = z + 4 * i;
        qmul(c, q + 4 * i, o);
        qmat(o, R);
        for (int r = 0; r < 3; r++)
            for (int s = 0; s < 3; s++) J[9 * i + 3 * r + s] = -R[3 * s + r];
    }
}

// tau = Log(x^-1 y), d tau / d y = Jr^-1(tau), d tau / d x = -Jl^-1(tau) = -Jr^-1(tau)^T
static void so3_minus_jac(const double *y, const double *x, double *tau, double *Jy, double *Jx,
                          long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double c[4], z[4];
        qconj(x + 4 * i, c);
        qmul(c, y + 4 * i, z);
        double *w = tau + 3 * i;
        qlog(z, w);
        double t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
        double s = std::sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2]);
        double k = t2 < 1e-16 ? 0.5 : s / std::sqrt(t2), ch = std::fabs(z[3]);
        double *A = Jy + 9 * i, *B = Jx + 9 * i;
        ihat(0.5, coef_c(t2, k, ch), w, A, 3);
        for (int r = 0; r < 3; r++)
            for (int q = 0; q < 3; q++) B[3 * r + q] = -A[3 * q + r];
    }
}

// inverse of an SE3 row
static inline void se3_inv(const double *a, double *o) {
    qconj(a + 3, o + 3);
    double t[3];
    qrot(o + 3, a, t);
    o[0] = -t[0]; o[1] = -t[1]; o[2] = -t[2];
}

// z = p^-1 q and d z / d p = -Ad(z^-1), Ad(g) = [[R, hat(t) R], [0, R]]
static void se3_between_jac(const double *p, const double *q, double *z, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *a = p + 7 * i, *b = q + 7 * i;
        double pi[7], zi[7], t[3], R[9];
        double *o = z + 7 * i;
        se3_inv(a, pi);
        qrot(pi + 3, b, t);
        for (int j = 0; j < 3; j++) o[j] = pi[j] + t[j];
        qmul(pi + 3, b + 3, o + 3);
        se3_inv(o, zi);
        qmat(zi + 3, R);
        double *Ji = J + 36 * i;
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++) {
                // (hat(t) R)_{rc} = t x R_col c
                int r1 = (r + 1) % 3, r2 = (r + 2) % 3;
                double tr = zi[r1] * R[3 * r2 + c] - zi[r2] * R[3 * r1 + c];
                Ji[6 * r + c] = -R[3 * r + c];
                Ji[6 * r + 3 + c] = -tr;
                Ji[6 * (r + 3) + c] = 0.0;
                Ji[6 * (r + 3) + 3 + c] = -R[3 * r + c];
            }
    }
}

// [[Ji, -Ji Q Ji], [0, Ji]] into a 6x6, times s
static inline void jinv6(const double Ji[9], const double Q[9], double s, double *J) {
    double T[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            T[3 * r + c] = Q[3 * r] * Ji[c] + Q[3 * r + 1] * Ji[3 + c] + Q[3 * r + 2] * Ji[6 + c];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            double m = Ji[3 * r] * T[c] + Ji[3 * r + 1] * T[3 + c] + Ji[3 * r + 2] * T[6 + c];
            J[6 * r + c] = s * Ji[3 * r + c];
            J[6 * r + 3 + c] = -s * m;
            J[6 * (r + 3) + c] = 0.0;
            J[6 * (r + 3) + 3 + c] = s * Ji[3 * r + c];
        }
}

// tau = Log(x^-1 y), d tau / d y = Jr^-1(tau), d tau / d x = -Jl^-1(tau) = -Jr^-1(-tau)
static void se3_minus_jac(const double *y, const double *x, double *tau, double *Jy, double *Jx,
                          long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double xi[7], z[7], t[3];
        se3_inv(x + 7 * i, xi);
        qrot(xi + 3, y + 7 * i, t);
        for (int j = 0; j < 3; j++) z[j] = xi[j] + t[j];
        qmul(xi + 3, y + 7 * i + 3, z + 3);
        double *rho = tau + 6 * i, *phi = rho + 3;
        qlog(z + 3, phi);
        double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2];
        double s = std::sqrt(z[3] * z[3] + z[4] * z[4] + z[5] * z[5]);
        double k = t2 < 1e-16 ? 0.5 : s / std::sqrt(t2), ch = std::fabs(z[6]);
        double c = coef_c(t2, k, ch), a[3], b[3];
        cross(phi, z, a);
        cross(phi, a, b);
        for (int j = 0; j < 3; j++) rho[j] = z[j] - 0.5 * a[j] + c * b[j];
        double Ji[9], Jt[9], Qm[9], Qp[9], mr[3] = {-rho[0], -rho[1], -rho[2]},
                                          mp[3] = {-phi[0], -phi[1], -phi[2]};
        ihat(0.5, c, phi, Ji, 3);  // Jr^-1(phi); Jl^-1(phi) = Jr^-1(-phi) = Ji^T
        for (int r = 0; r < 3; r++)
            for (int q = 0; q < 3; q++) Jt[3 * r + q] = Ji[3 * q + r];
        q_block(mr, mp, t2, k, ch, Qm);  // Q(-rho, -phi): Jr^-1(tau)'s block
        q_block(rho, phi, t2, k, ch, Qp);  // Q(rho, phi): Jl^-1(tau)'s block
        jinv6(Ji, Qm, 1.0, Jy + 36 * i);
        jinv6(Jt, Qp, -1.0, Jx + 36 * i);
    }
}

// ------------------------------------------------------------ SO(2) and SE(2) (MATH.md section 6)
// SO2 (c, s), tangent theta; SE2 (x, y, c, s), tangent (rho1, rho2, theta). Sines and cosines
// from one tan of the half angle (vectorised by libmvec; no sincos merge).

// cos t, sin t, sin t / t, (1 - cos t) / t^2, (t - sin t) / t^3 of t (small-angle series inside)
static inline void trig(double t, double *c, double *s, double *a, double *b2, double *b3) {
    double t2 = t * t, k, ch;
    half(t2, &k, &ch);
    *c = 2.0 * ch * ch - 1.0;
    *s = 2.0 * k * ch * t;
    *a = 2.0 * k * ch;
    *b2 = 2.0 * k * k;
    *b3 = coef_b(t2, k, ch);
}

// (t / 2) cot(t / 2) from cos t, sin t (the two forms: no cancellation near 0 or near pi)
static inline double half_cot(double t, double c, double s) {
    bool small = t * t < 1e-8;
    double r = c >= 0.0 ? (1.0 + c) / (small ? 1.0 : s) : s / (1.0 - c);
    return small ? 1.0 - t * t / 12.0 : 0.5 * t * r;
}

static void so2_exp(const double *t, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double c, s, a, b2, b3;
        trig(t[i], &c, &s, &a, &b2, &b3);
        o[2 * i] = c; o[2 * i + 1] = s;
    }
}

static void so2_log(const double *p, double *t, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) t[i] = atan2(p[2 * i + 1], p[2 * i]);
}

static inline void cmul(const double *a, const double *b, double *o) {
    double c = a[0] * b[0] - a[1] * b[1], s = a[1] * b[0] + a[0] * b[1];
    o[0] = c; o[1] = s;
}

static void so2_compose(const double *p, const double *q, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) cmul(p + 2 * i, q + 2 * i, o + 2 * i);
}

static void so2_act(const double *p, const double *v, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) cmul(p + 2 * i, v + 2 * i, o + 2 * i);
}

static void so2_exp_jac(const double *t, double *o, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double c, s, a, b2, b3;
        trig(t[i], &c, &s, &a, &b2, &b3);
        o[2 * i] = c; o[2 * i + 1] = s; J[i] = 1.0;
    }
}

// R v; d/dtheta = R (-v2, v1), d/dv = R
static void so2_act_jac(const double *p, const double *v, double *o, double *JR, double *Jv,
                        long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double c = p[2 * i], s = p[2 * i + 1], x = v[2 * i], y = v[2 * i + 1];
        double ox = c * x - s * y, oy = s * x + c * y;
        o[2 * i] = ox; o[2 * i + 1] = oy;
        JR[2 * i] = -oy; JR[2 * i + 1] = ox;
        double *J = Jv + 4 * i;
        J[0] = c; J[1] = -s; J[2] = s; J[3] = c;
    }
}

static void so2_between_jac(const double *p, const double *q, double *z, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double a[2] = {p[2 * i], -p[2 * i + 1]};
        cmul(a, q + 2 * i, z + 2 * i);
        J[i] = -1.0;
    }
}

static void so2_minus_jac(const double *y, const double *x, double *t, double *Jy, double *Jx,
                          long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double a[2] = {x[2 * i], -x[2 * i + 1]}, z[2];
        cmul(a, y + 2 * i, z);
        t[i] = atan2(z[1], z[0]);
        Jy[i] = 1.0; Jx[i] = -1.0;
    }
}

static void se2_exp(const double *tau, double *p, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *r = tau + 3 * i;
        double c, s, a, b2, b3, *o = p + 4 * i;
        trig(r[2], &c, &s, &a, &b2, &b3);
        double b = b2 * r[2];  // (1 - cos t) / t
        o[0] = a * r[0] - b * r[1]; o[1] = b * r[0] + a * r[1]; o[2] = c; o[3] = s;
    }
}

static void se2_log(const double *p, double *tau, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *x = p + 4 * i;
        double *r = tau + 3 * i, t = atan2(x[3], x[2]), A = half_cot(t, x[2], x[3]);
        r[0] = A * x[0] + 0.5 * t * x[1]; r[1] = -0.5 * t * x[0] + A * x[1]; r[2] = t;
    }
}

static inline void se2_mul(const double *a, const double *b, double *o) {
    double x = a[0] + a[2] * b[0] - a[3] * b[1], y = a[1] + a[3] * b[0] + a[2] * b[1];
    cmul(a + 2, b + 2, o + 2);
    o[0] = x; o[1] = y;
}

static inline void se2_inv(const double *a, double *o) {
    double c = a[2], s = a[3];
    o[0] = -(c * a[0] + s * a[1]); o[1] = -(-s * a[0] + c * a[1]); o[2] = c; o[3] = -s;
}

static void se2_compose(const double *p, const double *q, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) se2_mul(p + 4 * i, q + 4 * i, o + 4 * i);
}

static void se2_act(const double *p, const double *v, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *a = p + 4 * i, *x = v + 2 * i;
        o[2 * i] = a[0] + a[2] * x[0] - a[3] * x[1];
        o[2 * i + 1] = a[1] + a[3] * x[0] + a[2] * x[1];
    }
}

// Jr(rho, t) of MATH.md section 6 into J (3x3), given sin t / t, (1 - cos t)/t^2, (t - sin t)/t^3
static inline void se2_jr(const double *r, double a, double b2, double b3, double *J) {
    double t = r[2], b = b2 * t, e = b3 * t;  // e = (t - sin t) / t^2
    J[0] = a; J[1] = b; J[2] = e * r[0] - b2 * r[1];
    J[3] = -b; J[4] = a; J[5] = b2 * r[0] + e * r[1];
    J[6] = 0.0; J[7] = 0.0; J[8] = 1.0;
}

static void se2_exp_jac(const double *tau, double *p, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *r = tau + 3 * i;
        double c, s, a, b2, b3, *o = p + 4 * i;
        trig(r[2], &c, &s, &a, &b2, &b3);
        double b = b2 * r[2];
        o[0] = a * r[0] - b * r[1]; o[1] = b * r[0] + a * r[1]; o[2] = c; o[3] = s;
        se2_jr(r, a, b2, b3, J + 9 * i);
    }
}

// R v + t; d/dT (right) = [R, R (-v2, v1)], d/dv = R
static void se2_act_jac(const double *p, const double *v, double *o, double *JT, double *Jv,
                        long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *a = p + 4 * i, *x = v + 2 * i;
        double c = a[2], s = a[3], rx = c * x[0] - s * x[1], ry = s * x[0] + c * x[1];
        o[2 * i] = a[0] + rx; o[2 * i + 1] = a[1] + ry;
        double *J = JT + 6 * i, *K = Jv + 4 * i;
        J[0] = c; J[1] = -s; J[2] = -ry; J[3] = s; J[4] = c; J[5] = rx;
        K[0] = c; K[1] = -s; K[2] = s; K[3] = c;
    }
}

// z = p^-1 q, d z / d p = -Ad(z^-1), Ad(g) = [[R, (t2, -t1)], [0, 1]]
static void se2_between_jac(const double *p, const double *q, double *z, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double pi[4], zi[4], *o = z + 4 * i, *K = J + 9 * i;
        se2_inv(p + 4 * i, pi);
        se2_mul(pi, q + 4 * i, o);
        se2_inv(o, zi);
        K[0] = -zi[2]; K[1] = zi[3]; K[2] = -zi[1];
        K[3] = -zi[3]; K[4] = -zi[2]; K[5] = zi[0];
        K[6] = 0.0; K[7] = 0.0; K[8] = -1.0;
    }
}

// Jr^-1 = [[M^-1, -M^-1 u], [0, 1]] with Jr = [[M, u], [0, 1]], M^-1 = [[A, -t/2], [t/2, A]]
static inline void se2_jr_inv(const double *r, double A, double b2, double b3, double sign,
                              double *J) {
    double Jr[9];
    se2_jr(r, 1.0, b2, b3, Jr);  // only u is read
    double t = r[2], u0 = Jr[2], u1 = Jr[5];
    J[0] = sign * A; J[1] = -sign * 0.5 * t; J[2] = -sign * (A * u0 - 0.5 * t * u1);
    J[3] = sign * 0.5 * t; J[4] = sign * A; J[5] = -sign * (0.5 * t * u0 + A * u1);
    J[6] = 0.0; J[7] = 0.0; J[8] = sign;
}

// tau = Log(x^-1 y), d tau / d y = Jr^-1(tau), d tau / d x = -Jr^-1(-tau)
static void se2_minus_jac(const double *y, const double *x, double *tau, double *Jy, double *Jx,
                          long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double xi[4], z[4], *r = tau + 3 * i;
        se2_inv(x + 4 * i, xi);
        se2_mul(xi, y + 4 * i, z);
        double t = atan2(z[3], z[2]), A = half_cot(t, z[2], z[3]);
        r[0] = A * z[0] + 0.5 * t * z[1]; r[1] = -0.5 * t * z[0] + A * z[1]; r[2] = t;
        double t2 = t * t, tt = t2 < 1e-16 ? 1.0 : t2;  // (1 - cos t)/t^2, no cancellation
        double b2 = t2 < 1e-16 ? 0.5 : (z[2] >= 0.0 ? z[3] * z[3] / (1.0 + z[2]) : 1.0 - z[2]) / tt;
        double b3 = t2 < 1e-4 ? 1.0 / 6.0 - t2 / 120.0 : (t - z[3]) / (t2 * t);
        double m[3] = {-r[0], -r[1], -t};
        se2_jr_inv(r, A, b2, b3, 1.0, Jy + 9 * i);
        se2_jr_inv(m, A, b2, b3, -1.0, Jx + 9 * i);
    }
}

// ------------------------------------------------------------ Sim(3) (MATH.md section 5)
// (tx, ty, tz, qx, qy, qz, qw, s), tangent (rho, phi, sigma); W = a I + b F + c F^2 with F =
// hat(phi) (b, c: MATH.md's coefficients of hat(phi / theta), divided by theta, theta^2). Exp and
// Log guard theta = 0 and sigma = 0 against division by zero only (not the full removable
// singularities: a cheaper reference than microlie's, accurate on the benchmark's inputs).
static inline void sim3_w(double sg, double t2, double k, double ch, double *a, double *b,
                          double *c) {
    double es = exp(sg), em = expm1(sg), th = std::sqrt(t2);
    double sn = 2.0 * k * ch * th, cs = 1.0 - 2.0 * k * k * t2, d = sg * sg + t2;
    d = d > 0.0 ? d : 1.0;
    *a = sg != 0.0 ? em / sg : 1.0;
    *b = (sg * es * 2.0 * k * ch + 2.0 * k * k * t2 - em * cs) / d;  // (1 - e^s cos t) = ...
    double tt = t2 > 0.0 ? t2 : 1.0;
    *c = (*a - ((es * cs - 1.0) * sg + es * sn * th) / d) / tt;
}

static inline void sim3_wmul(double a, double b, double c, const double F[3], const double *v,
                             double *o) {
    double x[3], y[3];
    cross(F, v, x);
    cross(F, x, y);
    for (int j = 0; j < 3; j++) o[j] = a * v[j] + b * x[j] + c * y[j];
}

static void sim3_exp(const double *z, double *p, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *rho = z + 7 * i, *phi = rho + 3;
        double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2], k, ch, a, b, c;
        half(t2, &k, &ch);
        sim3_w(rho[6], t2, k, ch, &a, &b, &c);
        double *o = p + 8 * i;
        sim3_wmul(a, b, c, phi, rho, o);
        o[3] = k * phi[0]; o[4] = k * phi[1]; o[5] = k * phi[2]; o[6] = ch; o[7] = exp(rho[6]);
    }
}

static void sim3_log(const double *p, double *z, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *x = p + 8 * i, *q = x + 3;
        double *rho = z + 7 * i, *phi = rho + 3;
        qlog(q, phi);
        double sg = log(x[7]);
        double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2];
        double sv = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]), th = std::sqrt(t2);
        double k = t2 < 1e-16 ? 0.5 : sv / th, ch = std::fabs(q[3]), a, b, c;
        sim3_w(sg, t2, k, ch, &a, &b, &c);
        // W^-1 = al I + be F + ga F^2 (F^3 = -t2 F)
        double al = 1.0 / a, d = a - t2 * c, det = d * d + t2 * b * b;
        double be = -al * b * a / det, ga = al * (b * b - c * d) / det;
        sim3_wmul(al, be, ga, phi, x, rho);
        rho[6] = sg;
    }
}

static inline void sim3_mul(const double *a, const double *b, double *o) {
    double t[3];
    qrot(a + 3, b, t);
    double x = a[0] + a[7] * t[0], y = a[1] + a[7] * t[1], w = a[2] + a[7] * t[2];
    qmul(a + 3, b + 3, o + 3);
    o[0] = x; o[1] = y; o[2] = w; o[7] = a[7] * b[7];
}

static inline void sim3_inv(const double *a, double *o) {
    double si = 1.0 / a[7], t[3];
    qconj(a + 3, o + 3);
    qrot(o + 3, a, t);
    o[0] = -si * t[0]; o[1] = -si * t[1]; o[2] = -si * t[2]; o[7] = si;
}

static void sim3_compose(const double *p, const double *q, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double r[8];
        sim3_mul(p + 8 * i, q + 8 * i, r);
        for (int j = 0; j < 8; j++) o[8 * i + j] = r[j];
    }
}

static void sim3_act(const double *p, const double *v, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *a = p + 8 * i;
        double t[3];
        qrot(a + 3, v + 3 * i, t);
        for (int j = 0; j < 3; j++) o[3 * i + j] = a[j] + a[7] * t[j];
    }
}

// s R v + t; d/dS (right) = [s R, -s R hat(v), s R v], d/dv = s R
static void sim3_act_jac(const double *p, const double *v, double *o, double *JS, double *Jv,
                         long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *a = p + 8 * i, *x = v + 3 * i;
        double R[9], s = a[7];
        qmat(a + 3, R);
        for (int e = 0; e < 9; e++) R[e] *= s;
        for (int r = 0; r < 3; r++) {
            double Rv = R[3 * r] * x[0] + R[3 * r + 1] * x[1] + R[3 * r + 2] * x[2];
            o[3 * i + r] = a[r] + Rv;
            double *J = JS + 21 * i + 7 * r;
            J[0] = R[3 * r]; J[1] = R[3 * r + 1]; J[2] = R[3 * r + 2];
            J[3] = -(R[3 * r + 1] * x[2] - R[3 * r + 2] * x[1]);
            J[4] = -(R[3 * r + 2] * x[0] - R[3 * r] * x[2]);
            J[5] = -(R[3 * r] * x[1] - R[3 * r + 1] * x[0]);
            J[6] = Rv;
            for (int c = 0; c < 3; c++) Jv[9 * i + 3 * r + c] = R[3 * r + c];
        }
    }
}

// z = p^-1 q, d z / d p = -Ad(z^-1), Ad(S) = [[s R, hat(t) R, -t], [0, R, 0], [0, 0, 1]]
static void sim3_between_jac(const double *p, const double *q, double *z, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double pi[8], zi[8], R[9], r8[8];
        sim3_inv(p + 8 * i, pi);
        sim3_mul(pi, q + 8 * i, r8);
        for (int j = 0; j < 8; j++) z[8 * i + j] = r8[j];
        sim3_inv(r8, zi);
        qmat(zi + 3, R);
        double *K = J + 49 * i, s = zi[7];
        for (int r = 0; r < 3; r++) {
            int r1 = (r + 1) % 3, r2 = (r + 2) % 3;
            for (int c = 0; c < 3; c++) {
                double tr = zi[r1] * R[3 * r2 + c] - zi[r2] * R[3 * r1 + c];
                K[7 * r + c] = -s * R[3 * r + c];
                K[7 * r + 3 + c] = -tr;
                K[7 * (r + 3) + c] = 0.0;
                K[7 * (r + 3) + 3 + c] = -R[3 * r + c];
            }
            K[7 * r + 6] = zi[r];
            K[7 * (r + 3) + 6] = 0.0;
            K[42 + r] = 0.0; K[45 + r] = 0.0;
        }
        K[48] = -1.0;
    }
}

// ------------------------------------------------------------ SE_2(3): (p, q, v), (rho, phi, nu)
// Exp: [[Exp(phi), V rho, V nu]], V = Jl_SO3(phi) (the SE(3) formulas of MATH.md section 4 on
// both vectors); Jr = [[Jr, Q(-rho,-phi), 0], [0, Jr, 0], [0, Q(-nu,-phi), Jr]].
static void se23_exp(const double *tau, double *p, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *rho = tau + 9 * i, *phi = rho + 3, *nu = rho + 6;
        double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2], k, ch;
        half(t2, &k, &ch);
        double a = 2.0 * k * k, b = coef_b(t2, k, ch), c[3], d[3], e[3], f[3];
        cross(phi, rho, c); cross(phi, c, d);
        cross(phi, nu, e); cross(phi, e, f);
        double *o = p + 10 * i;
        for (int j = 0; j < 3; j++) {
            o[j] = rho[j] + a * c[j] + b * d[j];
            o[7 + j] = nu[j] + a * e[j] + b * f[j];
        }
        o[3] = k * phi[0]; o[4] = k * phi[1]; o[5] = k * phi[2]; o[6] = ch;
    }
}

static void se23_log(const double *p, double *tau, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *t = p + 10 * i, *q = t + 3, *v = t + 7;
        double *rho = tau + 9 * i, *phi = rho + 3, *nu = rho + 6;
        qlog(q, phi);
        double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2];
        double s = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]), th = std::sqrt(t2);
        double k = t2 < 1e-16 ? 0.5 : s / th, ch = std::fabs(q[3]);
        double c = coef_c(t2, k, ch), a[3], b[3], e[3], f[3];
        cross(phi, t, a); cross(phi, a, b);
        cross(phi, v, e); cross(phi, e, f);
        for (int j = 0; j < 3; j++) {
            rho[j] = t[j] - 0.5 * a[j] + c * b[j];
            nu[j] = v[j] - 0.5 * e[j] + c * f[j];
        }
    }
}

static inline void se23_mul(const double *a, const double *b, double *o) {
    double t[3], u[3];
    qrot(a + 3, b, t);
    qrot(a + 3, b + 7, u);
    qmul(a + 3, b + 3, o + 3);
    for (int j = 0; j < 3; j++) { o[j] = a[j] + t[j]; o[7 + j] = a[7 + j] + u[j]; }
}

static inline void se23_inv(const double *a, double *o) {
    double t[3], u[3];
    qconj(a + 3, o + 3);
    qrot(o + 3, a, t);
    qrot(o + 3, a + 7, u);
    for (int j = 0; j < 3; j++) { o[j] = -t[j]; o[7 + j] = -u[j]; }
}

static void se23_compose(const double *p, const double *q, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double r[10];
        se23_mul(p + 10 * i, q + 10 * i, r);
        for (int j = 0; j < 10; j++) o[10 * i + j] = r[j];
    }
}

static void se23_act(const double *p, const double *v, double *o, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *a = p + 10 * i;
        double t[3];
        qrot(a + 3, v + 3 * i, t);
        for (int j = 0; j < 3; j++) o[3 * i + j] = a[j] + t[j];
    }
}

// R x + p; d/dX (right) = [R, -R hat(x), 0], d/dx = R
static void se23_act_jac(const double *p, const double *v, double *o, double *JT, double *Jv,
                         long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *a = p + 10 * i, *x = v + 3 * i;
        double R[9];
        qmat(a + 3, R);
        for (int r = 0; r < 3; r++) {
            o[3 * i + r] = a[r] + R[3 * r] * x[0] + R[3 * r + 1] * x[1] + R[3 * r + 2] * x[2];
            double *J = JT + 27 * i + 9 * r;
            J[0] = R[3 * r]; J[1] = R[3 * r + 1]; J[2] = R[3 * r + 2];
            J[3] = -(R[3 * r + 1] * x[2] - R[3 * r + 2] * x[1]);
            J[4] = -(R[3 * r + 2] * x[0] - R[3 * r] * x[2]);
            J[5] = -(R[3 * r] * x[1] - R[3 * r + 1] * x[0]);
            J[6] = 0.0; J[7] = 0.0; J[8] = 0.0;
            for (int c = 0; c < 3; c++) Jv[9 * i + 3 * r + c] = R[3 * r + c];
        }
    }
}

// z = p^-1 q, d z / d p = -Ad(z^-1), Ad = [[R, hat(p) R, 0], [0, R, 0], [0, hat(v) R, R]]
static void se23_between_jac(const double *p, const double *q, double *z, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double pi[10], zi[10], R[9], r10[10];
        se23_inv(p + 10 * i, pi);
        se23_mul(pi, q + 10 * i, r10);
        for (int j = 0; j < 10; j++) z[10 * i + j] = r10[j];
        se23_inv(r10, zi);
        qmat(zi + 3, R);
        double *K = J + 81 * i;
        for (int r = 0; r < 3; r++) {
            int r1 = (r + 1) % 3, r2 = (r + 2) % 3;
            for (int c = 0; c < 3; c++) {
                double tp = zi[r1] * R[3 * r2 + c] - zi[r2] * R[3 * r1 + c];
                double tv = zi[7 + r1] * R[3 * r2 + c] - zi[7 + r2] * R[3 * r1 + c];
                K[9 * r + c] = -R[3 * r + c]; K[9 * r + 3 + c] = -tp; K[9 * r + 6 + c] = 0.0;
                K[9 * (r + 3) + c] = 0.0; K[9 * (r + 3) + 3 + c] = -R[3 * r + c];
                K[9 * (r + 3) + 6 + c] = 0.0;
                K[9 * (r + 6) + c] = 0.0; K[9 * (r + 6) + 3 + c] = -tv;
                K[9 * (r + 6) + 6 + c] = -R[3 * r + c];
            }
        }
    }
}

static void se23_exp_jac(const double *tau, double *p, double *J, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        const double *rho = tau + 9 * i, *phi = rho + 3, *nu = rho + 6;
        double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2], k, ch;
        half(t2, &k, &ch);
        double a = 2.0 * k * k, b = coef_b(t2, k, ch), c[3], d[3], e[3], f[3];
        cross(phi, rho, c); cross(phi, c, d);
        cross(phi, nu, e); cross(phi, e, f);
        double *o = p + 10 * i;
        for (int j = 0; j < 3; j++) {
            o[j] = rho[j] + a * c[j] + b * d[j];
            o[7 + j] = nu[j] + a * e[j] + b * f[j];
        }
        o[3] = k * phi[0]; o[4] = k * phi[1]; o[5] = k * phi[2]; o[6] = ch;
        double *K = J + 81 * i, Jr[9], Qr[9], Qn[9];
        so3_ihat(-a, b, phi, Jr, 3);
        double mr[3] = {-rho[0], -rho[1], -rho[2]}, mn[3] = {-nu[0], -nu[1], -nu[2]},
               mp[3] = {-phi[0], -phi[1], -phi[2]};
        q_block(mr, mp, t2, k, ch, Qr);
        q_block(mn, mp, t2, k, ch, Qn);
        for (int r = 0; r < 3; r++)
            for (int s = 0; s < 3; s++) {
                double g = Jr[3 * r + s];
                K[9 * r + s] = g; K[9 * r + 3 + s] = Qr[3 * r + s]; K[9 * r + 6 + s] = 0.0;
                K[9 * (r + 3) + s] = 0.0; K[9 * (r + 3) + 3 + s] = g; K[9 * (r + 3) + 6 + s] = 0.0;
                K[9 * (r + 6) + s] = 0.0; K[9 * (r + 6) + 3 + s] = Qn[3 * r + s];
                K[9 * (r + 6) + 6 + s] = g;
            }
    }
}

// [[Ji, -Ji Qr Ji, 0], [0, Ji, 0], [0, -Ji Qn Ji, Ji]] times s into a 9x9
static inline void jinv9(const double Ji[9], const double Qr[9], const double Qn[9], double s,
                         double *J) {
    double T[9], U[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            T[3 * r + c] = Qr[3 * r] * Ji[c] + Qr[3 * r + 1] * Ji[3 + c] + Qr[3 * r + 2] * Ji[6 + c];
            U[3 * r + c] = Qn[3 * r] * Ji[c] + Qn[3 * r + 1] * Ji[3 + c] + Qn[3 * r + 2] * Ji[6 + c];
        }
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            double m = Ji[3 * r] * T[c] + Ji[3 * r + 1] * T[3 + c] + Ji[3 * r + 2] * T[6 + c];
            double w = Ji[3 * r] * U[c] + Ji[3 * r + 1] * U[3 + c] + Ji[3 * r + 2] * U[6 + c];
            double g = s * Ji[3 * r + c];
            J[9 * r + c] = g; J[9 * r + 3 + c] = -s * m; J[9 * r + 6 + c] = 0.0;
            J[9 * (r + 3) + c] = 0.0; J[9 * (r + 3) + 3 + c] = g; J[9 * (r + 3) + 6 + c] = 0.0;
            J[9 * (r + 6) + c] = 0.0; J[9 * (r + 6) + 3 + c] = -s * w; J[9 * (r + 6) + 6 + c] = g;
        }
}

// tau = Log(x^-1 y), d tau / d y = Jr^-1(tau), d tau / d x = -Jr^-1(-tau)
static void se23_minus_jac(const double *y, const double *x, double *tau, double *Jy,
                           double *Jx, long n) {
#pragma omp simd
    for (long i = 0; i < n; i++) {
        double xi[10], z[10];
        se23_inv(x + 10 * i, xi);
        se23_mul(xi, y + 10 * i, z);
        double *rho = tau + 9 * i, *phi = rho + 3, *nu = rho + 6;
        qlog(z + 3, phi);
        double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2];
        double s = std::sqrt(z[3] * z[3] + z[4] * z[4] + z[5] * z[5]);
        double k = t2 < 1e-16 ? 0.5 : s / std::sqrt(t2), ch = std::fabs(z[6]);
        double c = coef_c(t2, k, ch), a[3], b[3], e[3], f[3];
        cross(phi, z, a); cross(phi, a, b);
        cross(phi, z + 7, e); cross(phi, e, f);
        for (int j = 0; j < 3; j++) {
            rho[j] = z[j] - 0.5 * a[j] + c * b[j];
            nu[j] = z[7 + j] - 0.5 * e[j] + c * f[j];
        }
        double Ji[9], Jt[9], Qr[9], Qn[9], Pr[9], Pn[9];
        double mr[3] = {-rho[0], -rho[1], -rho[2]}, mn[3] = {-nu[0], -nu[1], -nu[2]},
               mp[3] = {-phi[0], -phi[1], -phi[2]};
        ihat(0.5, c, phi, Ji, 3);
        for (int r = 0; r < 3; r++)
            for (int q = 0; q < 3; q++) Jt[3 * r + q] = Ji[3 * q + r];
        q_block(mr, mp, t2, k, ch, Qr);
        q_block(mn, mp, t2, k, ch, Qn);
        q_block(rho, phi, t2, k, ch, Pr);
        q_block(nu, phi, t2, k, ch, Pn);
        jinv9(Ji, Qr, Qn, 1.0, Jy + 81 * i);
        jinv9(Jt, Pr, Pn, -1.0, Jx + 81 * i);
    }
}

// Entry points for benchmarks/native.py (ctypes): rows of doubles, n elements.
extern "C" {
#define ENTRY1(G, OP) \
    void n_##G##_##OP(const double *a, double *o, long n) { G##_##OP(a, o, n); }
#define ENTRY2(G, OP) \
    void n_##G##_##OP(const double *a, const double *b, double *o, long n) { G##_##OP(a, b, o, n); }
#define ENTRY1J(G, OP) \
    void n_##G##_##OP(const double *a, double *o, double *j, long n) { G##_##OP(a, o, j, n); }
#define ENTRY2J(G, OP) \
    void n_##G##_##OP(const double *a, const double *b, double *o, double *j, long n) { \
        G##_##OP(a, b, o, j, n); \
    }
#define ENTRY2JJ(G, OP) \
    void n_##G##_##OP(const double *a, const double *b, double *o, double *j1, double *j2, \
                      long n) { G##_##OP(a, b, o, j1, j2, n); }
#define GROUP_ENTRIES(G) \
    ENTRY1(G, exp) ENTRY1(G, log) ENTRY2(G, compose) ENTRY2(G, act) ENTRY2JJ(G, act_jac) \
    ENTRY2J(G, between_jac)
GROUP_ENTRIES(so2) GROUP_ENTRIES(se2) GROUP_ENTRIES(sim3) GROUP_ENTRIES(se23)
// Sim3 exp_jac and minus_jac: only the blocked loops (lie_blocked.c)
ENTRY1J(so2, exp_jac) ENTRY1J(se2, exp_jac) ENTRY1J(se23, exp_jac)
ENTRY2JJ(so2, minus_jac) ENTRY2JJ(se2, minus_jac) ENTRY2JJ(se23, minus_jac)
void n_so3_exp(const double *a, double *o, long n) { so3_exp(a, o, n); }
void n_so3_log(const double *a, double *o, long n) { so3_log(a, o, n); }
void n_se3_exp(const double *a, double *o, long n) { se3_exp(a, o, n); }
void n_se3_log(const double *a, double *o, long n) { se3_log(a, o, n); }
void n_se3_compose(const double *a, const double *b, double *o, long n) { se3_compose(a, b, o, n); }
void n_so3_compose(const double *a, const double *b, double *o, long n) { so3_compose(a, b, o, n); }
void n_so3_act(const double *a, const double *b, double *o, long n) { so3_act(a, b, o, n); }
void n_se3_act(const double *a, const double *b, double *o, long n) { se3_act(a, b, o, n); }
void n_se3_act_jac(const double *a, const double *b, double *o, double *j1, double *j2, long n) {
    se3_act_jac(a, b, o, j1, j2, n);
}
void n_se3_exp_jac(const double *a, double *o, double *j, long n) { se3_exp_jac(a, o, j, n); }
void n_so3_exp_jac(const double *a, double *o, double *j, long n) { so3_exp_jac(a, o, j, n); }
void n_so3_act_jac(const double *a, const double *b, double *o, double *j1, double *j2, long n) {
    so3_act_jac(a, b, o, j1, j2, n);
}
void n_so3_between_jac(const double *a, const double *b, double *o, double *j, long n) {
    so3_between_jac(a, b, o, j, n);
}
void n_so3_minus_jac(const double *a, const double *b, double *o, double *j1, double *j2,
                     long n) {
    so3_minus_jac(a, b, o, j1, j2, n);
}
void n_se3_between_jac(const double *a, const double *b, double *o, double *j, long n) {
    se3_between_jac(a, b, o, j, n);
}
void n_se3_minus_jac(const double *a, const double *b, double *o, double *j1, double *j2,
                     long n) {
    se3_minus_jac(a, b, o, j1, j2, n);
}
}
