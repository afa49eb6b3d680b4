/* rod_swingup.c -- energy pumping (eq. (22) generalized) plus the kick that starts it from rest. */
#include "rod_swingup.h"

#include <math.h>

#include "rod_config.h"

void rod_swingup_init(rod_swingup_t *s)
{
    s->rate_lp = 0.0f;
    s->peak = 0.0f;
    s->last_peak = -1.0f;
    s->side = 0.0f;
    s->target = ROD_SWING_ENERGY_TARGET;
    s->gain = 1.0f;
    s->stalls = 0;
}

/* The half-swing ends where the rod crosses the bottom, fast, so encoder steps cannot fake it;
 * swings within the rest angle are the kick's and are not compared. */
static void watch_stall(rod_swingup_t *s, float from_bottom)
{
    float off = fabsf(from_bottom);
    if (off > s->peak) {
        s->peak = off;
    }
    float side = from_bottom > 0.0f ? 1.0f : (from_bottom < 0.0f ? -1.0f : s->side);
    if (side == s->side || s->side == 0.0f) {
        s->side = side;
        return;
    }
    s->side = side;
    if (s->peak <= ROD_SWING_REST_ANGLE_RAD) {
        s->peak = off;
        return;
    }
    if (s->last_peak >= 0.0f && s->stalls < ROD_SWING_STALL_STEPS
        && s->peak - s->last_peak <= ROD_SWING_STALL_RISE_RAD) {
        s->stalls++;
        s->target += ROD_SWING_STALL_TARGET_STEP;
        s->gain *= ROD_SWING_STALL_GAIN;
        if (s->gain > ROD_SWING_STALL_GAIN_MAX) {
            s->gain = ROD_SWING_STALL_GAIN_MAX;
        }
    }
    s->last_peak = s->peak;
    s->peak = off;
}

float rod_swingup_energy(float from_bottom, float rate)
{
    const float v = rate * (1.0f / ROD_SWING_OMEGA0_RAD_S);
    return 0.5f * v * v + (1.0f - cosf(from_bottom));
}

float rod_swingup_torque(rod_swingup_t *s, float amplitude, float swing_angle, float from_bottom, float rate)
{
    /* The base rate carries the bending modes (the shaft is their node); pumping on their sign
     * feeds them instead of the pendulum. The low-pass keeps the pendulum's swing (~1.4 Hz). */
    s->rate_lp += ROD_SWING_RATE_LP_K * (rate - s->rate_lp);
    const float w = s->rate_lp;
    watch_stall(s, from_bottom);
    amplitude *= s->gain;
    float off = fabsf(from_bottom);
    if (!(off < swing_angle)) {
        return 0.0f;
    }
    if (fabsf(rate) <= ROD_SWING_REST_RATE_RAD_S && off <= ROD_SWING_REST_ANGLE_RAD) {
        return amplitude;
    }
    float gain = (s->target - rod_swingup_energy(from_bottom, w)) * (1.0f / ROD_SWING_ENERGY_BAND);
    if (gain > 1.0f) {
        gain = 1.0f;
    } else if (gain < -1.0f) {
        gain = -1.0f;
    }
    if (w > 0.0f) {
        return amplitude * gain;
    }
    if (w < 0.0f) {
        return -amplitude * gain;
    }
    return 0.0f;
}
