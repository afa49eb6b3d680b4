/* rod_observer.c -- the gain tables (their only instantiation) and the estimator step. */
#include "rod_observer.h"

#include <math.h>

/* Full unrolling of the NX-long loops (GCC >= 8 knows the pragma; older compilers just loop). */
#if defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 8
#define UNROLL _Pragma("GCC unroll 64")
#else
#define UNROLL
#endif

/* const: the tables live in flash on the target and cost no RAM. */
static const float Ad[ROD_NX][ROD_NX] = ROD_AD_INIT;
static const float Bd[ROD_NX] = ROD_BD_INIT;
static const float K[ROD_NX] = ROD_K_INIT;
#if ROD_NY == 1
static const float L[ROD_NX] = ROD_L_INIT;
#else
static const float L[ROD_NX][ROD_NY] = ROD_IMU_L_INIT;
static const float LW[ROD_NY] = ROD_IMU_LW_INIT;
static const float LA[ROD_IMU_NA][ROD_NY] = ROD_IMU_LA_INIT;
static const float AZ[ROD_IMU_NA][ROD_NX] = ROD_IMU_AZ_INIT;
static const float AA[ROD_IMU_NA][ROD_IMU_NA] = ROD_IMU_AA_INIT;
static const float BA[ROD_IMU_NA] = ROD_IMU_BA_INIT;
static const float CZ[ROD_NY][ROD_NX] = ROD_IMU_CZ_INIT;
static const float CA[ROD_NY][ROD_IMU_NA] = ROD_IMU_CA_INIT;
static const float DY[ROD_NY] = ROD_IMU_DY_INIT;
#endif

void rod_observer_init(rod_observer_t *o, float y, float rate, float gyro_bias)
{
    for (int i = 0; i < ROD_N; i++) {
        o->z[i] = y;
        o->z[ROD_N + i] = rate;
    }
    o->u_prev = 0.0f;
    o->w = 0.0f;
    o->finite = isfinite(y) && isfinite(rate);
#if ROD_NY > 1
    /* the readings in flight are what this estimate would give: AZ z (no torque yet); the offset 0 */
    for (int i = 0; i < ROD_IMU_NA; i++) {
        float s = 0.0f;
        for (int j = 0; j < ROD_NX; j++) {
            s = fmaf(AZ[i][j], o->z[j], s);
        }
        o->a[i] = s;
    }
    o->a[ROD_OBS_ENCODER_OFFSET] = 0.0f;
    o->a[ROD_OBS_GYRO_BIAS] = gyro_bias;
    o->steps = 0u;
#else
    (void)gyro_bias;
#endif
}

/* Ad z + Bd u with the column loop fully unrolled (NX is a compile-time constant): no loop
 * overhead, and for small N the whole z stays in FPU registers across all rows. fmaf is one
 * VFMA on the M4F, and the same correctly rounded result in the host SIL. */
static inline void predict(const float *z, float u, float *zp)
{
    float zr[ROD_NX];
    UNROLL
    for (int j = 0; j < ROD_NX; j++) {
        zr[j] = z[j];
    }
    for (int i = 0; i < ROD_NX; i++) {
        const float *row = Ad[i];
        float s = Bd[i] * u;
        UNROLL
        for (int j = 0; j < ROD_NX; j++) {
            s = fmaf(row[j], zr[j], s);
        }
        zp[i] = s;
    }
}

/* The torque beside -K z: the disturbance w, and the torque-rate gain on the last net torque
 * (u = -K z - w - ROD_K_TORQUE_PREV (u_prev + w)). */
static inline float w_and_rate_terms(const rod_observer_t *o)
{
    return fmaf(ROD_K_TORQUE_PREV, o->u_prev + o->w, o->w);
}

#if ROD_NY == 1
float rod_observer_step(rod_observer_t *o, const float y[ROD_NY], bool imu_ok)
{
    (void)imu_ok;
    float zp[ROD_NX];
    predict(o->z, o->u_prev + o->w, zp);
    const float innovation = y[0] - zp[0];
    o->w = fmaf(ROD_L_DISTURBANCE, innovation, ROD_W_DECAY * o->w);
    float fb = w_and_rate_terms(o);
    /* x - x is 0 for every finite x and NaN otherwise, so `check` stays 0 exactly while the
     * whole estimate is finite, without a branch per entry. */
    float check = 0.0f;
    UNROLL
    for (int i = 0; i < ROD_NX; i++) {
        float zi = fmaf(L[i], innovation, zp[i]);
        o->z[i] = zi;
        fb = fmaf(K[i], zi, fb);
        check += zi - zi;
    }
    o->finite = (check == 0.0f) && isfinite(o->w);
    return -fb;
}
#else
float rod_observer_step(rod_observer_t *o, const float y[ROD_NY], bool imu_ok)
{
    const float ue = o->u_prev + o->w;
    float zp[ROD_NX], ap[ROD_IMU_NA], e[ROD_NY];
    predict(o->z, ue, zp);
    for (int i = 0; i < ROD_IMU_NA; i++) {
        float s = BA[i] * ue;
        for (int j = 0; j < ROD_NX; j++) {
            s = fmaf(AZ[i][j], o->z[j], s);
        }
        for (int j = 0; j < ROD_IMU_NA; j++) {
            s = fmaf(AA[i][j], o->a[j], s);
        }
        ap[i] = s;
    }
    const float wp = ROD_W_DECAY * o->w;
    for (int r = 0; r < ROD_NY; r++) {
        float s = DY[r] * (o->u_prev + wp);
        for (int j = 0; j < ROD_NX; j++) {
            s = fmaf(CZ[r][j], zp[j], s);
        }
        for (int j = 0; j < ROD_IMU_NA; j++) {
            s = fmaf(CA[r][j], ap[j], s);
        }
        /* a bad IMU sample corrects nothing: the prediction carries the IMU's states */
        e[r] = (r == 0 || imu_ok) ? y[r] - s : 0.0f;
    }
    float w = wp;
    for (int r = 0; r < ROD_NY; r++) {
        w = fmaf(LW[r], e[r], w);
    }
    o->w = w;
    float fb = w; /* no torque-rate term: lqr.r_torque_rate is refused with the IMU (params.py) */
    float check = 0.0f;
    for (int i = 0; i < ROD_NX; i++) {
        float zi = zp[i];
        for (int r = 0; r < ROD_NY; r++) {
            zi = fmaf(L[i][r], e[r], zi);
        }
        o->z[i] = zi;
        fb = fmaf(K[i], zi, fb);
        check += zi - zi;
    }
    for (int i = 0; i < ROD_IMU_NA; i++) {
        float ai = ap[i];
        for (int r = 0; r < ROD_NY; r++) {
            ai = fmaf(LA[i][r], e[r], ai);
        }
        o->a[i] = ai;
        check += ai - ai;
    }
    o->finite = (check == 0.0f) && isfinite(o->w);
    /* An upright rod needs no torque, so the motor would sit in the gearbox's gap and cross it at every
     * change of sign, and the estimate loses the base at each crossing. Held leaning by a small steady
     * torque, gravity keeps one flank loaded; the IMU sees the lean, so it is exact (docs/sensors.md). */
    if (o->steps < ROD_IMU_FLANK_RAMP_STEPS) {
        o->steps++;
    }
    return -fb + (float)o->steps * (ROD_IMU_FLANK_FF_NM / (float)ROD_IMU_FLANK_RAMP_STEPS);
}
#endif

float rod_observer_feedback(const rod_observer_t *o)
{
    float fb = w_and_rate_terms(o);
    for (int i = 0; i < ROD_NX; i++) {
        fb = fmaf(K[i], o->z[i], fb);
    }
    return -fb;
}

void rod_observer_hold(rod_observer_t *o, float u_applied)
{
    o->u_prev = u_applied;
}
