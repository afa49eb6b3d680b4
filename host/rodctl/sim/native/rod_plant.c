/* rod_plant.c: the simulated plant (rod + motor + driver + encoder) and the closed-loop runner.
 *
 * Why these integrators
 * ---------------------
 * Fine rods are stiff. With Table I values (+ the motor's J and b) the linearization has real,
 * overdamped modes down to -537 rad/s at N = 5 and -5.2e4 rad/s at N = 20 (the inter-edge damping
 * d acting on edges of tiny inertia m l^2), while the lightly damped (oscillatory) modes stay
 * below about 170 rad/s at N = 5 and 570 rad/s at N = 20. An explicit method must resolve the
 * fastest real mode (RK4: h < 2.8/5.2e4 = 5e-5 s at N = 20); an implicit one only the slow ones.
 * The wrapper (rodctl.sim.plant.choose_integrator) computes both spectra and picks per plant:
 *
 * Inextensible rod, stiff (N = 20): ROS2 (Verwer, Spee, Blom, Hundsdorfer 1999), y = (theta, w):
 *     (I - gamma h A) k1 = F(y_n)
 *     (I - gamma h A) k2 = F(y_n + h k1) - 2 k1,          gamma = 1 + 1/sqrt(2)
 *     y_{n+1} = y_n + h (3/2 k1 + 1/2 k2)
 * It is order 2 for ANY matrix A (a W-method) and L-stable when A is the exact Jacobian, so A
 * holds just the stiff part: A = [[0, I], [-M^-1 K, -M^-1 D]] with M = M(theta_n),
 * D = d Lap + (b + back-EMF slope) e1 e1' (exact) and K the exact tridiagonal Hessian of the tan
 * bending springs. Gravity, Coriolis and dM/dtheta stay explicit (slow). Eliminating the angle
 * part of each stage leaves one SPD solve per stage,
 *     (M + gamma h D + gamma^2 h^2 K) k_w = M r_w - gamma h K r_theta,   k_theta = r_theta + gamma h k_w
 * (M r_w is the generalized force itself at stage 1), plus the stage-2 acceleration
 * M(theta*)^-1 F(theta*). In joint coordinates (phi_k = theta_k - theta_{k-1}) D and K are
 * diagonal, so both matrices are "chain inertia + joint armature" and the articulated-body
 * recursion solves them in O(N) (no N x N matrix is ever formed in a step; see aba_*). Products
 * with M use its staircase structure, also O(N). sin/cos are taken once per node per step
 * (stage values by an exact small-angle rotation), cos(theta_i - theta_j) and
 * tan(phi/2) = sin(phi) / (1 + cos(phi)) come from products. h = 0.1 / omega_osc.
 * Against Radau (2 s violent swing): 5.4e-4 rad at h = 0.175 ms (N = 20), errors ~ h^2.
 *
 * Inextensible rod, mildly stiff (N <= 10 with Table I): classical RK4 with the same O(N) solves,
 * h = min(2 / max|lambda|, 0.5 / omega_osc, 1 ms): at N = 5 one step per 1 ms period, error 4e-7 rad
 * (ROS2 needs 2 steps for 1e-3 rad). It is chosen whenever it needs no more steps than ROS2.
 *
 * DER: the mass is diagonal and constant, and the undamped stretching modes are NOT stiff in the
 * "fast but unexcited" sense: the axial fundamental of the soft silicone rod is near 240 rad/s
 * and centrifugal loading excites it, so an L-stable method that damps it (ROS2) lost accuracy
 * (1.3e-2 rad at 0.5 ms, N = 5). Velocity Verlet conserves the elastic energy of those modes, so:
 *     kick 1:  (diag(m) + h/2 C(q_n)) v_half = diag(m) v_n + h/2 (F_el(q_n) + T(v_half) e1)
 *     drift:   q_{n+1} = q_n + h v_half
 *     kick 2:  v_{n+1} = v_half + h/2 diag(m)^-1 (F_el(q_{n+1}) - C(q_{n+1}) v_half + T e1)
 * C(q) = d (Delta W)'(Delta W) + b e1 e1' is the exact damping matrix (edge rates are linear in
 * the velocities, omega = W(q) qd), banded with half-bandwidth 5 (LDL', no square roots); the
 * back-EMF and the driver's current clamp enter kick 1 through a scalar equation solved exactly
 * (Sherman-Morrison). Over two steps the damping sees kick 2 (explicit half) + kick 1 (implicit
 * half): the trapezoidal rule, A-stable and second order, and quasi-static (forced) damped motion
 * is reproduced exactly. With d = b = 0 it is velocity Verlet: symplectic, no energy drift.
 * Stability needs h omega_max < 2 for the undamped frequencies of the elastic part (axial
 * ~1500 rad/s at N = 5, ~6000 rad/s at N = 20); the wrapper takes h = 1 / omega_max.
 * Against Radau: 9e-5 rad (N = 5, h = 0.674 ms), 3e-5 rad (N = 20, h = 0.166 ms).
 *
 * No allocation after rod_plant_new(); no -ffast-math (NaN must reach the caller).
 */
#define _GNU_SOURCE /* sincos */
#include "rod_plant.h"

#include <math.h>
#if !defined(__GLIBC__)
#define sincos(x, s, c) (*(s) = sin(x), *(c) = cos(x))
#endif
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#define ROD_GAMMA 1.7071067811865475244 /* 1 + 1/sqrt(2) */
#define ROD_TWO_PI 6.283185307179586477
#define DER_BAND 5                      /* half-bandwidth of the DER damping matrix */
#define DER_BW (DER_BAND + 1)
#define ROD_MAX_EDGES 1024

typedef struct {
    double *U;    /* 3N: U_k = I^A_k s_k */
    double *invD; /* N: 1 / (s_k' I^A_k s_k + arm_k) */
    double *P;    /* 2(N+1): node positions; joint k sits at node k */
} aba_factor;

struct rod_plant {
    rod_plant_config cfg;
    int N;     /* edges */
    int n;     /* generalized coordinates */
    int nr;    /* the rod's (n without the motor side) */
    int im;    /* index of the motor side theta_m (n - 1) when the gearbox is compliant, else -1 */
    double J_shaft, b_shaft; /* inertia and viscous friction on theta_1 (everything when rigid) */
    double cur;              /* winding current [A]: the state with inductance, else the last step's */
    double gear_c;           /* DER: the gear damping at the prepared q (0 inside the gap) */
    double *kbar;            /* per joint: the discrete curvature 2 tan(phi/2) the spring rests at */
    double t;  /* time [s] */
    double *q; /* coordinates, n */
    double *v; /* rates, n */
    double last_torque, last_current;
    double pending; /* delayed input held by the runner */
    double jit;     /* the runner's current jitter: the plant's time past the control grid [s] */
    uint32_t rng;   /* the runner's jitter draws */
    int prepared;   /* DER: Fc and Cb hold the values at q */
    /* constants */
    double *lv;          /* edge lengths: hub_length, then l [m] */
    double *ksj, *dj;    /* per joint (between edges j and j+1): bending stiffness [N m/rad], damping [N m s/rad] */
    double ext;          /* external torque on the shaft [N m] */
    double *cc;          /* inextensible: node mass beyond edge i [kg]; DER: node masses m_0..m_N */
    double *md;          /* DER mass diagonal */
    /* inextensible workspace */
    double *s, *c, *s2, *c2, *F, *F2, *kj, *ta, *tb, *tc, *td;
    double *k1q, *k1v, *k2q, *k2v, *th2, *w2, *r2, *ta2, *arm, *mn;
    aba_factor fS, fM; /* stage-1 S and stage-2 M factors */
    /* DER workspace */
    double *Fc, *Cb, *Ab, *x, *w, *vh, *X, *E, *ge, *rr, *rl;
    double *tmp; /* 2n scratch for deriv/force */
    /* the IMU (cfg.imu_on) */
    int imu_edge;       /* the edge its centre lies on (0-based) */
    double imu_frac;    /* how far along it [-] */
    int imu_primed;     /* the previous read's kinematics are valid */
    double imu_th, imu_vx, imu_vy; /* at the previous read: edge angle [rad], site velocity [m/s] */
    double imu_bias;    /* the gyro's bias now [rad/s] */
    uint32_t imu_rng;
    float imu_ring[ROD_IMU_MAX_DELAY + 1][3];
    int imu_count;      /* samples made so far */
    float imu_stuck[3];
};

int rod_plant_api_version(void) { return ROD_PLANT_API_VERSION; }

static void imu_reset(rod_plant *p);

/* ------------------------------------------------------------------------------------------ */
/* motor and driver                                                                            */

/* Torque for input u at shaft rate omega; *slope = -dT/domega (the back-EMF damping when the
 * current is not clamped, else 0). Torque mode passes u through. */
static double motor(const rod_plant *p, double u, double omega, double *current, double *slope)
{
    const rod_plant_config *k = &p->cfg;
    if (k->input_mode == ROD_INPUT_TORQUE) {
        *current = u / k->kt_out;
        *slope = 0.0;
        return u;
    }
    double duty = u;
    if (duty > 1.0) duty = 1.0;
    if (duty < -1.0) duty = -1.0;
    double i = (duty * k->supply_voltage - k->ke_out * omega) / k->resistance;
    double sl = k->kt_out * k->ke_out / k->resistance;
    if (i > k->current_limit) {
        i = k->current_limit;
        sl = 0.0;
    } else if (i < -k->current_limit) {
        i = -k->current_limit;
        sl = 0.0;
    }
    *current = i;
    *slope = sl;
    return k->kt_out * i;
}

/* Coulomb friction torque opposing omega, smoothed over coulomb_rate so the integrators see a
 * Lipschitz force instead of a switch: stiction becomes a creep (at 80 % of the breakaway torque
 * the shaft turns at 1.1 coulomb_rate). 5 mN m over 0.01 rad/s is a 0.5 N m s/rad slope, 0.4 ms
 * with the reflected rotor: ROS2 takes the slope into its implicit part; the DER's Verlet steps
 * (< 0.2 ms) and RK4 (the paper's model has no Coulomb friction) resolve it explicitly.
 * *slope = its derivative. */
static inline double coulomb(const rod_plant *p, double omega, double *slope)
{
    const double tc = p->cfg.coulomb;
    if (!(tc > 0.0)) {
        if (slope) *slope = 0.0;
        return 0.0;
    }
    const double th = tanh(omega / p->cfg.coulomb_rate);
    if (slope) *slope = tc * (1.0 - th * th) / p->cfg.coulomb_rate;
    return tc * th;
}

/* The motor's torque over a step of h [s] at the motor rate omega. Without inductance it is motor().
 * With it the current is a state: exact for the RL circuit with omega held over the step, so the
 * torque is the step's mean current times kt (constant over the step; *slope = 0), and the state
 * advances to the step's end. The driver's current regulation clamps both. */
static double motor_step(rod_plant *p, double u, double omega, double h, double *current, double *slope)
{
    const rod_plant_config *k = &p->cfg;
    if (k->input_mode == ROD_INPUT_TORQUE || !(k->inductance > 0.0)) {
        const double T = motor(p, u, omega, current, slope);
        p->cur = *current;
        return T;
    }
    double duty = u;
    if (duty > 1.0) duty = 1.0;
    if (duty < -1.0) duty = -1.0;
    const double iss = (duty * k->supply_voltage - k->ke_out * omega) / k->resistance;
    const double x = h * k->resistance / k->inductance;
    const double e = exp(-x);
    const double frac = x > 1e-8 ? (1.0 - e) / x : 1.0 - 0.5 * x; /* mean of e^(-t) over the step */
    const double lim = k->current_limit;
    double mean = iss + (p->cur - iss) * frac, end = iss + (p->cur - iss) * e;
    mean = mean > lim ? lim : (mean < -lim ? -lim : mean);
    end = end > lim ? lim : (end < -lim ? -lim : end);
    p->cur = end;
    *current = mean;
    *slope = 0.0;
    return k->kt_out * mean;
}

static inline int has_lag(const rod_plant *p)
{
    return p->cfg.input_mode == ROD_INPUT_DUTY && p->cfg.inductance > 0.0;
}

/* The gear train's torque on the shaft [N m] for the motor-minus-shaft angle dm [rad] and rate dw
 * [rad/s]; *k, *c: its stiffness and damping there, both 0 inside the gap. With no backlash the
 * teeth always touch. */
static inline double gear(const rod_plant *p, double dm, double dw, double *k, double *c)
{
    const double half = 0.5 * p->cfg.backlash;
    double x;
    if (!(half > 0.0)) x = dm;
    else if (dm > half) x = dm - half;
    else if (dm < -half) x = dm + half;
    else {
        *k = 0.0;
        *c = 0.0;
        return 0.0;
    }
    *k = p->cfg.gear_stiffness;
    *c = p->cfg.gear_damping;
    return *k * x + *c * dw;
}

static double gear_energy(const rod_plant *p, double dm)
{
    const double half = 0.5 * p->cfg.backlash;
    double x = dm;
    if (half > 0.0) x = dm > half ? dm - half : (dm < -half ? dm + half : 0.0);
    return 0.5 * p->cfg.gear_stiffness * x * x;
}

double rod_plant_motor_torque(const rod_plant *p, double input, double omega, double *current)
{
    double cur, slope;
    double T = motor(p, input, omega, &cur, &slope);
    if (current) *current = cur;
    return T;
}

/* ------------------------------------------------------------------------------------------ */
/* inextensible rod                                                                             */

/* The inner helpers take N as an argument and are always inlined, so rod_step can be
 * instantiated with N a compile-time constant for small rods (loops unrolled). */
#define HOT static inline __attribute__((always_inline))

HOT void trig(const double *th, double *s, double *c, const int N)
{
    for (int i = 0; i < N; i++) sincos(th[i], s + i, c + i);
}

/* F = T e1 - C(theta, w) - V(theta) - D w; kj (optional) = bending Hessian per joint.
 * Coriolis: C_i = m l^2 sum_j c_max(i,j) w_j^2 sin(theta_i - theta_j)
 *              = m l^2 (s_i stair(w^2 c)_i - c_i stair(w^2 s)_i),
 * stair(x)_i = sum_j c_max(i,j) x_j = c_i sum_{j<=i} x_j + sum_{j>i} c_j x_j: O(N). */
HOT void rod_force(rod_plant *p, const int N, const double *s, const double *c, const double *w, double torque,
                   double *F, double *kj)
{
    const double *cc = p->cc, *lv = p->lv, *ksj = p->ksj, *dj = p->dj;
    double *a = p->ta, *b = p->tb, *A = p->tc, *B = p->td;
    double Qa = 0.0, Qb = 0.0;
    for (int i = N - 1; i >= 0; i--) {
        const double w2 = w[i] * w[i] * lv[i];
        a[i] = w2 * c[i];
        b[i] = w2 * s[i];
        A[i] = Qa;
        B[i] = Qb;
        Qa += cc[i] * a[i];
        Qb += cc[i] * b[i];
    }
    const double g = p->cfg.g;
    double Pa = 0.0, Pb = 0.0;
    for (int i = 0; i < N; i++) {
        Pa += a[i];
        Pb += b[i];
        const double Ai = A[i] + cc[i] * Pa, Bi = B[i] + cc[i] * Pb;
        F[i] = -lv[i] * ((s[i] * Ai - c[i] * Bi) + g * cc[i] * s[i]);
    }
    for (int j = 0; j < N - 1; j++) {
        const double cp = c[j + 1] * c[j] + s[j + 1] * s[j]; /* cos(phi_j) */
        const double sp = s[j + 1] * c[j] - c[j + 1] * s[j]; /* sin(phi_j) */
        const double t = sp / (1.0 + cp);                      /* tan(phi_j / 2) */
        const double tt = t * t;
        const double kb = p->kbar[j];
        const double f = ksj[j] * (2.0 * t - kb) * (1.0 + tt) + dj[j] * (w[j + 1] - w[j]);
        F[j] += f;
        F[j + 1] -= f;
        if (kj) kj[j] = ksj[j] * (1.0 + tt) * (1.0 + 3.0 * tt - kb * t);
    }
    /* torque: the motor's (rigid) or the gear train's (compliant); the Coulomb friction sits on the
     * motor side when there is one */
    F[0] += torque - p->b_shaft * w[0] - (p->im < 0 ? coulomb(p, w[0], NULL) : 0.0) + p->ext;
}

/* y = M(theta) x in O(N): M_ij = l_i l_j c_max(i,j) (c_i c_j + s_i s_j) + J [i = j = 1]. */
HOT void rod_mass_mul(rod_plant *p, const int N, const double *s, const double *c, const double *x, double *y)
{
    const double *cc = p->cc, *lv = p->lv;
    double *a = p->ta, *b = p->tb, *A = p->tc, *B = p->td;
    double Qa = 0.0, Qb = 0.0;
    for (int i = N - 1; i >= 0; i--) {
        a[i] = lv[i] * c[i] * x[i];
        b[i] = lv[i] * s[i] * x[i];
        A[i] = Qa;
        B[i] = Qb;
        Qa += cc[i] * a[i];
        Qb += cc[i] * b[i];
    }
    double Pa = 0.0, Pb = 0.0;
    for (int i = 0; i < N; i++) {
        Pa += a[i];
        Pb += b[i];
        y[i] = lv[i] * (c[i] * (A[i] + cc[i] * Pa) + s[i] * (B[i] + cc[i] * Pb));
    }
    y[0] += p->J_shaft * x[0];
}

/* y = K x for the tridiagonal bending Hessian given per joint. */
HOT void joint_mul(const double *kj, const double *x, double *y, const int N)
{
    for (int i = 0; i < N; i++) y[i] = 0.0;
    for (int j = 0; j < N - 1; j++) {
        const double f = kj[j] * (x[j] - x[j + 1]);
        y[j] += f;
        y[j + 1] -= f;
    }
}

/* O(N) solves with M(theta) + diag-in-joint-space terms: the articulated-body algorithm.
 *
 * In joint coordinates phi (theta = L phi, L lower-triangular ones: phi_1 = theta_1,
 * phi_k = theta_k - theta_{k-1}) the damping d Lap, the bending Hessian Delta' diag(k) Delta and
 * the base terms J, b are all diagonal: L' Lap L = diag(0, 1, ..., 1). So
 *     L' (M + gh D + gh^2 K) L = M_phi + diag(arm),
 *     arm_1 = J + gh (b + back-EMF slope),  arm_k = gh d + gh^2 k_{k-1},
 * and M_phi + diag(arm) is the joint-space inertia of a planar chain (point mass m_k at node k,
 * revolute joint k at node k-1) with joint armature arm: Featherstone's articulated-body
 * recursion solves it in O(N) with 3-vectors (omega, v_x, v_y) referred to the axis (world
 * frame, no transforms). S_theta x = r becomes (M_phi + diag(arm)) z = L' r, x = L z. The
 * factor pass (inertias) is shared by every right-hand side. M itself carries J as arm_1. */
HOT void node_positions(const rod_plant *p, const int N, const double *s, const double *c, double *P)
{
    const double *lv = p->lv;
    double x = 0.0, y = 0.0;
    P[0] = P[1] = 0.0;
    for (int k = 0; k < N; k++) {
        x += lv[k] * s[k];
        y -= lv[k] * c[k];
        P[2 * k + 2] = x;
        P[2 * k + 3] = y;
    }
}

/* Factor pass, fused with the backward half of a first solve of x (x may be NULL).
 * Written for a short dependency chain (it is latency-bound for small N): D = s' A s is formed
 * from the carried inertia directly, not from U, and the next body's point mass is added to
 * the carry before the division resolves. */
HOT int aba_factor_pass(const rod_plant *p, const int N, const aba_factor *f, const double *arm, const double *x,
                        double *u)
{
    const double *P = f->P, *mn = p->mn;
    /* articulated inertia of bodies k..N-1 seen at the axis, (omega, vx, vy) order */
    double rx = P[2 * N], ry = P[2 * N + 1], m = mn[N - 1];
    double A00 = m * (rx * rx + ry * ry), A01 = -m * ry, A02 = m * rx, A11 = m, A12 = 0.0, A22 = m;
    double tau = 0.0, p0 = 0.0, p1 = 0.0, p2 = 0.0; /* right-hand side carried likewise */
    for (int k = N - 1; k >= 0; k--) {
        const double sy = P[2 * k + 1], sz = -P[2 * k]; /* s = (1, y_k, -x_k): rotation about node k */
        const double D = (A00 + arm[k]) + (A11 * (sy * sy) + A22 * (sz * sz)) +
                         2.0 * ((A01 * sy + A02 * sz) + A12 * (sy * sz));
        const double U0 = A00 + A01 * sy + A02 * sz;
        const double U1 = A01 + A11 * sy + A12 * sz;
        const double U2 = A02 + A12 * sy + A22 * sz;
        if (!(D > 0.0)) return ROD_ERR_NOT_SPD;
        const double iD = 1.0 / D;
        f->U[3 * k] = U0;
        f->U[3 * k + 1] = U1;
        f->U[3 * k + 2] = U2;
        f->invD[k] = iD;
        if (k > 0) { /* parent: its own point mass plus this body's articulated inertia */
            rx = P[2 * k];
            ry = P[2 * k + 1];
            m = mn[k - 1];
            const double B00 = A00 + m * (rx * rx + ry * ry), B01 = A01 - m * ry, B02 = A02 + m * rx;
            const double B11 = A11 + m, B22 = A22 + m;
            const double Q00 = U0 * U0, Q01 = U0 * U1, Q02 = U0 * U2, Q11 = U1 * U1, Q12 = U1 * U2, Q22 = U2 * U2;
            A00 = B00 - Q00 * iD;
            A01 = B01 - Q01 * iD;
            A02 = B02 - Q02 * iD;
            A11 = B11 - Q11 * iD;
            A12 = A12 - Q12 * iD;
            A22 = B22 - Q22 * iD;
        }
        if (x) {
            tau += x[k]; /* (L' r)_k: suffix sums */
            const double uk = tau - (p0 + sy * p1 + sz * p2);
            u[k] = uk;
            const double g = uk * iD;
            p0 += U0 * g;
            p1 += U1 * g;
            p2 += U2 * g;
        }
    }
    return ROD_OK;
}

/* Forward half: x = L z from the u of a backward half. */
HOT void aba_forward(const int N, const aba_factor *f, double *x, const double *u)
{
    const double *P = f->P, *U = f->U, *iD = f->invD;
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, th = 0.0;
    for (int k = 0; k < N; k++) {
        const double z = (u[k] - (U[3 * k] * a0 + U[3 * k + 1] * a1 + U[3 * k + 2] * a2)) * iD[k];
        const double sy = P[2 * k + 1], sz = -P[2 * k];
        a0 += z;
        a1 += sy * z;
        a2 += sz * z;
        th += z; /* x = L z: prefix sums */
        x[k] = th;
    }
}

/* x <- S_theta^-1 x with S_theta = L^-T (M_phi + diag(arm)) L^-1 factored in f; u is scratch (N). */
HOT void aba_solve(const int N, const aba_factor *f, double *x, double *u)
{
    const double *P = f->P, *U = f->U, *iD = f->invD;
    double tau = 0.0, p0 = 0.0, p1 = 0.0, p2 = 0.0;
    for (int k = N - 1; k >= 0; k--) {
        tau += x[k]; /* (L' r)_k: suffix sums */
        const double sy = P[2 * k + 1], sz = -P[2 * k];
        const double uk = tau - (p0 + sy * p1 + sz * p2);
        u[k] = uk;
        const double g = uk * iD[k];
        p0 += U[3 * k] * g;
        p1 += U[3 * k + 1] * g;
        p2 += U[3 * k + 2] * g;
    }
    aba_forward(N, f, x, u);
}

/* sin/cos of theta + delta from those of theta; polynomials for small delta (error < 1e-18). */
HOT void trig_shift(const double *s, const double *c, const double *th, const double *delta, double *s2,
                    double *c2, const int N)
{
    for (int i = 0; i < N; i++) {
        const double d = delta[i];
        if (fabs(d) < 0.1) {
            const double d2 = d * d;
            const double sd =
                d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0) * (1.0 - d2 * (1.0 / 72.0)))));
            const double cd =
                1.0 - d2 * 0.5 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0) * (1.0 - d2 * (1.0 / 56.0) * (1.0 - d2 * (1.0 / 90.0)))));
            s2[i] = s[i] * cd + c[i] * sd;
            c2[i] = c[i] * cd - s[i] * sd;
        } else {
            s2[i] = sin(th[i] + d);
            c2[i] = cos(th[i] + d);
        }
    }
}

HOT int rod_step_n(rod_plant *p, const int N, double u, double h, double *Tsum, double *Isum)
{
    double *th = p->q, *w = p->v;
    double *s = p->s, *c = p->c, *kj = p->kj, *arm = p->arm;
    const double gh = ROD_GAMMA * h, *dj = p->dj;
    const int m = p->im; /* the motor side (compliant gearbox), else -1 */
    double cur, slope, cslope = 0.0;

    /* stage 1 at y_n: factor S = M + gh D + gh^2 K (joint space). A compliant gearbox adds the motor
     * side's row, coupled to theta_1 alone: it is eliminated (Schur complement) into arm_1 and the
     * right-hand side, and recovered after the rod's solve. */
    trig(th, s, c, N);
    const double T1 = motor_step(p, u, m >= 0 ? w[m] : w[0], h, &cur, &slope);
    double kk = 0.0, ce = 0.0, Fm = 0.0, Tshaft = T1;
    if (m >= 0) {
        Tshaft = gear(p, th[m] - th[0], w[m] - w[0], &kk, &ce);
        Fm = T1 - Tshaft - p->cfg.b * w[m] - coulomb(p, w[m], &cslope);
    }
    rod_force(p, N, s, c, w, Tshaft, p->F, kj);
    node_positions(p, N, s, c, p->fS.P);
    if (m < 0) {
        coulomb(p, w[0], &cslope);
        arm[0] = p->J_shaft + gh * (p->b_shaft + slope + cslope);
    } else {
        arm[0] = p->J_shaft + gh * p->b_shaft;
    }
    for (int k = 1; k < N; k++) arm[k] = gh * dj[k - 1] + gh * gh * kj[k - 1];
    double *k1q = p->k1q, *k1v = p->k1v, *k2q = p->k2q, *k2v = p->k2v, *tmp = p->r2, *us = p->ta2;
    joint_mul(kj, w, tmp, N);
    for (int i = 0; i < N; i++) k1v[i] = p->F[i] - gh * tmp[i];
    double am = 1.0, sc = 0.0;
    if (m >= 0) {
        am = p->cfg.J + gh * (ce + p->cfg.b + slope + cslope) + gh * gh * kk;
        sc = gh * ce + gh * gh * kk;
        arm[0] += sc - sc * sc / am;
        k1v[m] = Fm - gh * kk * (w[m] - w[0]);
        k1v[0] += -gh * kk * (w[0] - w[m]) + sc / am * k1v[m];
    }
    int err = aba_factor_pass(p, N, &p->fS, arm, k1v, us);
    if (err) return err;
    aba_forward(N, &p->fS, k1v, us);
    if (m >= 0) k1v[m] = (k1v[m] + sc * k1v[0]) / am;
    for (int i = 0; i < p->n; i++) k1q[i] = w[i] + gh * k1v[i];

    /* stage 2 at y_n + h k1: acceleration M(theta*)^-1 F(theta*) */
    double *th2 = p->th2, *w2 = p->w2;
    for (int i = 0; i < N; i++) {
        th2[i] = h * k1q[i]; /* increment first, for the trig shift */
        w2[i] = w[i] + h * k1v[i];
    }
    trig_shift(s, c, th, th2, p->s2, p->c2, N);
    for (int i = 0; i < N; i++) th2[i] += th[i];
    double cur2, slope2, a2m = 0.0;
    double *a2 = p->F2;
    if (m >= 0) {
        const double thm = th[m] + h * k1q[m], wm = w[m] + h * k1v[m];
        const double T2 = has_lag(p) ? T1 : motor(p, u, wm, &cur2, &slope2);
        double k2, c2;
        const double Tg = gear(p, thm - th2[0], wm - w2[0], &k2, &c2);
        a2m = (T2 - Tg - p->cfg.b * wm - coulomb(p, wm, NULL)) / p->cfg.J;
        rod_force(p, N, p->s2, p->c2, w2, Tg, a2, NULL);
        k2q[m] = wm - 2.0 * k1q[m];
    } else {
        const double T2 = has_lag(p) ? T1 : motor(p, u, w2[0], &cur2, &slope2);
        rod_force(p, N, p->s2, p->c2, w2, T2, a2, NULL);
    }
    node_positions(p, N, p->s2, p->c2, p->fM.P);
    arm[0] = p->J_shaft;
    for (int k = 1; k < N; k++) arm[k] = 0.0;
    err = aba_factor_pass(p, N, &p->fM, arm, a2, us);
    if (err) return err;
    aba_forward(N, &p->fM, a2, us);
    /* r_theta = w2 - 2 k1q (in k2q), r_w = a2 - 2 k1v (in a2) */
    for (int i = 0; i < N; i++) {
        k2q[i] = w2[i] - 2.0 * k1q[i];
        a2[i] -= 2.0 * k1v[i];
    }
    rod_mass_mul(p, N, s, c, a2, k2v);
    joint_mul(kj, k2q, tmp, N);
    for (int i = 0; i < N; i++) k2v[i] -= gh * tmp[i];
    if (m >= 0) {
        k2v[m] = p->cfg.J * (a2m - 2.0 * k1v[m]) - gh * kk * (k2q[m] - k2q[0]);
        k2v[0] += -gh * kk * (k2q[0] - k2q[m]) + sc / am * k2v[m];
    }
    aba_solve(N, &p->fS, k2v, us);
    if (m >= 0) k2v[m] = (k2v[m] + sc * k2v[0]) / am;
    for (int i = 0; i < p->n; i++) {
        k2q[i] += gh * k2v[i];
        th[i] += h * (1.5 * k1q[i] + 0.5 * k2q[i]);
        w[i] += h * (1.5 * k1v[i] + 0.5 * k2v[i]);
    }
    *Tsum += T1;
    *Isum += cur;
    return ROD_OK;
}

/* Classical RK4 for mildly stiff rods (the wrapper picks it when the whole spectrum fits RK4's
 * stability region at a step near the control period, e.g. Table I at N = 5: fastest mode
 * -537 rad/s, stable to h = 5 ms). Each stage: one O(N) articulated-body solve with M. Tshaft is
 * the torque on theta_1 from the motor (rigid) or the gear train (compliant). */
HOT int rod_accel_n(rod_plant *p, const int N, const double *s, const double *c, const double *w, double Tshaft,
                    double *acc, aba_factor *f)
{
    rod_force(p, N, s, c, w, Tshaft, acc, NULL);
    node_positions(p, N, s, c, f->P);
    double *arm = p->arm;
    arm[0] = p->J_shaft;
    for (int k = 1; k < N; k++) arm[k] = 0.0;
    const int err = aba_factor_pass(p, N, f, arm, acc, p->ta2);
    if (err) return err;
    aba_forward(N, f, acc, p->ta2);
    return ROD_OK;
}

/* One RK4 stage's accelerations at angles (s, c; the motor side at thm), rates w (motor side wm):
 * the rod's in acc[0..N), the motor side's in *am. Tm: the motor torque when it is held over the
 * step (inductance: held), else computed at the stage's rate. */
HOT int rk4_stage(rod_plant *p, const int N, const double *s, const double *c, const double *th, double thm,
                  const double *w, double wm, double u, int held, double Tm, double *acc, double *am, double *T,
                  double *cur)
{
    double slope;
    const int m = p->im;
    if (m < 0) {
        *T = held ? Tm : motor(p, u, w[0], cur, &slope);
        return rod_accel_n(p, N, s, c, w, *T, acc, &p->fM);
    }
    *T = held ? Tm : motor(p, u, wm, cur, &slope);
    double k, cg;
    const double Tg = gear(p, thm - th[0], wm - w[0], &k, &cg);
    *am = (*T - Tg - p->cfg.b * wm - coulomb(p, wm, NULL)) / p->cfg.J;
    return rod_accel_n(p, N, s, c, w, Tg, acc, &p->fM);
}

HOT int rk4_step_n(rod_plant *p, const int N, double u, double h, double *Tsum, double *Isum)
{
    double *th = p->q, *w = p->v, *s = p->s, *c = p->c, *s2 = p->s2, *c2 = p->c2;
    double *a1 = p->k1v, *a2 = p->k2v, *a3 = p->F, *a4 = p->F2, *w2 = p->w2, *dth = p->th2, *wsum = p->k1q;
    double *th2 = p->k2q; /* stage angles (theta_1 for the gear) */
    const int m = p->im;
    double T, cur, T2, cur2, slope;
    const double thm0 = m >= 0 ? th[m] : 0.0, wm0 = m >= 0 ? w[m] : 0.0;
    const int held = has_lag(p); /* the torque is the step's mean current's, not the stage rates' */
    const double Tm = held ? motor_step(p, u, m >= 0 ? wm0 : w[0], h, &cur, &slope) : 0.0;
    double m1 = 0, m2 = 0, m3 = 0, m4 = 0, wm2, wmsum, thm;
    trig(th, s, c, N);
    int err = rk4_stage(p, N, s, c, th, thm0, w, wm0, u, held, Tm, a1, &m1, &T, &cur);
    if (err) return err;
    for (int i = 0; i < N; i++) { /* stage 2 at y + h/2 k1 */
        dth[i] = 0.5 * h * w[i];
        th2[i] = th[i] + dth[i];
        w2[i] = w[i] + 0.5 * h * a1[i];
        wsum[i] = w[i] + 2.0 * w2[i];
    }
    thm = thm0 + 0.5 * h * wm0;
    wm2 = wm0 + 0.5 * h * m1;
    wmsum = wm0 + 2.0 * wm2;
    trig_shift(s, c, th, dth, s2, c2, N);
    err = rk4_stage(p, N, s2, c2, th2, thm, w2, wm2, u, held, Tm, a2, &m2, &T2, &cur2);
    if (err) return err;
    for (int i = 0; i < N; i++) { /* stage 3 at y + h/2 k2 */
        dth[i] = 0.5 * h * w2[i];
        th2[i] = th[i] + dth[i];
        w2[i] = w[i] + 0.5 * h * a2[i];
        wsum[i] += 2.0 * w2[i];
    }
    thm = thm0 + 0.5 * h * wm2;
    wm2 = wm0 + 0.5 * h * m2;
    wmsum += 2.0 * wm2;
    trig_shift(s, c, th, dth, s2, c2, N);
    err = rk4_stage(p, N, s2, c2, th2, thm, w2, wm2, u, held, Tm, a3, &m3, &T2, &cur2);
    if (err) return err;
    for (int i = 0; i < N; i++) { /* stage 4 at y + h k3 */
        dth[i] = h * w2[i];
        th2[i] = th[i] + dth[i];
        w2[i] = w[i] + h * a3[i];
        wsum[i] += w2[i];
    }
    thm = thm0 + h * wm2;
    wm2 = wm0 + h * m3;
    wmsum += wm2;
    trig_shift(s, c, th, dth, s2, c2, N);
    err = rk4_stage(p, N, s2, c2, th2, thm, w2, wm2, u, held, Tm, a4, &m4, &T2, &cur2);
    if (err) return err;
    const double h6 = h / 6.0;
    for (int i = 0; i < N; i++) {
        th[i] += h6 * wsum[i];
        w[i] += h6 * (a1[i] + 2.0 * (a2[i] + a3[i]) + a4[i]);
    }
    if (m >= 0) {
        th[m] += h6 * wmsum;
        w[m] += h6 * (m1 + 2.0 * (m2 + m3) + m4);
    }
    *Tsum += T;
    *Isum += cur;
    return ROD_OK;
}

static int rk4_step(rod_plant *p, double u, double h, double *Tsum, double *Isum)
{
    switch (p->N) { /* compile-time N for small rods: loops unrolled */
    case 2: return rk4_step_n(p, 2, u, h, Tsum, Isum);
    case 3: return rk4_step_n(p, 3, u, h, Tsum, Isum);
    case 4: return rk4_step_n(p, 4, u, h, Tsum, Isum);
    case 5: return rk4_step_n(p, 5, u, h, Tsum, Isum);
    case 6: return rk4_step_n(p, 6, u, h, Tsum, Isum);
    case 8: return rk4_step_n(p, 8, u, h, Tsum, Isum);
    default: return rk4_step_n(p, p->N, u, h, Tsum, Isum);
    }
}

static int rod_step(rod_plant *p, double u, double h, double *Tsum, double *Isum)
{
    switch (p->N) { /* compile-time N for small rods: loops unrolled */
    case 2: return rod_step_n(p, 2, u, h, Tsum, Isum);
    case 3: return rod_step_n(p, 3, u, h, Tsum, Isum);
    case 4: return rod_step_n(p, 4, u, h, Tsum, Isum);
    case 5: return rod_step_n(p, 5, u, h, Tsum, Isum);
    case 6: return rod_step_n(p, 6, u, h, Tsum, Isum);
    case 8: return rod_step_n(p, 8, u, h, Tsum, Isum);
    case 10: return rod_step_n(p, 10, u, h, Tsum, Isum);
    default: return rod_step_n(p, p->N, u, h, Tsum, Isum);
    }
}

/* ------------------------------------------------------------------------------------------ */
/* DER: coordinates q = [phi, x_2, y_2, ..., x_N, y_N]                                          */

static inline int node_index(int k) { return 1 + 2 * (k - 2); } /* k >= 2 */

/* Node positions X (2(N+1)) and edges E (2N, E[2(k-1)] = x_k - x_{k-1}). */
static void der_geometry(const rod_plant *p, const double *q, double *X, double *E)
{
    const int N = p->N;
    const double l0 = p->cfg.hub_length;
    X[0] = 0.0;
    X[1] = 0.0;
    X[2] = l0 * sin(q[0]);
    X[3] = -l0 * cos(q[0]);
    for (int k = 2; k <= N; k++) {
        X[2 * k] = q[node_index(k)];
        X[2 * k + 1] = q[node_index(k) + 1];
    }
    for (int k = 1; k <= N; k++) {
        E[2 * (k - 1)] = X[2 * k] - X[2 * (k - 1)];
        E[2 * (k - 1) + 1] = X[2 * k + 1] - X[2 * (k - 1) + 1];
    }
}

static inline void band_add(double *B, int i, int j, double val)
{
    if (i < j) {
        int t = i;
        i = j;
        j = t;
    }
    B[(size_t)i * DER_BW + (i - j)] += val;
}

/* Elastic + gravity force Fc(q) = -dE/dq and the damping matrix C(q) (band, lower). */
static void der_prepare(rod_plant *p, const double *q, double *Fc, double *Cb)
{
    const int N = p->N, n = p->n;
    const double l = p->cfg.l, EA = p->cfg.EA, g = p->cfg.g, *ksj = p->ksj;
    double *X = p->X, *E = p->E, *ge = p->ge, *rr = p->rr, *rl = p->rl;
    der_geometry(p, q, X, E);
    const double tx = p->cfg.hub_length * cos(q[0]), ty = p->cfg.hub_length * sin(q[0]); /* d x_1 / d phi */
    double *irr = rr;                                    /* 1 / |e|^2 */
    double *ir = rl;                                     /* 1 / |e| */
    for (int k = 0; k < N; k++) {
        const double ex = E[2 * k], ey = E[2 * k + 1];
        const double r = sqrt(ex * ex + ey * ey);
        ir[k] = 1.0 / r;
        irr[k] = ir[k] * ir[k];
        ge[2 * k] = 0.0;
        ge[2 * k + 1] = 0.0;
    }
    for (int k = 1; k < N; k++) { /* stretching of edges 2..N: EA (r/l - 1) t = EA (1/l - 1/r) e */
        const double f = EA * (1.0 / l - ir[k]);
        ge[2 * k] += f * E[2 * k];
        ge[2 * k + 1] += f * E[2 * k + 1];
    }
    for (int j = 0; j < N - 1; j++) { /* bending at the node between edges j and j+1 (0-based) */
        const double ax = E[2 * j], ay = E[2 * j + 1], bx = E[2 * j + 2], by = E[2 * j + 3];
        const double cr = ax * by - ay * bx;
        const double ra = ir[j] / ir[j + 1], rb = ir[j + 1] / ir[j]; /* |b| / |a|, |a| / |b| */
        const double sd = 1.0 / (ir[j] * ir[j + 1]) + ax * bx + ay * by;
        const double isd = 1.0 / sd;
        const double kap = 2.0 * cr * isd;
        const double f = ksj[j] * (kap - p->kbar[j]) * 2.0 * isd * isd;
        const double dsax = ra * ax + bx, dsay = ra * ay + by;
        const double dsbx = rb * bx + ax, dsby = rb * by + ay;
        /* dk/da = 2 (-perp(b) s - c ds/da) / s^2, dk/db = 2 (perp(a) s - c ds/db) / s^2, perp(v) = (-vy, vx) */
        ge[2 * j] += f * (by * sd - cr * dsax);
        ge[2 * j + 1] += f * (-bx * sd - cr * dsay);
        ge[2 * j + 2] += f * (-ay * sd - cr * dsbx);
        ge[2 * j + 3] += f * (ax * sd - cr * dsby);
    }
    /* node gradient gx_k = ge_k - ge_{k+1} + gravity; Fc = -(gradient in q) */
    for (int k = 1; k <= N; k++) {
        double gx = ge[2 * (k - 1)], gy = ge[2 * (k - 1) + 1] + g * p->cc[k];
        if (k < N) {
            gx -= ge[2 * k];
            gy -= ge[2 * k + 1];
        }
        if (k == 1) {
            Fc[0] = -(gx * tx + gy * ty);
        } else {
            Fc[node_index(k)] = -gx;
            Fc[node_index(k) + 1] = -gy;
        }
    }
    /* damping: rows rho_j = d(omega_{j+1} - omega_j)/dqd, C = d sum rho rho' + b e1 e1'.
     * d omega_k / d x_k = perp(e_k) / |e_k|^2 = -d omega_k / d x_{k-1}. */
    memset(Cb, 0, sizeof(double) * (size_t)n * DER_BW);
    Cb[0] = p->b_shaft;
    if (p->im >= 0) { /* the gear train's spring (explicit); its damping couples theta_m (der_step) */
        double k, c;
        const double Tg = gear(p, q[p->im] - q[0], 0.0, &k, &c);
        Fc[0] += Tg;
        Fc[p->im] = -Tg;
        p->gear_c = c;
        Cb[0] += c;
    }
    {
        for (int j = 1; j <= N - 1; j++) { /* 1-based edges j, j+1 meet at node j */
            const double d = p->dj[j - 1];
            if (!(d > 0.0)) continue;
            const double pax = -E[2 * (j - 1) + 1] * irr[j - 1], pay = E[2 * (j - 1)] * irr[j - 1];
            const double pbx = -E[2 * j + 1] * irr[j], pby = E[2 * j] * irr[j];
            /* node j-1: +pa; node j: -(pa + pb); node j+1: +pb */
            const double v[6] = {pax, pay, -(pax + pbx), -(pay + pby), pbx, pby};
            if (j >= 3) { /* nodes j-1..j+1 are free: 6 consecutive coordinates from x_{j-1} */
                double *B0 = Cb + (size_t)node_index(j - 1) * DER_BW;
                for (int a = 0; a < 6; a++) {
                    const double da = d * v[a];
                    for (int b2 = 0; b2 <= a; b2++) B0[a * DER_BW + (a - b2)] += da * v[b2];
                }
                continue;
            }
            int idx[6];
            double val[6];
            int m = 0;
            for (int a = 0; a < 3; a++) {
                const int k = j - 1 + a;
                if (k == 0) continue;
                if (k == 1) {
                    idx[m] = 0;
                    val[m++] = v[2 * a] * tx + v[2 * a + 1] * ty;
                } else {
                    idx[m] = node_index(k);
                    val[m++] = v[2 * a];
                    idx[m] = node_index(k) + 1;
                    val[m++] = v[2 * a + 1];
                }
            }
            for (int a = 0; a < m; a++)
                for (int b2 = a; b2 < m; b2++) band_add(Cb, idx[a], idx[b2], d * val[a] * val[b2]);
        }
    }
}

/* y = C x for the symmetric band matrix (lower storage). */
static void band_mul(const double *B, const double *x, double *y, int n)
{
    for (int i = 0; i < n; i++) y[i] = B[(size_t)i * DER_BW] * x[i];
    for (int i = 1; i < n; i++) {
        const double *Bi = B + (size_t)i * DER_BW;
        const int kmax = i < DER_BAND ? i : DER_BAND;
        for (int k = 1; k <= kmax; k++) {
            const double a = Bi[k];
            y[i] += a * x[i - k];
            y[i - k] += a * x[i];
        }
    }
}

/* In place LDL': B (lower band of an SPD matrix) -> unit lower L in B[i][k] = L[i][i-k], k >= 1,
 * and 1 / D_i in B[i][0]. No square roots; one division per row. */
static int band_ldl(double *B, int n)
{
    double t[DER_BW]; /* t_j = L_ij D_j for the current row */
    for (int i = 0; i < n; i++) {
        double *Bi = B + (size_t)i * DER_BW;
        const int j0 = i - DER_BAND > 0 ? i - DER_BAND : 0;
        double dsum = Bi[0];
        for (int j = j0; j < i; j++) {
            const double *Bj = B + (size_t)j * DER_BW;
            double sum = Bi[i - j];
            for (int k = j0; k < j; k++) sum -= t[k - j0] * Bj[j - k];
            t[j - j0] = sum;
            const double L = sum * Bj[0];
            Bi[i - j] = L;
            dsum -= sum * L;
        }
        if (!(dsum > 0.0)) return ROD_ERR_NOT_SPD;
        Bi[0] = 1.0 / dsum;
    }
    return ROD_OK;
}

/* x <- A^-1 x for A = L D L' from band_ldl. */
static void band_solve(const double *L, double *x, int n)
{
    int i = 0;
    for (; i < n && i < DER_BAND; i++) {
        const double *Li = L + (size_t)i * DER_BW;
        double s = x[i];
        for (int k = 0; k < i; k++) s -= Li[i - k] * x[k];
        x[i] = s;
    }
    for (; i < n; i++) { /* full band: a balanced sum */
        const double *Li = L + (size_t)i * DER_BW;
        x[i] -= ((Li[1] * x[i - 1] + Li[2] * x[i - 2]) + (Li[3] * x[i - 3] + (Li[4] * x[i - 4] + Li[5] * x[i - 5])));
    }
    for (i = 0; i < n; i++) x[i] *= L[(size_t)i * DER_BW];
    for (i = n - 1; i >= 0; i--) {
        if (i + DER_BAND < n) {
            const double *L1 = L + (size_t)(i + 1) * DER_BW;
            x[i] -= ((L1[1] * x[i + 1] + L1[DER_BW + 2] * x[i + 2]) +
                     (L1[2 * DER_BW + 3] * x[i + 3] + (L1[3 * DER_BW + 4] * x[i + 4] + L1[4 * DER_BW + 5] * x[i + 5])));
        } else {
            double s = x[i];
            for (int k = i + 1; k < n; k++) s -= L[(size_t)k * DER_BW + (k - i)] * x[k];
            x[i] = s;
        }
    }
}

/* A x = r for A = diag(m) + hh C with the motor side coupled to phi through the gear damping
 * (compliant): the band part Ab is already factored with the Schur term on its first pivot; x_m
 * comes back from x_0. am: the motor side's diagonal, sc: the coupling (hh c). */
static void der_solve(const rod_plant *p, const double *Ab, double *x, double am, double sc)
{
    const int m = p->im;
    if (m >= 0) x[0] += sc / am * x[m];
    band_solve(Ab, x, p->nr);
    if (m >= 0) x[m] = (x[m] + sc * x[0]) / am;
}

static int der_step(rod_plant *p, double u, double h, double *Tsum, double *Isum)
{
    const int n = p->n, nr = p->nr, m = p->im, e = m >= 0 ? m : 0; /* e: where the motor acts */
    const rod_plant_config *k = &p->cfg;
    double *q = p->q, *v = p->v, *md = p->md, *Fc = p->Fc, *Cb = p->Cb, *Ab = p->Ab, *x = p->x, *vh = p->vh;
    const double hh = 0.5 * h;
    if (!p->prepared) der_prepare(p, q, Fc, Cb);
    p->prepared = 0;
    for (int i = 0; i < nr * DER_BW; i++) Ab[i] = hh * Cb[i];
    for (int i = 0; i < nr; i++) Ab[(size_t)i * DER_BW] += md[i];
    double am = 1.0, sc = 0.0;
    if (m >= 0) {
        am = md[m] + hh * (p->gear_c + k->b);
        sc = hh * p->gear_c;
        Ab[0] -= sc * sc / am;
    }
    int err = band_ldl(Ab, nr);
    if (err) return err;
    for (int i = 0; i < n; i++) x[i] = md[i] * v[i] + hh * Fc[i];
    x[0] += hh * p->ext;
    x[e] -= hh * coulomb(p, v[e], NULL); /* explicit: slow next to the step (see coulomb) */
    double T, cur, slope;
    if (k->input_mode == ROD_INPUT_TORQUE || has_lag(p)) {
        T = motor_step(p, u, v[e], h, &cur, &slope);
        x[e] += hh * T;
        der_solve(p, Ab, x, am, sc);
        for (int i = 0; i < n; i++) vh[i] = x[i];
    } else {
        /* v_half = x + hh T w with x = A^-1 rhs, w = A^-1 e and T = kt sat((V - ke v_half_e) / R):
         * v_half_e rises with T (w_e > 0), so the clamped solution of the scalar equation is the
         * clamp of the unclamped one. */
        double *w = p->w;
        der_solve(p, Ab, x, am, sc);
        for (int i = 0; i < n; i++) w[i] = 0.0;
        w[e] = 1.0;
        der_solve(p, Ab, w, am, sc);
        double duty = u;
        if (duty > 1.0) duty = 1.0;
        if (duty < -1.0) duty = -1.0;
        cur = (duty * k->supply_voltage - k->ke_out * x[e]) / (k->resistance + k->kt_out * k->ke_out * hh * w[e]);
        if (cur > k->current_limit) cur = k->current_limit;
        if (cur < -k->current_limit) cur = -k->current_limit;
        p->cur = cur;
        T = k->kt_out * cur;
        for (int i = 0; i < n; i++) vh[i] = x[i] + hh * T * w[i];
    }
    for (int i = 0; i < n; i++) q[i] += h * vh[i];
    der_prepare(p, q, Fc, Cb);
    p->prepared = 1;
    band_mul(Cb, vh, x, nr);
    for (int i = 0; i < nr; i++) v[i] = vh[i] + hh * (Fc[i] - x[i]) / md[i];
    v[0] += hh * p->ext / md[0];
    if (m >= 0) {
        const double gc = p->gear_c;
        v[0] += hh * gc * vh[m] / md[0]; /* the coupling half of the gear damping on the shaft row */
        v[m] = vh[m] + hh * (Fc[m] - (gc + k->b) * vh[m] + gc * vh[0] + T - coulomb(p, vh[m], NULL)) / md[m];
    } else {
        v[0] += hh * (T - coulomb(p, vh[0], NULL)) / md[0];
    }
    *Tsum += T;
    *Isum += cur;
    return ROD_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* lifecycle                                                                                    */

static int config_ok(const rod_plant_config *k)
{
    if (!k) return 0;
    if (k->kind != ROD_PLANT_INEXTENSIBLE && k->kind != ROD_PLANT_DER) return 0;
    if (k->edges < 2 || k->edges > ROD_MAX_EDGES) return 0;
    if (k->input_mode != ROD_INPUT_TORQUE && k->input_mode != ROD_INPUT_DUTY) return 0;
    if (!(k->l > 0 && k->m > 0 && k->EI > 0 && k->d >= 0 && k->g >= 0 && k->J >= 0 && k->b >= 0)) return 0;
    if (k->kind == ROD_PLANT_DER && !(k->EA > 0 && k->hub_length > 0)) return 0;
    if (!(k->hub_length >= 0 && k->hub_mass >= 0 && k->hub_stiffness > 0 && k->hub_damping >= 0)) return 0;
    if (!(k->hub_length > 0 || k->J > 0)) return 0; /* a massless shaft with no hub: M is singular */
    if (!(k->coulomb >= 0 && (k->coulomb == 0 || k->coulomb_rate > 0))) return 0;
    if (!(k->kt_out > 0 && k->ke_out >= 0 && k->resistance > 0 && k->supply_voltage >= 0 && k->current_limit > 0))
        return 0;
    if (!(k->counts_per_rev > 0 && k->encoder_phase >= 0 && k->encoder_phase < 1)) return 0;
    if (!(k->max_step > 0 && isfinite(k->max_step))) return 0;
    if (k->kind == ROD_PLANT_DER ? k->method != ROD_METHOD_VERLET
                                 : (k->method != ROD_METHOD_ROS2 && k->method != ROD_METHOD_RK4))
        return 0;
    if (!(k->gear_stiffness >= 0 && k->gear_damping >= 0 && k->backlash >= 0 && k->output_inertia >= 0 &&
          k->output_viscous >= 0 && k->inductance >= 0 && isfinite(k->gear_stiffness) && isfinite(k->backlash) &&
          isfinite(k->zero_error) && isfinite(k->rest_curvature)))
        return 0;
    if (k->gear_stiffness > 0 && !(k->J > 0)) return 0; /* the motor side needs its inertia */
    if (k->imu_on && !(k->imu_mass >= 0 && k->imu_position > 0 && k->imu_gyro_sigma >= 0 && k->imu_accel_sigma >= 0
                       && k->imu_bias_step >= 0 && k->imu_gyro_lsb > 0 && k->imu_accel_lsb > 0
                       && isfinite(k->imu_gyro_bias) && isfinite(k->imu_tilt) && k->imu_delay >= 0 && k->imu_delay <= ROD_IMU_MAX_DELAY
                       && k->imu_fault >= 0 && k->imu_fault <= ROD_IMU_FAULT_RANGE))
        return 0;
    if (k->gear_stiffness > 0 && !(k->hub_length > 0 || k->output_inertia > 0)) return 0;
    return 1;
}

rod_plant *rod_plant_new(const rod_plant_config *cfg)
{
    if (!config_ok(cfg)) return NULL;
    const int N = cfg->edges;
    const int compliant = cfg->gear_stiffness > 0.0;
    const int nr = cfg->kind == ROD_PLANT_DER ? 2 * N - 1 : N;
    const int n = nr + compliant;
    /* one block: struct, then doubles */
    size_t nd = 0;
    nd += 2 * (size_t)n;                  /* q, v */
    nd += (size_t)N + 1;                  /* cc */
    nd += (size_t)n;                      /* md */
    nd += 21 * ((size_t)N + 1);           /* inextensible vectors, s .. mn (the motor side's row too) */
    nd += 4 * (size_t)N;                  /* lv, ksj, dj, kbar */
    nd += 2 * (6 * (size_t)N + 2);        /* two ABA factors */
    nd += 2 * (size_t)n * DER_BW;         /* Cb, Ab */
    nd += 4 * (size_t)n;                  /* Fc, x, w, vh */
    nd += 2 * ((size_t)N + 1);            /* X */
    nd += 2 * (size_t)N * 2;              /* E, ge */
    nd += 2 * (size_t)N;                  /* rr, rl */
    nd += 4 * (size_t)n;                  /* tmp */
    rod_plant *p = calloc(1, sizeof(rod_plant) + nd * sizeof(double) + 64);
    if (!p) return NULL;
    double *mem = (double *)(void *)((char *)p + ((sizeof(rod_plant) + 63) / 64) * 64);
#define TAKE(ptr, count) \
    do {                 \
        (ptr) = mem;     \
        mem += (count);  \
    } while (0)
    p->cfg = *cfg;
    p->N = N;
    p->n = n;
    p->nr = nr;
    p->im = compliant ? n - 1 : -1;
    /* rigid: the motor's inertia and friction act on theta_1 with the gearbox's output side */
    p->J_shaft = compliant ? cfg->output_inertia : cfg->J + cfg->output_inertia;
    p->b_shaft = compliant ? cfg->output_viscous : cfg->b + cfg->output_viscous;
    TAKE(p->q, n);
    TAKE(p->v, n);
    TAKE(p->cc, N + 1);
    TAKE(p->md, n);
    TAKE(p->s, N + 1);
    TAKE(p->c, N + 1);
    TAKE(p->s2, N + 1);
    TAKE(p->c2, N + 1);
    TAKE(p->F, N + 1);
    TAKE(p->F2, N + 1);
    TAKE(p->kj, N + 1);
    TAKE(p->ta, N + 1);
    TAKE(p->tb, N + 1);
    TAKE(p->tc, N + 1);
    TAKE(p->td, N + 1);
    TAKE(p->k1q, N + 1);
    TAKE(p->k1v, N + 1);
    TAKE(p->k2q, N + 1);
    TAKE(p->k2v, N + 1);
    TAKE(p->th2, N + 1);
    TAKE(p->w2, N + 1);
    TAKE(p->r2, N + 1);
    TAKE(p->ta2, N + 1);
    TAKE(p->arm, N + 1);
    TAKE(p->mn, N + 1);
    TAKE(p->lv, N);
    TAKE(p->ksj, N);
    TAKE(p->dj, N);
    TAKE(p->kbar, N);
    TAKE(p->fS.U, 3 * (size_t)N);
    TAKE(p->fS.invD, N);
    TAKE(p->fS.P, 2 * (size_t)N + 2);
    TAKE(p->fM.U, 3 * (size_t)N);
    TAKE(p->fM.invD, N);
    TAKE(p->fM.P, 2 * (size_t)N + 2);
    TAKE(p->Cb, (size_t)n * DER_BW);
    TAKE(p->Ab, (size_t)n * DER_BW);
    TAKE(p->Fc, n);
    TAKE(p->x, n);
    TAKE(p->w, n);
    TAKE(p->vh, n);
    TAKE(p->X, 2 * (N + 1));
    TAKE(p->E, 2 * N);
    TAKE(p->ge, 2 * N);
    TAKE(p->rr, N);
    TAKE(p->rl, N);
    TAKE(p->tmp, 4 * n);
#undef TAKE
    /* edge 1 is the hub (lumped: half its mass on the axis, half at its end); edges 2..N are l long */
    for (int i = 0; i < N; i++) {
        p->lv[i] = i == 0 ? cfg->hub_length : cfg->l;
        p->ksj[i] = i == 0 ? cfg->hub_stiffness : cfg->EI / cfg->l;
        p->dj[i] = i == 0 ? cfg->hub_damping : cfg->d;
        /* a rod curved at rest: the joint rests at the turning angle kappa x its Voronoi length,
         * which its stiffness EI / l_v carries */
        p->kbar[i] = i < N - 1 ? 2.0 * tan(0.5 * cfg->rest_curvature * cfg->EI / p->ksj[i]) : 0.0;
    }
    /* the IMU's site: the edge spanning its arc length; its mass split between that edge's nodes */
    double imu_node[2] = {0.0, 0.0};
    p->imu_edge = N - 1;
    p->imu_frac = 1.0;
    if (cfg->imu_on) {
        double s0 = 0.0;
        for (int i = 0; i < N; i++) {
            if (cfg->imu_position <= s0 + p->lv[i] || i == N - 1) {
                p->imu_edge = i;
                p->imu_frac = fmin(fmax((cfg->imu_position - s0) / p->lv[i], 0.0), 1.0);
                break;
            }
            s0 += p->lv[i];
        }
        imu_node[0] = (1.0 - p->imu_frac) * cfg->imu_mass;
        imu_node[1] = p->imu_frac * cfg->imu_mass;
    }
    if (cfg->kind == ROD_PLANT_INEXTENSIBLE) {
        for (int i = 0; i < N; i++) p->mn[i] = cfg->m; /* node i + 1 */
        p->mn[0] = 0.5 * (cfg->hub_mass + cfg->m);
        p->mn[N - 1] = 0.5 * cfg->m;
        if (p->imu_edge >= 1) p->mn[p->imu_edge - 1] += imu_node[0]; /* node 0 is on the axis */
        p->mn[p->imu_edge] += imu_node[1];
        double sum = 0.0;
        for (int i = N - 1; i >= 0; i--) {
            sum += p->mn[i];
            p->cc[i] = sum;
        }
    } else {
        for (int k = 0; k <= N; k++) p->cc[k] = cfg->m;
        p->cc[0] = 0.5 * cfg->hub_mass;
        p->cc[1] = 0.5 * (cfg->hub_mass + cfg->m);
        p->cc[N] = 0.5 * cfg->m;
        p->cc[p->imu_edge] += imu_node[0];
        p->cc[p->imu_edge + 1] += imu_node[1];
        p->md[0] = p->J_shaft + p->cc[1] * cfg->hub_length * cfg->hub_length;
        for (int k = 2; k <= N; k++) p->md[node_index(k)] = p->md[node_index(k) + 1] = p->cc[k];
    }
    for (int i = 0; i < n; i++) p->v[i] = 0.0;
    if (cfg->kind == ROD_PLANT_DER) {
        for (int k = 2; k <= N; k++) {
            p->q[node_index(k)] = 0.0;
            p->q[node_index(k) + 1] = -(cfg->hub_length + (k - 1) * cfg->l);
        }
        p->q[0] = 0.0;
    }
    if (compliant) p->md[p->im] = cfg->J;
    imu_reset(p);
    return p;
}

void rod_plant_free(rod_plant *p) { free(p); }

void rod_plant_set_external_torque(rod_plant *p, double torque) { p->ext = torque; }

int rod_plant_kind(const rod_plant *p) { return p->cfg.kind; }
int rod_plant_edges(const rod_plant *p) { return p->N; }
int rod_plant_size(const rod_plant *p) { return p->n; }
double rod_plant_max_step(const rod_plant *p) { return p->cfg.max_step; }
double rod_plant_time(const rod_plant *p) { return p->t; }
void rod_plant_set_time(rod_plant *p, double t) { p->t = t; }
double rod_plant_last_torque(const rod_plant *p) { return p->last_torque; }
double rod_plant_last_current(const rod_plant *p) { return p->last_current; }

int rod_plant_set_max_step(rod_plant *p, double h)
{
    if (!(h > 0 && isfinite(h))) return ROD_ERR_ARGUMENT;
    p->cfg.max_step = h;
    return ROD_OK;
}

int rod_plant_set_method(rod_plant *p, int method)
{
    rod_plant_config k = p->cfg;
    k.method = method;
    if (!config_ok(&k)) return ROD_ERR_ARGUMENT;
    p->cfg.method = method;
    p->prepared = 0;
    return ROD_OK;
}

int rod_plant_method(const rod_plant *p) { return p->cfg.method; }

int rod_plant_set_encoder_phase(rod_plant *p, double phase)
{
    if (!(phase >= 0 && phase < 1)) return ROD_ERR_ARGUMENT;
    p->cfg.encoder_phase = phase;
    return ROD_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* state                                                                                        */

int rod_plant_set_raw_state(rod_plant *p, const double *q, const double *qd)
{
    p->imu_primed = 0;
    memcpy(p->q, q, sizeof(double) * (size_t)p->n);
    memcpy(p->v, qd, sizeof(double) * (size_t)p->n);
    p->prepared = 0;
    return ROD_OK;
}

void rod_plant_get_raw_state(const rod_plant *p, double *q, double *qd)
{
    if (q) memcpy(q, p->q, sizeof(double) * (size_t)p->n);
    if (qd) memcpy(qd, p->v, sizeof(double) * (size_t)p->n);
}

int rod_plant_set_state(rod_plant *p, const double *theta, const double *dtheta)
{
    p->imu_primed = 0;
    const int N = p->N;
    p->prepared = 0;
    p->cur = 0.0;
    if (p->im >= 0) {
        p->q[p->im] = theta[0];
        p->v[p->im] = dtheta[0];
    }
    if (p->cfg.kind == ROD_PLANT_INEXTENSIBLE) {
        memcpy(p->q, theta, sizeof(double) * (size_t)N);
        memcpy(p->v, dtheta, sizeof(double) * (size_t)N);
        return ROD_OK;
    }
    double x = 0, y = 0, vx = 0, vy = 0;
    for (int k = 1; k <= N; k++) {
        const double s = sin(theta[k - 1]), c = cos(theta[k - 1]), l = p->lv[k - 1];
        x += l * s;
        y -= l * c;
        vx += l * dtheta[k - 1] * c;
        vy += l * dtheta[k - 1] * s;
        if (k >= 2) {
            p->q[node_index(k)] = x;
            p->q[node_index(k) + 1] = y;
            p->v[node_index(k)] = vx;
            p->v[node_index(k) + 1] = vy;
        }
    }
    p->q[0] = theta[0];
    p->v[0] = dtheta[0];
    return ROD_OK;
}

static void state_angles(const rod_plant *p, const double *q, const double *qd, double *theta, double *dtheta)
{
    const int N = p->N;
    if (p->cfg.kind == ROD_PLANT_INEXTENSIBLE) {
        if (theta) memcpy(theta, q, sizeof(double) * (size_t)N);
        if (dtheta) memcpy(dtheta, qd, sizeof(double) * (size_t)N);
        return;
    }
    const double l = p->cfg.hub_length, sp = sin(q[0]), cp = cos(q[0]);
    double px = l * sp, py = -l * cp;              /* node k-1 */
    double pvx = l * qd[0] * cp, pvy = l * qd[0] * sp; /* its velocity */
    double prev = q[0];
    if (theta) theta[0] = q[0];
    if (dtheta) dtheta[0] = qd[0];
    for (int k = 2; k <= N; k++) {
        const int i = node_index(k);
        const double ex = q[i] - px, ey = q[i + 1] - py;
        const double dx = qd[i] - pvx, dy = qd[i + 1] - pvy;
        const double ang = atan2(ex, -ey);
        const double th = prev + remainder(ang - prev, ROD_TWO_PI);
        if (theta) theta[k - 1] = th;
        if (dtheta) dtheta[k - 1] = (ex * dy - ey * dx) / (ex * ex + ey * ey);
        prev = th;
        px = q[i];
        py = q[i + 1];
        pvx = qd[i];
        pvy = qd[i + 1];
    }
}

void rod_plant_get_state(const rod_plant *p, double *theta, double *dtheta)
{
    state_angles(p, p->q, p->v, theta, dtheta);
}

void rod_plant_motor_state(const rod_plant *p, double *theta_m, double *omega_m, double *current)
{
    const int e = p->im >= 0 ? p->im : 0;
    if (theta_m) *theta_m = p->q[e];
    if (omega_m) *omega_m = p->v[e];
    if (current) *current = p->cur;
}

int rod_plant_set_motor_state(rod_plant *p, double theta_m, double omega_m, double current)
{
    if (!(isfinite(theta_m) && isfinite(omega_m) && isfinite(current))) return ROD_ERR_ARGUMENT;
    const int e = p->im >= 0 ? p->im : 0;
    p->q[e] = theta_m;
    p->v[e] = omega_m;
    p->cur = current;
    p->prepared = 0;
    return ROD_OK;
}

double rod_plant_gear_torque(const rod_plant *p)
{
    if (p->im < 0) return 0.0;
    double k, c;
    return gear(p, p->q[p->im] - p->q[0], p->v[p->im] - p->v[0], &k, &c);
}

void rod_plant_nodes(const rod_plant *p, double *xy)
{
    const int N = p->N;
    if (p->cfg.kind == ROD_PLANT_DER) {
        der_geometry(p, p->q, xy, ((rod_plant *)p)->E); /* E is scratch */
        return;
    }
    double x = 0, y = 0;
    xy[0] = xy[1] = 0.0;
    for (int k = 1; k <= N; k++) {
        x += p->lv[k - 1] * sin(p->q[k - 1]);
        y -= p->lv[k - 1] * cos(p->q[k - 1]);
        xy[2 * k] = x;
        xy[2 * k + 1] = y;
    }
}

/* ------------------------------------------------------------------------------------------ */
/* model evaluation (tests, linearization, energy)                                              */

/* The motor torque at rate omega for an evaluation (not a step): with inductance, the current state's. */
static double motor_now(const rod_plant *p, double input, double omega)
{
    double cur, slope;
    if (has_lag(p)) return p->cfg.kt_out * p->cur;
    return motor(p, input, omega, &cur, &slope);
}

int rod_plant_force(rod_plant *p, const double *y, double input, double *F)
{
    const int n = p->n, nr = p->nr, m = p->im;
    const double *q = y, *qd = y + n;
    const double T = motor_now(p, input, qd[m >= 0 ? m : 0]);
    double Tshaft = T, Tg = 0.0;
    if (m >= 0) {
        double k, c;
        Tg = gear(p, q[m] - q[0], qd[m] - qd[0], &k, &c);
        Tshaft = Tg;
        F[m] = T - Tg - p->cfg.b * qd[m] - coulomb(p, qd[m], NULL);
    }
    if (p->cfg.kind == ROD_PLANT_INEXTENSIBLE) {
        double *s = p->s2, *c = p->c2;
        trig(q, s, c, p->N);
        rod_force(p, p->N, s, c, qd, Tshaft, F, NULL);
        return ROD_OK;
    }
    p->prepared = 0;
    der_prepare(p, q, p->Fc, p->Cb);
    band_mul(p->Cb, qd, p->tmp, nr);
    for (int i = 0; i < nr; i++) F[i] = p->Fc[i] - p->tmp[i];
    if (m >= 0) F[0] += p->gear_c * qd[m]; /* Fc and Cb[0] hold the gear's spring and damping diagonal */
    F[0] += p->ext + (m >= 0 ? 0.0 : T - coulomb(p, qd[0], NULL));
    return ROD_OK;
}

int rod_plant_mass(rod_plant *p, const double *y, double *M)
{
    const int n = p->n;
    memset(M, 0, sizeof(double) * (size_t)n * n);
    if (p->cfg.kind == ROD_PLANT_DER) {
        for (int i = 0; i < n; i++) M[(size_t)i * n + i] = p->md[i];
        return ROD_OK;
    }
    const int N = p->N;
    trig(y, p->s2, p->c2, N);
    for (int i = 0; i < N; i++) {
        const double si = p->s2[i] * p->lv[i], ci = p->c2[i] * p->lv[i];
        for (int j = i; j < N; j++) {
            const double v = p->cc[j] * p->lv[j] * (ci * p->c2[j] + si * p->s2[j]);
            M[(size_t)i * n + j] = v;
            M[(size_t)j * n + i] = v;
        }
    }
    M[0] += p->J_shaft;
    if (p->im >= 0) M[(size_t)p->im * n + p->im] = p->cfg.J;
    return ROD_OK;
}

int rod_plant_deriv(rod_plant *p, const double *y, double input, double *dy)
{
    const int n = p->n, N = p->N;
    int err = rod_plant_force(p, y, input, dy + n);
    if (err) return err;
    memcpy(dy, y + n, sizeof(double) * (size_t)n);
    if (p->cfg.kind == ROD_PLANT_DER) {
        for (int i = 0; i < n; i++) dy[n + i] /= p->md[i];
        return ROD_OK;
    }
    if (p->im >= 0) dy[n + p->im] /= p->cfg.J;
    node_positions(p, N, p->s2, p->c2, p->fM.P);
    for (int k = 0; k < N; k++) p->arm[k] = 0.0;
    p->arm[0] = p->J_shaft;
    err = aba_factor_pass(p, N, &p->fM, p->arm, dy + n, p->ta2);
    if (err) return err;
    aba_forward(N, &p->fM, dy + n, p->ta2);
    return ROD_OK;
}

/* The motor side's kinetic energy and the gear train's spring (inextensible rod; 0 when rigid). */
static double drivetrain_energy(const rod_plant *p)
{
    if (p->im < 0) return 0.0;
    const double w = p->v[p->im];
    return 0.5 * p->cfg.J * w * w + gear_energy(p, p->q[p->im] - p->q[0]);
}

double rod_plant_energy(const rod_plant *cp)
{
    rod_plant *p = (rod_plant *)cp; /* uses scratch only */
    const int N = p->N;
    const double *ksj = p->ksj;
    if (p->cfg.kind == ROD_PLANT_INEXTENSIBLE) {
        double *s = p->s2, *c = p->c2, *Mw = p->F2;
        trig(p->q, s, c, N);
        rod_mass_mul(p, N, s, c, p->v, Mw);
        double kin = 0, bend = 0, grav = 0;
        for (int i = 0; i < N; i++) {
            kin += p->v[i] * Mw[i];
            grav -= p->lv[i] * p->cc[i] * c[i];
        }
        for (int j = 0; j < N - 1; j++) {
            const double cp2 = c[j + 1] * c[j] + s[j + 1] * s[j], sp = s[j + 1] * c[j] - c[j + 1] * s[j];
            const double t = sp / (1.0 + cp2);
            bend += ksj[j] * (2.0 * t - p->kbar[j]) * (2.0 * t - p->kbar[j]);
        }
        return 0.5 * kin + 0.5 * bend + p->cfg.g * grav + drivetrain_energy(p);
    }
    const int n = p->n;
    double *X = p->X, *E = p->E;
    der_geometry(p, p->q, X, E);
    double kin = 0, st = 0, bend = 0, grav = 0;
    for (int i = 0; i < n; i++) kin += p->md[i] * p->v[i] * p->v[i];
    for (int k = 1; k < N; k++) {
        const double r = sqrt(E[2 * k] * E[2 * k] + E[2 * k + 1] * E[2 * k + 1]);
        const double e = r / p->cfg.l - 1.0;
        st += e * e;
    }
    for (int j = 0; j < N - 1; j++) {
        const double ax = E[2 * j], ay = E[2 * j + 1], bx = E[2 * j + 2], by = E[2 * j + 3];
        const double kap = 2.0 * (ax * by - ay * bx) /
                           (sqrt(ax * ax + ay * ay) * sqrt(bx * bx + by * by) + ax * bx + ay * by);
        bend += ksj[j] * (kap - p->kbar[j]) * (kap - p->kbar[j]);
    }
    for (int k = 0; k <= N; k++) grav += p->cc[k] * X[2 * k + 1];
    /* the DER's kinetic sum already covers the motor side (md holds its inertia) */
    const double gear_pe = p->im >= 0 ? gear_energy(p, p->q[p->im] - p->q[0]) : 0.0;
    return 0.5 * kin + 0.5 * p->cfg.EA * p->cfg.l * st + 0.5 * bend + p->cfg.g * grav + gear_pe;
}

/* ------------------------------------------------------------------------------------------ */
/* stepping, encoder                                                                            */

int rod_plant_advance(rod_plant *p, double input, double dt)
{
    if (!(dt > 0 && isfinite(dt))) return ROD_ERR_ARGUMENT;
    /* max_step may be exceeded by 1 ppm: a float control period (0.001f = 1.00000005e-3 s) must
     * not double the work */
    double steps = ceil(dt / p->cfg.max_step * (1.0 - 1e-6));
    if (steps < 1) steps = 1;
    if (steps > 1e9) return ROD_ERR_ARGUMENT;
    const long ns = (long)steps;
    const double h = dt / (double)ns;
    double Tsum = 0.0, Isum = 0.0;
    int err = ROD_OK;
    long k = 0;
    const int method = p->cfg.method;
    for (; k < ns && !err; k++) {
        if (method == ROD_METHOD_VERLET) err = der_step(p, input, h, &Tsum, &Isum);
        else if (method == ROD_METHOD_RK4) err = rk4_step(p, input, h, &Tsum, &Isum);
        else err = rod_step(p, input, h, &Tsum, &Isum);
    }
    p->last_torque = Tsum / (double)k;
    p->last_current = Isum / (double)k;
    p->t += dt;
    return err;
}

int32_t rod_plant_encoder_count(const rod_plant *p, double theta1)
{
    const double x = floor((theta1 + p->cfg.zero_error) * (p->cfg.counts_per_rev / ROD_TWO_PI) + p->cfg.encoder_phase);
    if (!isfinite(x)) return INT32_MIN;
    if (x >= 2147483647.0) return INT32_MAX;
    if (x <= -2147483648.0) return INT32_MIN;
    return (int32_t)x;
}

int32_t rod_plant_encoder(const rod_plant *p)
{
    return rod_plant_encoder_count(p, p->q[p->im >= 0 && !p->cfg.encoder_on_shaft ? p->im : 0]);
}

/* ------------------------------------------------------------------------------------------ */
/* the IMU                                                                                      */

/* Angle of the IMU's edge [rad] and its site's velocity [m/s] at the current state. */
static void imu_site(const rod_plant *p, double *th, double *vx, double *vy)
{
    const int j = p->imu_edge;
    const double *q = p->q, *v = p->v;
    double ax = 0, ay = 0, avx = 0, avy = 0; /* node j */
    double bx, by, bvx, bvy;                 /* node j + 1 */
    if (p->cfg.kind == ROD_PLANT_INEXTENSIBLE) {
        for (int i = 0; i < j; i++) {
            const double s = sin(q[i]), c = cos(q[i]);
            ax += p->lv[i] * s;
            ay -= p->lv[i] * c;
            avx += p->lv[i] * v[i] * c;
            avy += p->lv[i] * v[i] * s;
        }
        const double s = sin(q[j]), c = cos(q[j]);
        bx = ax + p->lv[j] * s;
        by = ay - p->lv[j] * c;
        bvx = avx + p->lv[j] * v[j] * c;
        bvy = avy + p->lv[j] * v[j] * s;
    } else {
        const double h = p->cfg.hub_length, s = sin(q[0]), c = cos(q[0]);
#define NODE(k, X, Y, VX, VY)                                                               \
    do {                                                                                    \
        if ((k) == 0) {                                                                     \
            X = Y = VX = VY = 0.0;                                                          \
        } else if ((k) == 1) {                                                              \
            X = h * s, Y = -h * c, VX = h * v[0] * c, VY = h * v[0] * s;                    \
        } else {                                                                            \
            const int ni = node_index(k);                                                   \
            X = q[ni], Y = q[ni + 1], VX = v[ni], VY = v[ni + 1];                           \
        }                                                                                   \
    } while (0)
        NODE(j, ax, ay, avx, avy);
        NODE(j + 1, bx, by, bvx, bvy);
#undef NODE
    }
    *th = atan2(bx - ax, -(by - ay));
    *vx = avx + p->imu_frac * (bvx - avx);
    *vy = avy + p->imu_frac * (bvy - avy);
}

static double imu_uniform(rod_plant *p)
{
    uint32_t r = p->imu_rng;
    r ^= r << 13;
    r ^= r >> 17;
    r ^= r << 5;
    p->imu_rng = r;
    return ((double)r + 0.5) / 4294967296.0;
}

static double imu_normal(rod_plant *p)
{
    const double u1 = imu_uniform(p), u2 = imu_uniform(p);
    return sqrt(-2.0 * log(u1)) * cos(ROD_TWO_PI * u2);
}

static float imu_quantize(double x, double lsb)
{
    double k = nearbyint(x / lsb);
    if (k > 32767.0) k = 32767.0;
    if (k < -32768.0) k = -32768.0;
    return (float)(k * lsb);
}

/* The sample the controller reads at this period's start (period [s]); out = gyro, accel x, y. Returns
 * whether one came. */
static int imu_read(rod_plant *p, double period, double run_time, float out[3])
{
    const rod_plant_config *k = &p->cfg;
    double th, vx, vy;
    imu_site(p, &th, &vx, &vy);
    if (!p->imu_primed) {
        p->imu_th = th, p->imu_vx = vx, p->imu_vy = vy;
        p->imu_primed = 1;
    }
    /* the period's means: the rate from the angle's change, the acceleration from the velocity's */
    const double rate = remainder(th - p->imu_th, ROD_TWO_PI) / period;
    const double fx = (vx - p->imu_vx) / period, fy = (vy - p->imu_vy) / period + k->g;
    const double mid = p->imu_th + 0.5 * remainder(th - p->imu_th, ROD_TWO_PI);
    p->imu_th = th, p->imu_vx = vx, p->imu_vy = vy;
    const double sx = sin(mid + k->imu_tilt), cx = cos(mid + k->imu_tilt);
    p->imu_bias += k->imu_bias_step * imu_normal(p);
    float now[3];
    now[0] = imu_quantize(rate + p->imu_bias + k->imu_gyro_sigma * imu_normal(p), k->imu_gyro_lsb);
    now[1] = imu_quantize(fx * sx - fy * cx + k->imu_accel_sigma * imu_normal(p), k->imu_accel_lsb);
    now[2] = imu_quantize(fx * cx + fy * sx + k->imu_accel_sigma * imu_normal(p), k->imu_accel_lsb);
    const int slot = p->imu_count % (ROD_IMU_MAX_DELAY + 1);
    memcpy(p->imu_ring[slot], now, sizeof now);
    p->imu_count++;
    if (p->imu_count <= k->imu_delay) return 0; /* nothing has come through the pipeline yet */
    const int old = (p->imu_count - 1 - k->imu_delay) % (ROD_IMU_MAX_DELAY + 1);
    memcpy(out, p->imu_ring[old], sizeof(float) * 3);
    if (k->imu_fault != ROD_IMU_FAULT_NONE && run_time >= k->imu_fault_time) {
        if (k->imu_fault == ROD_IMU_FAULT_SILENT) return 0;
        if (k->imu_fault == ROD_IMU_FAULT_STUCK) {
            if (!isnan(p->imu_stuck[0])) memcpy(out, p->imu_stuck, sizeof p->imu_stuck);
            else memcpy(p->imu_stuck, out, sizeof p->imu_stuck);
        } else {
            out[0] = imu_quantize(1e30, k->imu_gyro_lsb);
        }
    }
    return 1;
}

int rod_plant_imu_read(rod_plant *p, double period, float out[3])
{
    if (!p->cfg.imu_on || !(period > 0)) return -1;
    return imu_read(p, period, p->t, out);
}

static void imu_reset(rod_plant *p)
{
    p->imu_primed = 0;
    p->imu_count = 0;
    p->imu_bias = p->cfg.imu_gyro_bias;
    p->imu_rng = p->cfg.imu_seed ? p->cfg.imu_seed : 0x2545F491u;
    p->imu_stuck[0] = p->imu_stuck[1] = p->imu_stuck[2] = NAN;
}

/* ------------------------------------------------------------------------------------------ */
/* closed loop                                                                                  */

int64_t rod_run_closed_loop(rod_plant *p, const rod_sil_api *api, const rod_run_options *opt,
                            const rod_run_log *log, rod_run_result *result)
{
    rod_run_result res = {0, 0, 0, ROD_OK};
    if (!p || !api || !opt || !log) return ROD_ERR_ARGUMENT;
    if (!api->step || !api->status) return ROD_ERR_ABI;
    if (opt->reset && (!api->reset || (opt->arm_mode != 0 && !api->arm))) return ROD_ERR_ABI;
    if (p->cfg.input_mode == ROD_INPUT_DUTY && !api->duty) return ROD_ERR_ABI;
    if (opt->periods < 0 || !(opt->period > 0 && isfinite(opt->period))) return ROD_ERR_ARGUMENT;
    if (opt->est_len < 0 || opt->est_len > ROD_RUN_MAX_EST) return ROD_ERR_ARGUMENT;
    if (opt->delay_periods != 0 && opt->delay_periods != 1) return ROD_ERR_ARGUMENT;
    const int N = p->N, ne = opt->est_len, duty_mode = p->cfg.input_mode == ROD_INPUT_DUTY;
    if (!(opt->jitter >= 0 && opt->jitter < opt->period)) return ROD_ERR_ARGUMENT;
    const double period = opt->period;
    float est[ROD_RUN_MAX_EST];
    if (opt->reset) {
        api->reset();
        p->pending = 0.0;
        p->jit = 0.0;
        p->rng = opt->jitter_seed ? opt->jitter_seed : 0x9E3779B9u;
        imu_reset(p);
        if (opt->arm_mode != 0) api->arm(opt->arm_mode);
    }
    const double t0 = p->t - p->jit; /* the grid: the plant may sit a jitter past it */
    for (int64_t k = 0; k < opt->periods; k++) {
        const int32_t count = rod_plant_encoder(p);
        if (log->time) log->time[k] = t0 + (double)k * period;
        if (log->motor) log->motor[k] = p->q[p->im >= 0 ? p->im : 0];
        state_angles(p, p->q, p->v, log->theta ? log->theta + k * N : NULL, log->dtheta ? log->dtheta + k * N : NULL);
        if (p->cfg.imu_on) {
            float imu[3] = {NAN, NAN, NAN};
            const int fresh = imu_read(p, period, p->t, imu);
            if (api->imu) api->imu(imu[0], imu[1], imu[2], fresh);
            if (log->imu) {
                for (int j = 0; j < 3; j++) log->imu[3 * k + j] = fresh ? imu[j] : NAN;
            }
        }
        const float cmd = api->step(count);
        const float duty = api->duty ? api->duty() : 0.0f;
        for (int j = 0; j < ne; j++) est[j] = NAN;
        const int mode = api->status(est, ne);
        double input = duty_mode ? (double)duty : (double)cmd;
        if (!isfinite(input)) {
            input = 0.0;
            res.nonfinite_commands++;
        }
        double applied = input;
        if (opt->delay_periods) {
            applied = p->pending;
            p->pending = input;
        }
        /* the next read comes a fresh jitter after the next period's start (xorshift32: the same
         * sequence for the same seed on every machine) */
        double next = 0.0;
        if (opt->jitter > 0) {
            uint32_t r = p->rng;
            r ^= r << 13;
            r ^= r >> 17;
            r ^= r << 5;
            p->rng = r;
            next = opt->jitter * ((double)r / 4294967296.0);
        }
        const int err = rod_plant_advance(p, applied, period + next - p->jit);
        p->jit = next;
        p->t = t0 + (double)(k + 1) * period + next;
        if (log->est) memcpy(log->est + k * ne, est, sizeof(float) * (size_t)ne);
        if (log->torque_cmd) log->torque_cmd[k] = cmd;
        if (log->duty) log->duty[k] = duty;
        if (log->torque) log->torque[k] = p->last_torque;
        if (log->current) log->current[k] = p->last_current;
        if (log->mode) log->mode[k] = mode;
        if (log->count) log->count[k] = count;
        res.periods_run = k + 1;
        if (err) {
            res.error = err;
            break;
        }
        if (opt->stop_on_mode >= 0 && mode == opt->stop_on_mode) {
            res.stopped_on_mode = 1;
            break;
        }
    }
    if (result) *result = res;
    return res.error ? res.error : res.periods_run;
}
