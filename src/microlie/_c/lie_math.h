/* Element formulas of SO(3) and SE(3), written on doubles in the same form as microlie's generic
 * component kernels (microlie/groups/so3.py, se3.py, base.py): the same half-angle functions,
 * thresholds and Taylor polynomials (coeffs.h is generated from microlie.groups._math), so that a
 * compiled kernel agrees with the generic one to rounding.
 * Layouts: SO3 (qx, qy, qz, qw); SE3 (tx, ty, tz, qx, qy, qz, qw); tangents (rho, phi);
 * matrices row-major. Helpers work on small local arrays (stride 1); the element operations at
 * the end read and write their components with the block stride S (structure-of-arrays blocks,
 * see _lie.c), the form GCC vectorises. */
#pragma once
#include <math.h>
#include "coeffs.h"

/* Elementary functions: scalar libm calls until the vectorisable ones (vecmath.h) land; no
 * libmvec (it ties a build to glibc >= 2.22 on x86-64 and to one vector ISA). The hot loops that
 * call these formulas are marked LM_HOT (dispatch.h: wider clones chosen at load time). */
#include "dispatch.h"

#define LM_INLINE static inline __attribute__((always_inline))
#ifndef S
#define S 32 /* the block length: component i of an element is at x[i * S] */
#endif

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

/* (sin(t/2)/t, cos(t/2)) from t^2, through u = tan(t/4) (so3.half_angle) */
LM_INLINE void half_angle(double t2, double *k, double *ch) {
    double small = t2 < TINY2 ? 1.0 : 0.0;
    double t = sqrt(t2 + small);
    double u = tan(0.25 * t), u2 = u * u, r = 1.0 / (1.0 + u2);
    double kk = (2.0 * r) * u / t, cc = (1.0 - u2) * r;
    *k = small != 0.0 ? 0.5 - t2 * (1.0 / 48.0) : kk;
    *ch = small != 0.0 ? 1.0 - 0.125 * t2 : cc;
}

/* (t - sin t)/t^3 (so3.coef_b) */
LM_INLINE double coef_b(double t2, double k, double ch) {
    double small = t2 < SMALL2 ? 1.0 : 0.0;
    double closed = (1.0 - 2.0 * k * ch) / (t2 + small);
    return small != 0.0 ? horner(t2, C_T_SIN, N_T_SIN) : closed;
}

/* (1 - (t/2) cot(t/2))/t^2 (so3.coef_c) */
LM_INLINE double coef_c(double t2, double k, double ch) {
    double small = t2 < SMALL2 ? 1.0 : 0.0;
    double closed = (1.0 - ch / (2.0 * (k + small))) / (t2 + small);
    return small != 0.0 ? horner(t2, C_COT, N_COT) : closed;
}

LM_INLINE void quat_mul(const double *a, const double *b, double *o) {
    double ax = a[0], ay = a[1], az = a[2], aw = a[3], bx = b[0], by = b[1], bz = b[2], bw = b[3];
    o[0] = aw * bx + ax * bw + ay * bz - az * by;
    o[1] = aw * by - ax * bz + ay * bw + az * bx;
    o[2] = aw * bz + ax * by - ay * bx + az * bw;
    o[3] = aw * bw - ax * bx - ay * by - az * bz;
}

LM_INLINE void quat_conj(const double *q, double *o) {
    o[0] = -q[0]; o[1] = -q[1]; o[2] = -q[2]; o[3] = q[3];
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

/* rotation vector of a unit quaternion (so3.quat_log_parts), kl = theta/|v|, aw = |w| */
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

/* 3x3 products, row-major */
LM_INLINE void mm3(const double *a, const double *b, double *o) {
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 3; j++)
            o[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
}

LM_INLINE void hat3(const double *v, double *F) {
    F[0] = 0.0; F[1] = -v[2]; F[2] = v[1];
    F[3] = v[2]; F[4] = 0.0; F[5] = -v[0];
    F[6] = -v[1]; F[7] = v[0]; F[8] = 0.0;
}

/* I + a hat(w) + b hat(w)^2 (so3.i_hat_sq) */
LM_INLINE void i_hat_sq(double a, double b, const double *w, double t2, double *J) {
    double x = w[0], y = w[1], z = w[2];
    double bx = b * x, by = b * y, bz = b * z, d = 1.0 - b * t2;
    double ax = a * x, ay = a * y, az = a * z, xy = bx * y, xz = bx * z, yz = by * z;
    J[0] = d + bx * x; J[1] = xy - az; J[2] = xz + ay;
    J[3] = xy + az; J[4] = d + by * y; J[5] = yz - ax;
    J[6] = xz - ay; J[7] = yz + ax; J[8] = d + bz * z;
}

LM_INLINE double norm2_3(const double *w) { return w[0] * w[0] + w[1] * w[1] + w[2] * w[2]; }

LM_INLINE void so3_jr_m(const double *w, double *J) {
    double t2 = norm2_3(w), k, ch;
    half_angle(t2, &k, &ch);
    i_hat_sq(-2.0 * k * k, coef_b(t2, k, ch), w, t2, J);
}

LM_INLINE void so3_jr_inv_m(const double *w, double *J) {
    double t2 = norm2_3(w), k, ch;
    half_angle(t2, &k, &ch);
    i_hat_sq(0.5, coef_c(t2, k, ch), w, t2, J);
}

/* The even and odd parts of Q(rho, phi) (se3.q_parts): Q(-rho, -phi) = even - odd */
LM_INLINE void q_parts(const double *rho, const double *phi, double *even, double *odd) {
    double t2 = norm2_3(phi), k, ch;
    half_angle(t2, &k, &ch);
    double c1 = coef_b(t2, k, ch);
    double small = t2 < SMALL2 ? 1.0 : 0.0;
    /* cos(t + 0.0) (= cos t): keeps GCC from fusing sin and cos into a sincos, which does not
     * vectorise */
    double t2s = t2 + small, t = sqrt(t2s), st = sin(t), ct = cos(t + 0.0), t4 = t2s * t2s;
    double c2c = (t2s + 2.0 * ct - 2.0) / (2.0 * t4);
    double c3c = (2.0 * t - 3.0 * st + t * ct) / (2.0 * t4 * t);
    double c2 = small != 0.0 ? horner(t2, C_COS4, N_COS4) : c2c;
    double c3 = small != 0.0 ? horner(t2, C_SIN5, N_SIN5) : c3c;
    double d = rho[0] * phi[0] + rho[1] * phi[1] + rho[2] * phi[2];
    double F[9], P[9], G[9], a[3], g[3];
    hat3(phi, F);
    hat3(rho, P);
    cross3(phi, rho, a);
    cross3(phi, a, g);
    hat3(g, G);
    double c1d = c1 * d, c2d = c2 * d, c3d = 2.0 * c3 * d, c21 = c2d - c1d;
#define QP(i, j, DIAG)                                                                          \
    even[3 * i + j] = c1 * (rho[i] * phi[j] + phi[i] * rho[j] - DIAG * (2.0 * d))               \
                      - c3d * (phi[i] * phi[j] - DIAG * t2);                                    \
    odd[3 * i + j] = 0.5 * P[3 * i + j] + c21 * F[3 * i + j] + c2 * G[3 * i + j];
    QP(0, 0, 1.0) QP(0, 1, 0.0) QP(0, 2, 0.0)
    QP(1, 0, 0.0) QP(1, 1, 1.0) QP(1, 2, 0.0)
    QP(2, 0, 0.0) QP(2, 1, 0.0) QP(2, 2, 1.0)
#undef QP
}

/* [[Ji, -Ji Q Ji], [0, Ji]] into a 6x6 (se3._jinv_block) */
LM_INLINE void jinv_block(const double *Ji, const double *Q, double *J) {
    double T[9], M[9];
    mm3(Q, Ji, T);
    mm3(Ji, T, M);
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 3; j++) {
            J[6 * i + j] = Ji[3 * i + j];
            J[6 * i + 3 + j] = -M[3 * i + j];
            J[6 * (i + 3) + j] = 0.0;
            J[6 * (i + 3) + 3 + j] = Ji[3 * i + j];
        }
}

/* [[A, B], [0, A]] into a 6x6 */
LM_INLINE void upper_block(const double *A, const double *B, double *J) {
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 3; j++) {
            J[6 * i + j] = A[3 * i + j];
            J[6 * i + 3 + j] = B[3 * i + j];
            J[6 * (i + 3) + j] = 0.0;
            J[6 * (i + 3) + 3 + j] = A[3 * i + j];
        }
}

LM_INLINE void se3_jr_m(const double *tau, double *J) {
    double even[9], odd[9], Jr[9], D[9];
    q_parts(tau, tau + 3, even, odd);
    so3_jr_m(tau + 3, Jr);
#pragma GCC unroll 64
    for (int i = 0; i < 9; i++) D[i] = even[i] - odd[i];
    upper_block(Jr, D, J);
}

/* Jr^-1(tau) and, when Jl is not NULL, Jl^-1(tau) (se3._jr_inv_pair) */
LM_INLINE void se3_jr_inv_m(const double *tau, double *Jr, double *Jl) {
    double even[9], odd[9], Ji[9], D[9];
    so3_jr_inv_m(tau + 3, Ji);
    q_parts(tau, tau + 3, even, odd);
#pragma GCC unroll 64
    for (int i = 0; i < 9; i++) D[i] = even[i] - odd[i];
    jinv_block(Ji, D, Jr);
    if (Jl) {
        double Jt[9];
#pragma GCC unroll 64
        for (int i = 0; i < 3; i++)
#pragma GCC unroll 64
            for (int j = 0; j < 3; j++) {
                Jt[3 * i + j] = Ji[3 * j + i];
                D[3 * i + j] = even[3 * i + j] + odd[3 * i + j];
            }
        jinv_block(Jt, D, Jl);
    }
}

/* ------------------------------------------------------- group primitives on local arrays */

LM_INLINE void so3_exp_l(const double *w, double *q) {
    double k, ch;
    half_angle(norm2_3(w), &k, &ch);
    q[0] = k * w[0]; q[1] = k * w[1]; q[2] = k * w[2]; q[3] = ch;
}

LM_INLINE void se3_exp_l(const double *tau, double *p) {
    const double *rho = tau, *phi = tau + 3;
    double t2 = norm2_3(phi), k, ch;
    half_angle(t2, &k, &ch);
    double a = 2.0 * k * k, b = coef_b(t2, k, ch), c[3], d[3];
    cross3(phi, rho, c);
    cross3(phi, c, d);
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++) p[i] = rho[i] + a * c[i] + b * d[i];
    p[3] = k * phi[0]; p[4] = k * phi[1]; p[5] = k * phi[2]; p[6] = ch;
}

LM_INLINE void se3_log_l(const double *p, double *tau) {
    const double *t = p, *q = p + 3;
    double *phi = tau + 3, kl, aw, a[3], b[3];
    quat_log(q, phi, &kl, &aw);
    double t2 = norm2_3(phi);
    double c = coef_c(t2, 1.0 / kl, aw);
    cross3(phi, t, a);
    cross3(phi, a, b);
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++) tau[i] = t[i] - 0.5 * a[i] + c * b[i];
}

LM_INLINE void se3_compose_l(const double *p, const double *q, double *o) {
    double r[3];
    quat_rotate(p + 3, q, r);
    o[0] = p[0] + r[0]; o[1] = p[1] + r[1]; o[2] = p[2] + r[2];
    quat_mul(p + 3, q + 3, o + 3);
}

LM_INLINE void se3_inverse_l(const double *p, double *o) {
    double t[3];
    quat_conj(p + 3, o + 3);
    quat_rotate(o + 3, p, t);
    o[0] = -t[0]; o[1] = -t[1]; o[2] = -t[2];
}

/* Ad of an SE(3) element: [[R, hat(t) R], [0, R]] */
LM_INLINE void se3_adjoint_l(const double *p, double *J) {
    double R[9], H[9], HR[9];
    quat_matrix(p + 3, R);
    hat3(p, H);
    mm3(H, R, HR);
    upper_block(R, HR, J);
}

/* ------------------------------------------------ element operations on SoA blocks (stride S) */

#define LD3(p) {(p)[0], (p)[S], (p)[2 * S]}
#define LD4(p) {(p)[0], (p)[S], (p)[2 * S], (p)[3 * S]}
#define LD6(p) {(p)[0], (p)[S], (p)[2 * S], (p)[3 * S], (p)[4 * S], (p)[5 * S]}
#define LD7(p) {(p)[0], (p)[S], (p)[2 * S], (p)[3 * S], (p)[4 * S], (p)[5 * S], (p)[6 * S]}
#define ST(o, v, n) do { _Pragma("GCC unroll 64") for (int i_ = 0; i_ < (n); i_++) (o)[i_ * S] = (v)[i_]; } while (0)
#define NEG(v, n) do { _Pragma("GCC unroll 64") for (int i_ = 0; i_ < (n); i_++) (v)[i_] = -(v)[i_]; } while (0)

/* every element operation: (first input, second input, outputs one after another) */
#define EL(name) LM_INLINE void name(const double *a, const double *b, double *o)

EL(so3_exp) { (void)b; double w[3] = LD3(a), q[4]; so3_exp_l(w, q); ST(o, q, 4); }
EL(so3_log) {
    (void)b; double q[4] = LD4(a), phi[3], kl, aw;
    quat_log(q, phi, &kl, &aw);
    ST(o, phi, 3);
}
EL(so3_inverse) { (void)b; double q[4] = LD4(a), r[4]; quat_conj(q, r); ST(o, r, 4); }
EL(so3_compose) { double p[4] = LD4(a), q[4] = LD4(b), r[4]; quat_mul(p, q, r); ST(o, r, 4); }
EL(so3_between) {
    double p[4] = LD4(a), q[4] = LD4(b), c[4], r[4];
    quat_conj(p, c);
    quat_mul(c, q, r);
    ST(o, r, 4);
}
EL(so3_act) { double q[4] = LD4(a), v[3] = LD3(b), r[3]; quat_rotate(q, v, r); ST(o, r, 3); }
EL(so3_minus) { /* Log(X^-1 Y), inputs (Y, X) */
    double y[4] = LD4(a), x[4] = LD4(b), c[4], z[4], phi[3], kl, aw;
    quat_conj(x, c);
    quat_mul(c, y, z);
    quat_log(z, phi, &kl, &aw);
    ST(o, phi, 3);
}
EL(so3_jr) { (void)b; double w[3] = LD3(a), J[9]; so3_jr_m(w, J); ST(o, J, 9); }
EL(so3_jr_inv) { (void)b; double w[3] = LD3(a), J[9]; so3_jr_inv_m(w, J); ST(o, J, 9); }
EL(so3_exp_jac) {
    (void)b; double w[3] = LD3(a), q[4], J[9];
    so3_exp_l(w, q);
    so3_jr_m(w, J);
    ST(o, q, 4); ST(o + 4 * S, J, 9);
}
EL(so3_act_jac) { /* (R v, -R hat(v), R) */
    double q[4] = LD4(a), v[3] = LD3(b), r[3], R[9], H[9], M[9];
    quat_rotate(q, v, r);
    quat_matrix(q, R);
    hat3(v, H);
    mm3(R, H, M);
    NEG(M, 9);
    ST(o, r, 3); ST(o + 3 * S, M, 9); ST(o + 12 * S, R, 9);
}
EL(so3_inverse_jac) { /* (q^-1, -Ad(q)) */
    (void)b; double q[4] = LD4(a), r[4], R[9];
    quat_conj(q, r);
    quat_matrix(q, R);
    NEG(R, 9);
    ST(o, r, 4); ST(o + 4 * S, R, 9);
}
EL(so3_compose_jac) { /* (p q, Ad(q^-1)) */
    double p[4] = LD4(a), q[4] = LD4(b), r[4], c[4], R[9];
    quat_mul(p, q, r);
    quat_conj(q, c);
    quat_matrix(c, R);
    ST(o, r, 4); ST(o + 4 * S, R, 9);
}
EL(so3_between_jac) { /* (z = p^-1 q, -Ad(z^-1)) */
    double p[4] = LD4(a), q[4] = LD4(b), c[4], z[4], R[9];
    quat_conj(p, c);
    quat_mul(c, q, z);
    quat_conj(z, c);
    quat_matrix(c, R);
    NEG(R, 9);
    ST(o, z, 4); ST(o + 4 * S, R, 9);
}
EL(so3_minus_jac) { /* (tau, Jr^-1(tau), -Jl^-1(tau)) with Jl^-1 = (Jr^-1)^T */
    double y[4] = LD4(a), x[4] = LD4(b), c[4], z[4], phi[3], kl, aw, J[9], L[9];
    quat_conj(x, c);
    quat_mul(c, y, z);
    quat_log(z, phi, &kl, &aw);
    so3_jr_inv_m(phi, J);
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 3; j++) L[3 * i + j] = -J[3 * j + i];
    ST(o, phi, 3); ST(o + 3 * S, J, 9); ST(o + 12 * S, L, 9);
}

EL(se3_exp) { (void)b; double t[6] = LD6(a), p[7]; se3_exp_l(t, p); ST(o, p, 7); }
EL(se3_log) { (void)b; double p[7] = LD7(a), t[6]; se3_log_l(p, t); ST(o, t, 6); }
EL(se3_inverse) { (void)b; double p[7] = LD7(a), r[7]; se3_inverse_l(p, r); ST(o, r, 7); }
EL(se3_compose) {
    double p[7] = LD7(a), q[7] = LD7(b), r[7];
    se3_compose_l(p, q, r);
    ST(o, r, 7);
}
EL(se3_between) {
    double p[7] = LD7(a), q[7] = LD7(b), pi[7], r[7];
    se3_inverse_l(p, pi);
    se3_compose_l(pi, q, r);
    ST(o, r, 7);
}
EL(se3_act) {
    double p[7] = LD7(a), v[3] = LD3(b), r[3];
    quat_rotate(p + 3, v, r);
    r[0] += p[0]; r[1] += p[1]; r[2] += p[2];
    ST(o, r, 3);
}
EL(se3_minus) {
    double y[7] = LD7(a), x[7] = LD7(b), xi[7], z[7], t[6];
    se3_inverse_l(x, xi);
    se3_compose_l(xi, y, z);
    se3_log_l(z, t);
    ST(o, t, 6);
}
EL(se3_jr) { (void)b; double t[6] = LD6(a), J[36]; se3_jr_m(t, J); ST(o, J, 36); }
EL(se3_jr_inv) {
    (void)b; double t[6] = LD6(a), J[36];
    se3_jr_inv_m(t, J, (double *)0);
    ST(o, J, 36);
}
EL(se3_exp_jac) {
    (void)b; double t[6] = LD6(a), p[7], J[36];
    se3_exp_l(t, p);
    se3_jr_m(t, J);
    ST(o, p, 7); ST(o + 7 * S, J, 36);
}
EL(se3_act_jac) { /* (R v + t, [R, -R hat(v)], R) */
    double p[7] = LD7(a), v[3] = LD3(b), r[3], R[9], H[9], M[9], JT[18];
    quat_rotate(p + 3, v, r);
    r[0] += p[0]; r[1] += p[1]; r[2] += p[2];
    quat_matrix(p + 3, R);
    hat3(v, H);
    mm3(R, H, M);
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 3; j++) {
            JT[6 * i + j] = R[3 * i + j];
            JT[6 * i + 3 + j] = -M[3 * i + j];
        }
    ST(o, r, 3); ST(o + 3 * S, JT, 18); ST(o + 21 * S, R, 9);
}
EL(se3_inverse_jac) { /* (p^-1, -Ad(p)) */
    (void)b; double p[7] = LD7(a), r[7], J[36];
    se3_inverse_l(p, r);
    se3_adjoint_l(p, J);
    NEG(J, 36);
    ST(o, r, 7); ST(o + 7 * S, J, 36);
}
EL(se3_compose_jac) { /* (p q, Ad(q^-1)) */
    double p[7] = LD7(a), q[7] = LD7(b), r[7], qi[7], J[36];
    se3_compose_l(p, q, r);
    se3_inverse_l(q, qi);
    se3_adjoint_l(qi, J);
    ST(o, r, 7); ST(o + 7 * S, J, 36);
}
EL(se3_between_jac) { /* (z = p^-1 q, -Ad(z^-1)) */
    double p[7] = LD7(a), q[7] = LD7(b), pi[7], z[7], zi[7], J[36];
    se3_inverse_l(p, pi);
    se3_compose_l(pi, q, z);
    se3_inverse_l(z, zi);
    se3_adjoint_l(zi, J);
    NEG(J, 36);
    ST(o, z, 7); ST(o + 7 * S, J, 36);
}
EL(se3_minus_jac) { /* (tau, Jr^-1(tau), -Jl^-1(tau)) */
    double y[7] = LD7(a), x[7] = LD7(b), xi[7], z[7], t[6], Jr[36], Jl[36];
    se3_inverse_l(x, xi);
    se3_compose_l(xi, y, z);
    se3_log_l(z, t);
    se3_jr_inv_m(t, Jr, Jl);
    NEG(Jl, 36);
    ST(o, t, 6); ST(o + 6 * S, Jr, 36); ST(o + 42 * S, Jl, 36);
}

EL(so3_log_jac) { /* (phi, Jr^-1(phi)) */
    (void)b; double q[4] = LD4(a), phi[3], kl, aw, J[9];
    quat_log(q, phi, &kl, &aw);
    so3_jr_inv_m(phi, J);
    ST(o, phi, 3); ST(o + 3 * S, J, 9);
}
EL(so3_matrix) { (void)b; double q[4] = LD4(a), R[9]; quat_matrix(q, R); ST(o, R, 9); }
EL(so3_adjoint_inv) { /* Ad(q^-1) = R(q^-1) */
    (void)b; double q[4] = LD4(a), c[4], R[9];
    quat_conj(q, c);
    quat_matrix(c, R);
    ST(o, R, 9);
}
EL(so3_plus) { /* q Exp(t) */
    double q[4] = LD4(a), w[3] = LD3(b), e[4], r[4];
    so3_exp_l(w, e);
    quat_mul(q, e, r);
    ST(o, r, 4);
}

EL(se3_log_jac) { /* (tau, Jr^-1(tau)) */
    (void)b; double p[7] = LD7(a), t[6], J[36];
    se3_log_l(p, t);
    se3_jr_inv_m(t, J, (double *)0);
    ST(o, t, 6); ST(o + 6 * S, J, 36);
}
EL(se3_adjoint) { (void)b; double p[7] = LD7(a), J[36]; se3_adjoint_l(p, J); ST(o, J, 36); }
EL(se3_adjoint_inv) {
    (void)b; double p[7] = LD7(a), pi[7], J[36];
    se3_inverse_l(p, pi);
    se3_adjoint_l(pi, J);
    ST(o, J, 36);
}
EL(se3_matrix) { /* [[R, t], [0, 1]] */
    (void)b; double p[7] = LD7(a), R[9], M[16];
    quat_matrix(p + 3, R);
    for (int i = 0; i < 3; i++) {
        M[4 * i] = R[3 * i]; M[4 * i + 1] = R[3 * i + 1]; M[4 * i + 2] = R[3 * i + 2];
        M[4 * i + 3] = p[i];
    }
    M[12] = 0.0; M[13] = 0.0; M[14] = 0.0; M[15] = 1.0;
    ST(o, M, 16);
}
EL(se3_plus) { /* p Exp(t) */
    double p[7] = LD7(a), t[6] = LD6(b), e[7], r[7];
    se3_exp_l(t, e);
    se3_compose_l(p, e, r);
    ST(o, r, 7);
}
EL(so3_adjoint) { (void)b; double q[4] = LD4(a), R[9]; quat_matrix(q, R); ST(o, R, 9); }

/* ---------------------------------------- left operations and the Jacobians of plus/lminus */

LM_INLINE void mm6(const double *a, const double *b, double *o) {
#pragma GCC unroll 64
    for (int i = 0; i < 6; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 6; j++)
            o[6 * i + j] = a[6 * i] * b[j] + a[6 * i + 1] * b[6 + j] + a[6 * i + 2] * b[12 + j]
                           + a[6 * i + 3] * b[18 + j] + a[6 * i + 4] * b[24 + j]
                           + a[6 * i + 5] * b[30 + j];
}

EL(so3_lplus) { /* Exp(t) q */
    double q[4] = LD4(a), w[3] = LD3(b), e[4], r[4];
    so3_exp_l(w, e);
    quat_mul(e, q, r);
    ST(o, r, 4);
}
EL(so3_lminus) { /* Log(Y X^-1), inputs (Y, X) */
    double y[4] = LD4(a), x[4] = LD4(b), c[4], z[4], phi[3], kl, aw;
    quat_conj(x, c);
    quat_mul(y, c, z);
    quat_log(z, phi, &kl, &aw);
    ST(o, phi, 3);
}
EL(so3_plus_jac) { /* (q Exp(t), Ad(Exp(t)^-1), Jr(t)) */
    double q[4] = LD4(a), w[3] = LD3(b), e[4], r[4], c[4], R[9], J[9];
    so3_exp_l(w, e);
    quat_mul(q, e, r);
    quat_conj(e, c);
    quat_matrix(c, R);
    so3_jr_m(w, J);
    ST(o, r, 4); ST(o + 4 * S, R, 9); ST(o + 13 * S, J, 9);
}
EL(so3_lplus_jac) { /* (Exp(t) q, Ad(q^-1) Jr(t)) */
    double q[4] = LD4(a), w[3] = LD3(b), e[4], r[4], c[4], R[9], J[9], M[9];
    so3_exp_l(w, e);
    quat_mul(e, q, r);
    quat_conj(q, c);
    quat_matrix(c, R);
    so3_jr_m(w, J);
    mm3(R, J, M);
    ST(o, r, 4); ST(o + 4 * S, M, 9);
}
EL(so3_lminus_jac) { /* (tau, Jr^-1(tau) Ad_X, -Jr^-1(tau) Ad_X) */
    double y[4] = LD4(a), x[4] = LD4(b), c[4], z[4], phi[3], kl, aw, J[9], R[9], M[9];
    quat_conj(x, c);
    quat_mul(y, c, z);
    quat_log(z, phi, &kl, &aw);
    so3_jr_inv_m(phi, J);
    quat_matrix(x, R);
    mm3(J, R, M);
    ST(o, phi, 3); ST(o + 3 * S, M, 9);
    NEG(M, 9);
    ST(o + 12 * S, M, 9);
}

EL(se3_lplus) { /* Exp(t) p */
    double p[7] = LD7(a), t[6] = LD6(b), e[7], r[7];
    se3_exp_l(t, e);
    se3_compose_l(e, p, r);
    ST(o, r, 7);
}
EL(se3_lminus) { /* Log(Y X^-1), inputs (Y, X) */
    double y[7] = LD7(a), x[7] = LD7(b), xi[7], z[7], t[6];
    se3_inverse_l(x, xi);
    se3_compose_l(y, xi, z);
    se3_log_l(z, t);
    ST(o, t, 6);
}
EL(se3_plus_jac) { /* (p Exp(t), Ad(Exp(t)^-1), Jr(t)) */
    double p[7] = LD7(a), t[6] = LD6(b), e[7], r[7], ei[7], A[36], J[36];
    se3_exp_l(t, e);
    se3_compose_l(p, e, r);
    se3_inverse_l(e, ei);
    se3_adjoint_l(ei, A);
    se3_jr_m(t, J);
    ST(o, r, 7); ST(o + 7 * S, A, 36); ST(o + 43 * S, J, 36);
}
EL(se3_lplus_jac) { /* (Exp(t) p, Ad(p^-1) Jr(t)) */
    double p[7] = LD7(a), t[6] = LD6(b), e[7], r[7], pi[7], A[36], J[36], M[36];
    se3_exp_l(t, e);
    se3_compose_l(e, p, r);
    se3_inverse_l(p, pi);
    se3_adjoint_l(pi, A);
    se3_jr_m(t, J);
    mm6(A, J, M);
    ST(o, r, 7); ST(o + 7 * S, M, 36);
}
EL(se3_lminus_jac) { /* (tau, Jr^-1(tau) Ad_X, -Jr^-1(tau) Ad_X) */
    double y[7] = LD7(a), x[7] = LD7(b), xi[7], z[7], t[6], J[36], A[36], M[36];
    se3_inverse_l(x, xi);
    se3_compose_l(y, xi, z);
    se3_log_l(z, t);
    se3_jr_inv_m(t, J, (double *)0);
    se3_adjoint_l(x, A);
    mm6(J, A, M);
    ST(o, t, 6); ST(o + 6 * S, M, 36);
    NEG(M, 36);
    ST(o + 42 * S, M, 36);
}
