/* Element formulas of Sim(3), written on doubles in the same form as microlie's generic component
 * kernels (microlie/groups/sim3.py): the same phi-functions, weighted-mean coefficients of
 * W = a I + b hat(phi) + c hat(phi)^2, thresholds and Taylor polynomials (coeffs.h, generated
 * from microlie.groups.sim3), so that a compiled kernel agrees with the generic one to rounding.
 * Layouts: Sim3 (tx, ty, tz, qx, qy, qz, qw, s); tangent (rho, phi, sigma), s = e^sigma;
 * matrices row-major. Included by _lie.c after lie_math.h (whose helpers and SoA macros it uses).
 * The range |sigma| <= SIGMA_MAX is checked by the group class before and after the kernels. */
#pragma once
#include "lie_math.h"

/* horner() for the longer series (fully unrolled, so that the element loop vectorises) */
LM_INLINE double horner_long(double x, const double *c, int n) {
    double acc = c[n - 1];
#pragma GCC unroll 32
    for (int i = n - 2; i >= 0; i--) acc = acc * x + c[i];
    return acc;
}

/* (e^x, phi_1, phi_2, phi_3, phi_4) at x = sigma (sim3.phi_functions) */
LM_INLINE void sim3_phi(double sigma, double *E, double *a, double *d, double *e, double *f) {
    *E = exp(sigma);
    double small = fabs(sigma) < PHI_SMALL ? 1.0 : 0.0;
    double f_s = horner_long(sigma, C_PHI4, N_PHI4);
    double e_s = 1.0 / 6.0 + sigma * f_s;
    double d_s = 0.5 + sigma * e_s;
    double a_s = 1.0 + sigma * d_s;
    double x = small != 0.0 ? 3.0 : sigma;
    double a_c = expm1(x) / x;
    double d_c = (a_c - 1.0) / x;
    double e_c = (d_c - 0.5) / x;
    double f_c = (e_c - 1.0 / 6.0) / x;
    *a = small != 0.0 ? a_s : a_c;
    *d = small != 0.0 ? d_s : d_c;
    *e = small != 0.0 ? e_s : e_c;
    *f = small != 0.0 ? f_s : f_c;
}

/* The coefficients of W and (with D not NULL) their derivatives (sim3.coefficients):
 * W = (a, b, c); H = (E, sinc, h, k, ch); D = (a_s, b_s, c_s, b_t, c_t, cb) */
LM_INLINE void sim3_coefficients(double sigma, double t2, double k, double ch, double *W,
                                 double *H, double *D) {
    double E, a, d, e, f;
    sim3_phi(sigma, &E, &a, &d, &e, &f);
    double sinc = 2.0 * k * ch, h = 2.0 * k * k, cs = 1.0 - t2 * h;
    double cb = coef_b(t2, k, ch);
    double small = t2 < SMALL2 ? 1.0 : 0.0, ts = t2 + small;
    double c4 = small != 0.0 ? horner(t2, C_COS4, N_COS4) : (0.5 - h) / ts;
    double k3 = k * k - 0.5 * cb;
    double z2 = sigma * sigma + t2;
    double tiny = z2 < SIM3_TINY ? 1.0 : 0.0;
    z2 = z2 + tiny;
    double ws = sigma * sigma / z2, wt = t2 / z2;
    double Pb = a * sinc - d * cs, Qb = h + 2.0 * sigma * k3;
    double Pc = e + a * h - d * sinc, Qc = cb + sigma * (cb - c4);
    W[0] = a;
    W[1] = tiny != 0.0 ? 0.5 + sigma / 3.0 : ws * Pb + wt * Qb;
    W[2] = tiny != 0.0 ? 1.0 / 6.0 + sigma / 8.0 : ws * Pc + wt * Qc;
    H[0] = E; H[1] = sinc; H[2] = h; H[3] = k; H[4] = ch;
    if (!D) return;
    double c5 = small != 0.0 ? horner(t2, C_SIN5, N_SIN5) : (3.0 * cb - h) / (2.0 * ts);
    double c6 = small != 0.0 ? horner(t2, C_COS6, N_COS6) : (2.0 * c4 - 0.5 * cb) / ts;
    double ht = c4 - 0.5 * cb;
    double k3t = 0.5 * (ht + c5);
    double ad = a - d, de = d - 2.0 * e;
    /* slopes of f = ws P + wt Q in sigma and t2 (the quotient rule) */
#define SLOPES(P, Q, Ps, Qs, Pt, Qt, s0, t0, FS, FT)                                            \
    {                                                                                          \
        double Dq = ((P) - (Q)) / z2;                                                          \
        double fs = ws * (Ps) + wt * (Qs) + (2.0 * sigma) * wt * Dq;                           \
        double ft = ws * (Pt) + wt * (Qt) - ws * Dq;                                           \
        FS = tiny != 0.0 ? (s0) : fs;                                                          \
        FT = tiny != 0.0 ? (t0) : ft;                                                          \
    }
    double bs, bt, cs_, ct;
    SLOPES(Pb, Qb, ad * sinc - de * cs, 2.0 * k3, d * (0.5 * sinc) - a * k3,
           ht + 2.0 * sigma * k3t, 1.0 / 3.0, -1.0 / 24.0, bs, bt)
    SLOPES(Pc, Qc, (e - 3.0 * f) + ad * h - de * sinc, cb - c4, a * ht + d * k3,
           sigma * (c6 - c5) - c5, 1.0 / 8.0, -1.0 / 120.0, cs_, ct)
#undef SLOPES
    D[0] = ad; D[1] = bs; D[2] = cs_; D[3] = bt; D[4] = ct; D[5] = cb;
}

/* p0 I + p1 hat(w) + p2 hat(w)^2 (sim3.poly_matrix) */
LM_INLINE void poly_matrix(const double *p, const double *w, double t2, double *M) {
    double x = w[0], y = w[1], z = w[2];
    double bx = p[2] * x, by = p[2] * y, bz = p[2] * z, d = p[0] - p[2] * t2;
    double ax = p[1] * x, ay = p[1] * y, az = p[1] * z, xy = bx * y, xz = bx * z, yz = by * z;
    M[0] = d + bx * x; M[1] = xy - az; M[2] = xz + ay;
    M[3] = xy + az; M[4] = d + by * y; M[5] = yz - ax;
    M[6] = xz - ay; M[7] = yz + ax; M[8] = d + bz * z;
}

/* product of polynomials in hat(w) (sim3.poly_mul) */
LM_INLINE void poly_mul(const double *p, const double *q, double t2, double *o) {
    o[0] = p[0] * q[0];
    o[1] = p[0] * q[1] + p[1] * q[0] - t2 * (p[1] * q[2] + p[2] * q[1]);
    o[2] = p[0] * q[2] + p[1] * q[1] + p[2] * q[0] - t2 * (p[2] * q[2]);
}

/* inverse of p0 I + p1 hat(w) + p2 hat(w)^2 (sim3.poly_inv) */
LM_INLINE void poly_inv(const double *p, double t2, double *o) {
    double q1 = p[1] / p[0], q2 = p[2] / p[0];
    double u = 1.0 - q2 * t2;
    double L = u * u + q1 * q1 * t2;
    double s = 1.0 / p[0];
    o[0] = s;
    o[1] = -s * q1 / L;
    o[2] = s * (q1 * q1 - u * q2) / L;
}

/* (p0 I + p1 hat(w) + p2 hat(w)^2) v (sim3.poly_apply) */
LM_INLINE void poly_apply(const double *p, const double *w, const double *v, double *o) {
    double u[3], x[3];
    cross3(w, v, u);
    cross3(w, u, x);
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++) o[i] = p[0] * v[i] + p[1] * u[i] + p[2] * x[i];
}

LM_INLINE void sim3_exp_l(const double *tau, double *p) {
    const double *rho = tau, *phi = tau + 3;
    double sigma = tau[6], t2 = norm2_3(phi), k, ch, W[3], H[5];
    half_angle(t2, &k, &ch);
    sim3_coefficients(sigma, t2, k, ch, W, H, (double *)0);
    poly_apply(W, phi, rho, p);
    p[3] = k * phi[0]; p[4] = k * phi[1]; p[5] = k * phi[2]; p[6] = ch; p[7] = H[0];
}

LM_INLINE void sim3_log_l(const double *p, double *tau) {
    double *phi = tau + 3, kl, aw, W[3], H[5], Wi[3];
    quat_log(p + 3, phi, &kl, &aw);
    double sigma = log(p[7]), t2 = norm2_3(phi);
    sim3_coefficients(sigma, t2, 1.0 / kl, aw, W, H, (double *)0);
    poly_inv(W, t2, Wi);
    poly_apply(Wi, phi, p, tau);
    tau[6] = sigma;
}

LM_INLINE void sim3_compose_l(const double *p, const double *q, double *o) {
    double r[3], s = p[7];
    quat_rotate(p + 3, q, r);
    o[0] = p[0] + s * r[0]; o[1] = p[1] + s * r[1]; o[2] = p[2] + s * r[2];
    quat_mul(p + 3, q + 3, o + 3);
    o[7] = s * q[7];
}

LM_INLINE void sim3_inverse_l(const double *p, double *o) {
    double t[3], si = 1.0 / p[7];
    quat_conj(p + 3, o + 3);
    quat_rotate(o + 3, p, t);
    o[0] = -si * t[0]; o[1] = -si * t[1]; o[2] = -si * t[2];
    o[7] = si;
}

LM_INLINE void sim3_act_l(const double *p, const double *v, double *o) {
    double r[3], s = p[7];
    quat_rotate(p + 3, v, r);
    o[0] = s * r[0] + p[0]; o[1] = s * r[1] + p[1]; o[2] = s * r[2] + p[2];
}

/* Ad = [[s R, hat(t) R, -t], [0, R, 0], [0, 0, 1]] (7x7); every entry written once (a loop
 * of zero stores would become a memset call, which stops the element loop vectorising) */
LM_INLINE void sim3_adjoint_l(const double *p, double *J) {
    double R[9], H[9], HR[9], s = p[7];
    quat_matrix(p + 3, R);
    hat3(p, H);
    mm3(H, R, HR);
#pragma GCC unroll 64
    for (int i = 0; i < 7; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 7; j++)
            J[7 * i + j] = i < 3 ? (j < 3 ? s * R[3 * i + j] : j < 6 ? HR[3 * i + j - 3] : -p[i])
                           : i < 6 ? (j >= 3 && j < 6 ? R[3 * (i - 3) + j - 3] : 0.0)
                                   : (j == 6 ? 1.0 : 0.0);
}

/* [[A, top], [0, J, 0], [0, 0, 1]] into a 7x7 (sim3._assemble), top 3x4 */
LM_INLINE void sim3_assemble(const double *A, const double *top, const double *Jm, double *J) {
#pragma GCC unroll 64
    for (int i = 0; i < 7; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 7; j++)
            J[7 * i + j] = i < 3 ? (j < 3 ? A[3 * i + j] : top[4 * i + j - 3])
                           : i < 6 ? (j >= 3 && j < 6 ? Jm[3 * (i - 3) + j - 3] : 0.0)
                                   : (j == 6 ? 1.0 : 0.0);
}

/* The pieces of Jr and Jr^-1 (sim3._jacobian_pieces): W, H = (E, sinc, h, k, ch), cb, and the
 * 3x4 block [d(W rho)/d phi | d(W rho)/d sigma] */
LM_INLINE void sim3_pieces(const double *tau, double *t2o, double *W, double *H, double *cbo,
                           double *Mx) {
    const double *rho = tau, *phi = tau + 3;
    double sigma = tau[6], t2 = norm2_3(phi), k, ch, D[6];
    half_angle(t2, &k, &ch);
    sim3_coefficients(sigma, t2, k, ch, W, H, D);
    double b = W[1], c = W[2], a_s = D[0], b_s = D[1], c_s = D[2], b_t = D[3], c_t = D[4];
    double u[3], v[3], w[3], cp[3], br[3];
    cross3(phi, rho, u);
    cross3(phi, u, v);
    double d = phi[0] * rho[0] + phi[1] * rho[1] + phi[2] * rho[2];
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++) {
        cp[i] = c * phi[i];
        w[i] = 2.0 * (b_t * u[i] + c_t * v[i] - c * rho[i]);
        br[i] = b * rho[i];
    }
    double cd = c * d, g[9];
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 3; j++) g[3 * i + j] = cp[i] * rho[j] + w[i] * phi[j];
    Mx[0] = g[0] + cd; Mx[1] = g[1] + br[2]; Mx[2] = g[2] - br[1];
    Mx[4] = g[3] - br[2]; Mx[5] = g[4] + cd; Mx[6] = g[5] + br[0];
    Mx[8] = g[6] + br[1]; Mx[9] = g[7] - br[0]; Mx[10] = g[8] + cd;
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++) Mx[4 * i + 3] = a_s * rho[i] + b_s * u[i] + c_s * v[i];
    *t2o = t2;
    *cbo = D[5];
}

/* (3x3) @ (3x4) */
LM_INLINE void mm34(const double *a, const double *b, double *o) {
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 4; j++)
            o[4 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[4 + j] + a[3 * i + 2] * b[8 + j];
}

LM_INLINE void sim3_jr_m(const double *tau, double *J) {
    const double *phi = tau + 3;
    double t2, W[3], H[5], cb, Mx[12];
    sim3_pieces(tau, &t2, W, H, &cb, Mx);
    double ei = 1.0 / H[0], Rt[3] = {ei, -ei * H[1], ei * H[2]}, RtM[9], top[12], P[3], A[9];
    double Jm[9];
    poly_matrix(Rt, phi, t2, RtM);
    mm34(RtM, Mx, top);
    poly_mul(Rt, W, t2, P);
    poly_matrix(P, phi, t2, A);
    i_hat_sq(-H[2], cb, phi, t2, Jm);
    sim3_assemble(A, top, Jm, J);
}

LM_INLINE void sim3_jr_inv_m(const double *tau, double *J) {
    const double *phi = tau + 3;
    double t2, W[3], H[5], cb, Mx[12];
    sim3_pieces(tau, &t2, W, H, &cb, Mx);
    double E = H[0], Wi[3], ER[3] = {E, E * H[1], E * H[2]}, P[3], A[9], Ji[9], WiP[9];
    double WiM[12], B[9], Bl[9], top[12];
    poly_inv(W, t2, Wi);
    poly_mul(Wi, ER, t2, P);
    poly_matrix(P, phi, t2, A);
    i_hat_sq(0.5, coef_c(t2, H[3], H[4]), phi, t2, Ji);
    poly_matrix(Wi, phi, t2, WiP);
    mm34(WiP, Mx, WiM);
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 3; j++) Bl[3 * i + j] = WiM[4 * i + j];
    mm3(Bl, Ji, B);
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++) {
#pragma GCC unroll 64
        for (int j = 0; j < 3; j++) top[4 * i + j] = -B[3 * i + j];
        top[4 * i + 3] = -WiM[4 * i + 3];
    }
    sim3_assemble(A, top, Ji, J);
}

/* ------------------------------------------------ element operations on SoA blocks (stride S) */

#define LD8(p) {(p)[0], (p)[S], (p)[2 * S], (p)[3 * S], (p)[4 * S], (p)[5 * S], (p)[6 * S], (p)[7 * S]}

EL(sim3_exp) { (void)b; double t[7] = LD7(a), p[8]; sim3_exp_l(t, p); ST(o, p, 8); }
EL(sim3_log) { (void)b; double p[8] = LD8(a), t[7]; sim3_log_l(p, t); ST(o, t, 7); }
EL(sim3_compose) {
    double p[8] = LD8(a), q[8] = LD8(b), r[8];
    sim3_compose_l(p, q, r);
    ST(o, r, 8);
}
EL(sim3_inverse) { (void)b; double p[8] = LD8(a), r[8]; sim3_inverse_l(p, r); ST(o, r, 8); }
EL(sim3_between) {
    double p[8] = LD8(a), q[8] = LD8(b), pi[8], r[8];
    sim3_inverse_l(p, pi);
    sim3_compose_l(pi, q, r);
    ST(o, r, 8);
}
EL(sim3_act) { double p[8] = LD8(a), v[3] = LD3(b), r[3]; sim3_act_l(p, v, r); ST(o, r, 3); }
EL(sim3_minus) { /* Log(X^-1 Y), inputs (Y, X) */
    double y[8] = LD8(a), x[8] = LD8(b), xi[8], z[8], t[7];
    sim3_inverse_l(x, xi);
    sim3_compose_l(xi, y, z);
    sim3_log_l(z, t);
    ST(o, t, 7);
}
EL(sim3_plus) { /* p Exp(t) */
    double p[8] = LD8(a), t[7] = LD7(b), e[8], r[8];
    sim3_exp_l(t, e);
    sim3_compose_l(p, e, r);
    ST(o, r, 8);
}
EL(sim3_matrix) { /* [[s R, t], [0, 1]] */
    (void)b; double p[8] = LD8(a), R[9], M[16];
    quat_matrix(p + 3, R);
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++) {
        M[4 * i] = p[7] * R[3 * i]; M[4 * i + 1] = p[7] * R[3 * i + 1];
        M[4 * i + 2] = p[7] * R[3 * i + 2]; M[4 * i + 3] = p[i];
    }
    M[12] = 0.0; M[13] = 0.0; M[14] = 0.0; M[15] = 1.0;
    ST(o, M, 16);
}
EL(sim3_adjoint) { (void)b; double p[8] = LD8(a), J[49]; sim3_adjoint_l(p, J); ST(o, J, 49); }
EL(sim3_act_jac) { /* (s R v + t, [s R, -s R hat(v), s R v], s R) */
    double p[8] = LD8(a), v[3] = LD3(b), R[9], H[9], M[9], r[3], JT[21];
    quat_matrix(p + 3, R);
#pragma GCC unroll 64
    for (int i = 0; i < 9; i++) R[i] *= p[7];
    hat3(v, H);
    mm3(R, H, M);
#pragma GCC unroll 64
    for (int i = 0; i < 3; i++) {
        double sRv = R[3 * i] * v[0] + R[3 * i + 1] * v[1] + R[3 * i + 2] * v[2];
        r[i] = sRv;
#pragma GCC unroll 64
        for (int j = 0; j < 3; j++) {
            JT[7 * i + j] = R[3 * i + j];
            JT[7 * i + 3 + j] = -M[3 * i + j];
        }
        JT[7 * i + 6] = sRv;
    }
    sim3_act_l(p, v, r);
    ST(o, r, 3); ST(o + 3 * S, JT, 21); ST(o + 24 * S, R, 9);
}
EL(sim3_jr) { (void)b; double t[7] = LD7(a), J[49]; sim3_jr_m(t, J); ST(o, J, 49); }
EL(sim3_jr_inv) { (void)b; double t[7] = LD7(a), J[49]; sim3_jr_inv_m(t, J); ST(o, J, 49); }
EL(sim3_exp_jac) {
    (void)b; double t[7] = LD7(a), p[8], J[49];
    sim3_exp_l(t, p);
    sim3_jr_m(t, J);
    ST(o, p, 8); ST(o + 8 * S, J, 49);
}
EL(sim3_log_jac) { /* (tau, Jr^-1(tau)) */
    (void)b; double p[8] = LD8(a), t[7], J[49];
    sim3_log_l(p, t);
    sim3_jr_inv_m(t, J);
    ST(o, t, 7); ST(o + 7 * S, J, 49);
}
EL(sim3_minus_jac) { /* (tau, Jr^-1(tau), -Jr^-1(-tau)) */
    double y[8] = LD8(a), x[8] = LD8(b), xi[8], z[8], t[7], mt[7], J[49], L[49];
    sim3_inverse_l(x, xi);
    sim3_compose_l(xi, y, z);
    sim3_log_l(z, t);
    sim3_jr_inv_m(t, J);
#pragma GCC unroll 64
    for (int i = 0; i < 7; i++) mt[i] = -t[i];
    sim3_jr_inv_m(mt, L);
    NEG(L, 49);
    ST(o, t, 7); ST(o + 7 * S, J, 49); ST(o + 56 * S, L, 49);
}
EL(sim3_between_jac) { /* (z = p^-1 q, -Ad(z^-1)) */
    double p[8] = LD8(a), q[8] = LD8(b), pi[8], z[8], zi[8], J[49];
    sim3_inverse_l(p, pi);
    sim3_compose_l(pi, q, z);
    sim3_inverse_l(z, zi);
    sim3_adjoint_l(zi, J);
    NEG(J, 49);
    ST(o, z, 8); ST(o + 8 * S, J, 49);
}
EL(sim3_compose_jac) { /* (p q, Ad(q^-1)) */
    double p[8] = LD8(a), q[8] = LD8(b), r[8], qi[8], J[49];
    sim3_compose_l(p, q, r);
    sim3_inverse_l(q, qi);
    sim3_adjoint_l(qi, J);
    ST(o, r, 8); ST(o + 8 * S, J, 49);
}

/* ---------------------------------------- left operations and the Jacobians of plus/lminus */

LM_INLINE void mm7(const double *a, const double *b, double *o) {
#pragma GCC unroll 64
    for (int i = 0; i < 7; i++)
#pragma GCC unroll 64
        for (int j = 0; j < 7; j++) {
            double acc = 0.0;
#pragma GCC unroll 64
            for (int k = 0; k < 7; k++) acc += a[7 * i + k] * b[7 * k + j];
            o[7 * i + j] = acc;
        }
}

EL(sim3_adjoint_inv) {
    (void)b; double p[8] = LD8(a), pi[8], J[49];
    sim3_inverse_l(p, pi);
    sim3_adjoint_l(pi, J);
    ST(o, J, 49);
}
EL(sim3_inverse_jac) { /* (p^-1, -Ad(p)) */
    (void)b; double p[8] = LD8(a), r[8], J[49];
    sim3_inverse_l(p, r);
    sim3_adjoint_l(p, J);
    NEG(J, 49);
    ST(o, r, 8); ST(o + 8 * S, J, 49);
}
EL(sim3_lplus) { /* Exp(t) p */
    double p[8] = LD8(a), t[7] = LD7(b), e[8], r[8];
    sim3_exp_l(t, e);
    sim3_compose_l(e, p, r);
    ST(o, r, 8);
}
EL(sim3_lminus) { /* Log(Y X^-1), inputs (Y, X) */
    double y[8] = LD8(a), x[8] = LD8(b), xi[8], z[8], t[7];
    sim3_inverse_l(x, xi);
    sim3_compose_l(y, xi, z);
    sim3_log_l(z, t);
    ST(o, t, 7);
}
EL(sim3_plus_jac) { /* (p Exp(t), Ad(Exp(t)^-1), Jr(t)) */
    double p[8] = LD8(a), t[7] = LD7(b), e[8], r[8], ei[8], A[49], J[49];
    sim3_exp_l(t, e);
    sim3_compose_l(p, e, r);
    sim3_inverse_l(e, ei);
    sim3_adjoint_l(ei, A);
    sim3_jr_m(t, J);
    ST(o, r, 8); ST(o + 8 * S, A, 49); ST(o + 57 * S, J, 49);
}
EL(sim3_lplus_jac) { /* (Exp(t) p, Ad(p^-1) Jr(t)) */
    double p[8] = LD8(a), t[7] = LD7(b), e[8], r[8], pi[8], A[49], J[49], M[49];
    sim3_exp_l(t, e);
    sim3_compose_l(e, p, r);
    sim3_inverse_l(p, pi);
    sim3_adjoint_l(pi, A);
    sim3_jr_m(t, J);
    mm7(A, J, M);
    ST(o, r, 8); ST(o + 8 * S, M, 49);
}
EL(sim3_lminus_jac) { /* (tau, Jr^-1(tau) Ad_X, -Jr^-1(tau) Ad_X) */
    double y[8] = LD8(a), x[8] = LD8(b), xi[8], z[8], t[7], J[49], A[49], M[49];
    sim3_inverse_l(x, xi);
    sim3_compose_l(y, xi, z);
    sim3_log_l(z, t);
    sim3_jr_inv_m(t, J);
    sim3_adjoint_l(x, A);
    mm7(J, A, M);
    ST(o, t, 7); ST(o + 7 * S, M, 49);
    NEG(M, 49);
    ST(o + 56 * S, M, 49);
}
