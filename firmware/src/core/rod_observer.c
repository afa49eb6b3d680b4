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
static const float L[ROD_NX] = ROD_L_INIT;

void rod_observer_init(rod_observer_t *o, float y, float rate)
{
    for (int i = 0; i < ROD_N; i++) {
        o->z[i] = y;
        o->z[ROD_N + i] = rate;
    }
    o->u_prev = 0.0f;
    o->w = 0.0f;
    o->finite = isfinite(y) && isfinite(rate);
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

float rod_observer_step(rod_observer_t *o, float y)
{
    float zp[ROD_NX];
    predict(o->z, o->u_prev + o->w, zp);
    const float innovation = y - zp[0];
    o->w = fmaf(ROD_L_DISTURBANCE, innovation, ROD_W_DECAY * o->w);
    float fb = o->w;
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

float rod_observer_feedback(const rod_observer_t *o)
{
    float fb = o->w;
    for (int i = 0; i < ROD_NX; i++) {
        fb = fmaf(K[i], o->z[i], fb);
    }
    return -fb;
}

void rod_observer_hold(rod_observer_t *o, float u_applied)
{
    o->u_prev = u_applied;
}
