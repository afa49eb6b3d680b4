/* rod_trim.c -- the balance set-point that makes the steady holding torque small (rod_trim.h). */
#include "rod_trim.h"

#include <math.h>

void rod_trim_init(rod_trim_t *t)
{
    t->trim = ROD_TRIM_START_RAD;
    t->hold = 0.0f;
}

void rod_trim_catch(rod_trim_t *t)
{
    t->hold = 0.0f;
    if (!isfinite(t->trim)) {
        t->trim = ROD_TRIM_START_RAD;
    }
}

float rod_trim_update(rod_trim_t *t, float torque, bool quasi_static)
{
    t->hold = fmaf(ROD_TRIM_HOLD_K, torque - t->hold, t->hold);
    if (quasi_static) {
        float excess = 0.0f;
        const float off = t->hold - ROD_TRIM_TARGET_NM;
        if (off > ROD_TRIM_BAND_NM) {
            excess = off - ROD_TRIM_BAND_NM;
        } else if (off < -ROD_TRIM_BAND_NM) {
            excess = off + ROD_TRIM_BAND_NM;
        }
        float trim = fmaf(ROD_TRIM_RATE, excess, t->trim);
        if (trim > ROD_TRIM_START_RAD + ROD_TRIM_MAX_RAD) {
            trim = ROD_TRIM_START_RAD + ROD_TRIM_MAX_RAD;
        } else if (trim < ROD_TRIM_START_RAD - ROD_TRIM_MAX_RAD) {
            trim = ROD_TRIM_START_RAD - ROD_TRIM_MAX_RAD;
        }
        t->trim = trim;
    }
    return t->trim;
}
