/* rod_swingup.c -- eq. (22) plus the kick that starts it from rest. */
#include "rod_swingup.h"

#include <math.h>

#include "rod_config.h"

float rod_swingup_torque(float amplitude, float swing_angle, float from_bottom, float rate)
{
    float off = fabsf(from_bottom);
    if (!(off < swing_angle)) {
        return 0.0f;
    }
    if (fabsf(rate) <= ROD_SWING_REST_RATE_RAD_S && off <= ROD_SWING_REST_ANGLE_RAD) {
        return amplitude;
    }
    if (rate > 0.0f) {
        return amplitude;
    }
    if (rate < 0.0f) {
        return -amplitude;
    }
    return 0.0f;
}
