/* Stand-in controller with the firmware SIL ABI (version 1), for the simulator's tests only.
 *
 * Not the firmware: a PD on the measured base angle plus the paper's swing kick (eq. 22), with the
 * mode codes of docs/architecture.md. Everything is float, like the firmware. The rate is a
 * first-order filtered difference of the encoder angle.
 *   DISARMED 0: torque 0.  SWING_UP 2: u = SWING sign(rate) while |theta_1| < SWING_ANGLE, then
 *   BALANCE 1 inside CATCH of upright.  CATCH 4: wait for CATCH.  BALANCE 1: u = -KP e - KD rate,
 *   FAULT 3 beyond LIMIT (latched, torque 0).  |u| <= TMAX.  duty = u / TMAX.
 * Test hooks (not part of the ABI): standin_set_nan(k) makes step k (0-based) return NaN.
 */
#include <math.h>
#include <stdint.h>

#ifndef STANDIN_EDGES
#define STANDIN_EDGES 5
#endif
#define PERIOD 0.001f
#define RAD_PER_COUNT (6.2831853071795864f * 5.0f / 4896.0f) /* 2 pi / 979.2 */
#define PI_F 3.14159265358979f
#define SWING 0.05f
#define SWING_ANGLE 0.5235988f /* 30 deg */
#define CATCH 0.5235988f
#define LIMIT 1.0471976f       /* 60 deg */
#define KP 0.5f
#define KD 0.05f
#define TMAX 0.2f
#define ALPHA 0.2f

static int mode_, first_, nan_at_ = -1;
static long steps_;
static float angle_, rate_, duty_;

int rod_sil_abi_version(void) { return 1; }

void rod_sil_reset(void)
{
    mode_ = 0;
    first_ = 1;
    steps_ = 0;
    angle_ = rate_ = duty_ = 0.0f;
}

float rod_sil_period(void) { return PERIOD; }
int rod_sil_edges(void) { return STANDIN_EDGES; }

void rod_sil_arm(int mode)
{
    if (mode_ == 3) return;
    if (mode == 0) mode_ = 0;
    else if (mode == 1) mode_ = 4;
    else if (mode == 2) mode_ = 2;
}

void standin_set_nan(int k) { nan_at_ = k; }

static float wrap_pi(float x) /* to [-pi, pi) */
{
    return x - 2.0f * PI_F * floorf((x + PI_F) / (2.0f * PI_F));
}

float rod_sil_step(int32_t count)
{
    const float a = (float)count * RAD_PER_COUNT;
    if (first_) {
        angle_ = a;
        first_ = 0;
    }
    rate_ += ALPHA * ((a - angle_) / PERIOD - rate_);
    angle_ = a;
    const float e = wrap_pi(a - PI_F);   /* from upright */
    float u = 0.0f;
    if ((mode_ == 2 || mode_ == 4) && fabsf(e) < CATCH) mode_ = 1;
    if (mode_ == 2 && fabsf(wrap_pi(a)) < SWING_ANGLE) u = rate_ >= 0.0f ? SWING : -SWING;
    if (mode_ == 1) {
        if (fabsf(e) > LIMIT) mode_ = 3;
        else u = -KP * e - KD * rate_;
    }
    if (u > TMAX) u = TMAX;
    if (u < -TMAX) u = -TMAX;
    if (steps_++ == nan_at_) u = NAN;
    duty_ = u / TMAX;
    return u;
}

int rod_sil_status(float *est, int cap)
{
    for (int i = 0; i < cap; i++) est[i] = i < STANDIN_EDGES ? angle_ : rate_;
    return mode_;
}

float rod_sil_duty(void) { return duty_; }
