/* Element formulas of SO(3) and SE(3), written on doubles in the same form as microlie's generic
 * component kernels (microlie/groups/so3.py, se3.py): the same half-angle functions, thresholds
 * and Taylor polynomials, so that a compiled kernel agrees with the generic one to rounding.
 * Layouts: SO3 (qx, qy, qz, qw); SE3 (tx, ty, tz, qx, qy, qz, qw); tangents (rho, phi);
 * matrices row-major. Every function is inline and branch-free enough for `omp simd` loops. */
#pragma once
#include <math.h>
#include "coeffs.h"

/* glibc's libmvec supplies vector versions of these; declaring them lets GCC vectorise loops
 * that call them without -ffast-math (IEEE semantics are kept). */
#pragma omp declare simd notinbranch
extern double tan(double);
#pragma omp declare simd notinbranch
extern double sin(double);
#pragma omp declare simd notinbranch
extern double cos(double);
#pragma omp declare simd notinbranch
extern double atan2(double, double);

#define LM_INLINE static inline __attribute__((always_inline))

LM_INLINE double horner(double x, const double *c, int n) {
    double acc = c[n - 1];
#pragma GCC unroll 16
    for (int i = n - 2; i >= 0; i--) acc = acc * x + c[i];
    return acc;
}

LM_INLINE void cross3(const double *a, const double *b, double *c) {
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

/* (sin(t/2)/t, cos(t/2)) from t^2, through u = tan(t/4) */
LM_INLINE void half_angle(double t2, double *k, double *ch) {
    double small = t2 < TINY2 ? 1.0 : 0.0;
    double t = sqrt(t2 + small);
    double u = tan(0.25 * t), u2 = u * u, r = 1.0 / (1.0 + u2);
    double kk = (2.0 * r) * u / t, cc = (1.0 - u2) * r;
    *k = small != 0.0 ? 0.5 - t2 * (1.0 / 48.0) : kk;
    *ch = small != 0.0 ? 1.0 - 0.125 * t2 : cc;
}

/* (t - sin t)/t^3 */
LM_INLINE double coef_b(double t2, double k, double ch) {
    double small = t2 < SMALL2 ? 1.0 : 0.0;
    double closed = (1.0 - 2.0 * k * ch) / (t2 + small);
    return small != 0.0 ? horner(t2, C_T_SIN, 11) : closed;
}

/* (1 - (t/2) cot(t/2))/t^2 */
LM_INLINE double coef_c(double t2, double k, double ch) {
    double small = t2 < SMALL2 ? 1.0 : 0.0;
    double closed = (1.0 - ch / (2.0 * (k + small))) / (t2 + small);
    return small != 0.0 ? horner(t2, C_COT, 12) : closed;
}

LM_INLINE void quat_mul(const double *a, const double *b, double *o) {
    double ax = a[0], ay = a[1], az = a[2], aw = a[3], bx = b[0], by = b[1], bz = b[2], bw = b[3];
    o[0] = aw * bx + ax * bw + ay * bz - az * by;
    o[1] = aw * by - ax * bz + ay * bw + az * bx;
    o[2] = aw * bz + ax * by - ay * bx + az * bw;
    o[3] = aw * bw - ax * bx - ay * by - az * bz;
}

/* R(q) v = v + w c + u x c with c = 2 u x v */
LM_INLINE void quat_rotate(const double *q, const double *v, double *o) {
    double x = q[0], y = q[1], z = q[2], w = q[3];
    double x2 = x + x, y2 = y + y, z2 = z + z;
    double c0 = y2 * v[2] - z2 * v[1], c1 = z2 * v[0] - x2 * v[2], c2 = x2 * v[1] - y2 * v[0];
    o[0] = v[0] + w * c0 + (y * c2 - z * c1);
    o[1] = v[1] + w * c1 + (z * c0 - x * c2);
    o[2] = v[2] + w * c2 + (x * c1 - y * c0);
}

LM_INLINE void quat_matrix(const double *q, double *R) {
    double x = q[0], y = q[1], z = q[2], w = q[3];
    double xx = x * x, yy = y * y, zz = z * z, xy = x * y, xz = x * z, yz = y * z;
    double wx = w * x, wy = w * y, wz = w * z;
    R[0] = 1.0 - 2.0 * (yy + zz); R[1] = 2.0 * (xy - wz); R[2] = 2.0 * (xz + wy);
    R[3] = 2.0 * (xy + wz); R[4] = 1.0 - 2.0 * (xx + zz); R[5] = 2.0 * (yz - wx);
    R[6] = 2.0 * (xz - wy); R[7] = 2.0 * (yz + wx); R[8] = 1.0 - 2.0 * (xx + yy);
}

/* rotation vector of a unit quaternion, kl = theta/|v|, aw = |w| */
LM_INLINE void quat_log(const double *q, double *phi, double *kl_out, double *aw_out) {
    double x = q[0], y = q[1], z = q[2], w = q[3];
    double aw = fabs(w), n2 = x * x + y * y + z * z;
    double small = n2 < TINY2 ? 1.0 : 0.0;
    double n = sqrt(n2 + small);
    double kc = 2.0 * atan2(n, aw) / n;
    double kl = small != 0.0 ? 2.0 + n2 * (1.0 / 3.0) : kc;
    double ks = w < 0.0 ? -kl : kl;
    phi[0] = ks * x; phi[1] = ks * y; phi[2] = ks * z;
    *kl_out = kl; *aw_out = aw;
}

/* I + a hat(w) + b hat(w)^2 into a block with leading dimension ld */
LM_INLINE void i_hat_sq(double a, double b, const double *w, double t2, double *J, int ld) {
    double x = w[0], y = w[1], z = w[2];
    double bx = b * x, by = b * y, bz = b * z, d = 1.0 - b * t2;
    double ax = a * x, ay = a * y, az = a * z, xy = bx * y, xz = bx * z, yz = by * z;
    J[0] = d + bx * x; J[1] = xy - az; J[2] = xz + ay;
    J[ld] = xy + az; J[ld + 1] = d + by * y; J[ld + 2] = yz - ax;
    J[2 * ld] = xz - ay; J[2 * ld + 1] = yz + ax; J[2 * ld + 2] = d + bz * z;
}

LM_INLINE void so3_jr(const double *w, double *J, int ld) {
    double t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2], k, ch;
    half_angle(t2, &k, &ch);
    i_hat_sq(-2.0 * k * k, coef_b(t2, k, ch), w, t2, J, ld);
}

LM_INLINE void so3_jr_inv(const double *w, double *J, int ld) {
    double t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2], k, ch;
    half_angle(t2, &k, &ch);
    i_hat_sq(0.5, coef_c(t2, k, ch), w, t2, J, ld);
}

/* The block Q(rho, phi) of SE(3)'s left Jacobian, in microlie's reduced form */
LM_INLINE void q_block(const double *rho, const double *phi, double *Q, int ld) {
    double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2], k, ch;
    half_angle(t2, &k, &ch);
    double c1 = coef_b(t2, k, ch);
    double small = t2 < SMALL2 ? 1.0 : 0.0;
    double t2s = t2 + small, t = sqrt(t2s), st = sin(t), ct = cos(t), t4 = t2s * t2s;
    double c2c = (t2s + 2.0 * ct - 2.0) / (2.0 * t4);
    double c3c = (2.0 * t - 3.0 * st + t * ct) / (2.0 * t4 * t);
    double c2 = small != 0.0 ? horner(t2, C_COS4, 11) : c2c;
    double c3 = small != 0.0 ? horner(t2, C_SIN5, 11) : c3c;
    double d = rho[0] * phi[0] + rho[1] * phi[1] + rho[2] * phi[2];
    double F[9] = {0.0, -phi[2], phi[1], phi[2], 0.0, -phi[0], -phi[1], phi[0], 0.0};
    double P[9] = {0.0, -rho[2], rho[1], rho[2], 0.0, -rho[0], -rho[1], rho[0], 0.0};
    double a[3], g[3];
    cross3(phi, rho, a);
    cross3(phi, a, g);
    double G[9] = {0.0, -g[2], g[1], g[2], 0.0, -g[0], -g[1], g[0], 0.0};
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double f2 = phi[i] * phi[j] - (i == j ? t2 : 0.0);
            double sym = rho[i] * phi[j] + phi[i] * rho[j] - (i == j ? 2.0 * d : 0.0);
            Q[i * ld + j] = 0.5 * P[3 * i + j] + c1 * (sym - d * F[3 * i + j])
                            + c2 * (G[3 * i + j] + d * F[3 * i + j]) - 2.0 * c3 * d * f2;
        }
}

LM_INLINE void se3_jr(const double *tau, double *J) {
    double mr[3] = {-tau[0], -tau[1], -tau[2]}, mp[3] = {-tau[3], -tau[4], -tau[5]};
    so3_jr(tau + 3, J, 6);
    so3_jr(tau + 3, J + 21, 6);
    q_block(mr, mp, J + 3, 6);
    for (int i = 3; i < 6; i++) J[6 * i] = J[6 * i + 1] = J[6 * i + 2] = 0.0;
}

LM_INLINE void se3_jr_inv(const double *tau, double *J) {
    double mr[3] = {-tau[0], -tau[1], -tau[2]}, mp[3] = {-tau[3], -tau[4], -tau[5]};
    double Ji[9], Q[9], T[9];
    so3_jr_inv(tau + 3, Ji, 3);
    q_block(mr, mp, Q, 3);
    for (int i = 0; i < 3; i++)  /* T = Q Ji */
        for (int j = 0; j < 3; j++)
            T[3 * i + j] = Q[3 * i] * Ji[j] + Q[3 * i + 1] * Ji[3 + j] + Q[3 * i + 2] * Ji[6 + j];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double m = Ji[3 * i] * T[j] + Ji[3 * i + 1] * T[3 + j] + Ji[3 * i + 2] * T[6 + j];
            J[6 * i + j] = Ji[3 * i + j];
            J[6 * i + 3 + j] = -m;
            J[6 * (i + 3) + j] = 0.0;
            J[6 * (i + 3) + 3 + j] = Ji[3 * i + j];
        }
}

/* ---------------------------------------------------------------- element operations */

LM_INLINE void so3_exp(const double *w, double *q) {
    double k, ch;
    half_angle(w[0] * w[0] + w[1] * w[1] + w[2] * w[2], &k, &ch);
    q[0] = k * w[0]; q[1] = k * w[1]; q[2] = k * w[2]; q[3] = ch;
}

LM_INLINE void so3_log(const double *q, double *phi) {
    double kl, aw;
    quat_log(q, phi, &kl, &aw);
}

LM_INLINE void so3_inverse(const double *q, double *o) {
    o[0] = -q[0]; o[1] = -q[1]; o[2] = -q[2]; o[3] = q[3];
}

LM_INLINE void se3_exp(const double *tau, double *p) {
    const double *rho = tau, *phi = tau + 3;
    double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2], k, ch;
    half_angle(t2, &k, &ch);
    double a = 2.0 * k * k, b = coef_b(t2, k, ch), c[3], d[3];
    cross3(phi, rho, c);
    cross3(phi, c, d);
    for (int i = 0; i < 3; i++) p[i] = rho[i] + a * c[i] + b * d[i];
    p[3] = k * phi[0]; p[4] = k * phi[1]; p[5] = k * phi[2]; p[6] = ch;
}

LM_INLINE void se3_log(const double *p, double *tau) {
    const double *t = p, *q = p + 3;
    double *phi = tau + 3, kl, aw, a[3], b[3];
    quat_log(q, phi, &kl, &aw);
    double t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2];
    double c = coef_c(t2, 1.0 / kl, aw);
    cross3(phi, t, a);
    cross3(phi, a, b);
    for (int i = 0; i < 3; i++) tau[i] = t[i] - 0.5 * a[i] + c * b[i];
}

LM_INLINE void se3_compose(const double *p, const double *q, double *o) {
    double r[3];
    quat_rotate(p + 3, q, r);
    o[0] = p[0] + r[0]; o[1] = p[1] + r[1]; o[2] = p[2] + r[2];
    quat_mul(p + 3, q + 3, o + 3);
}

LM_INLINE void se3_inverse(const double *p, double *o) {
    double qi[4] = {-p[3], -p[4], -p[5], p[6]}, t[3];
    quat_rotate(qi, p, t);
    o[0] = -t[0]; o[1] = -t[1]; o[2] = -t[2];
    o[3] = qi[0]; o[4] = qi[1]; o[5] = qi[2]; o[6] = qi[3];
}

LM_INLINE void se3_act(const double *p, const double *v, double *o) {
    double r[3];
    quat_rotate(p + 3, v, r);
    o[0] = r[0] + p[0]; o[1] = r[1] + p[1]; o[2] = r[2] + p[2];
}

/* SE3 act with d/dT (right) = [R, -R hat(v)] (3x6) and d/dv = R (3x3) */
LM_INLINE void se3_act_jac(const double *p, const double *v, double *o, double *JT, double *Jv) {
    double R[9];
    quat_matrix(p + 3, R);
    se3_act(p, v, o);
    for (int r = 0; r < 3; r++) {
        const double *Rr = R + 3 * r;
        JT[6 * r] = Rr[0]; JT[6 * r + 1] = Rr[1]; JT[6 * r + 2] = Rr[2];
        /* (R hat(v))_rj = (R_r x v)... row r of R hat(v) is v x R_r... written out: */
        JT[6 * r + 3] = -(Rr[1] * v[2] - Rr[2] * v[1]);
        JT[6 * r + 4] = -(Rr[2] * v[0] - Rr[0] * v[2]);
        JT[6 * r + 5] = -(Rr[0] * v[1] - Rr[1] * v[0]);
        Jv[3 * r] = Rr[0]; Jv[3 * r + 1] = Rr[1]; Jv[3 * r + 2] = Rr[2];
    }
}

/* SO3 act with d/dR (right) = -R hat(v) and d/dv = R */
LM_INLINE void so3_act_jac(const double *q, const double *v, double *o, double *JR, double *Jv) {
    double R[9];
    quat_matrix(q, R);
    quat_rotate(q, v, o);
    for (int r = 0; r < 3; r++) {
        const double *Rr = R + 3 * r;
        JR[3 * r] = -(Rr[1] * v[2] - Rr[2] * v[1]);
        JR[3 * r + 1] = -(Rr[2] * v[0] - Rr[0] * v[2]);
        JR[3 * r + 2] = -(Rr[0] * v[1] - Rr[1] * v[0]);
        Jv[3 * r] = Rr[0]; Jv[3 * r + 1] = Rr[1]; Jv[3 * r + 2] = Rr[2];
    }
}
