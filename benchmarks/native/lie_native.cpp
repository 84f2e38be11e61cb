// A plain, vectorised C++ baseline for benchmarks/native.py: the SO(3)/SE(3) operations that
// benchmarks/groups.py times, written as flat loops over arrays of parameters (the same row layout
// as microlie: SO3 (qx,qy,qz,qw), SE3 (tx,ty,tz,qx,qy,qz,qw), tangents (rho, phi)).
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

// Entry points for benchmarks/native.py (ctypes): rows of doubles, n elements.
extern "C" {
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
