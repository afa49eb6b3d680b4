/* rod_runaway.c -- the torque-against-acceleration correlation of rod_runaway.h. */
#include "rod_runaway.h"

#include <math.h>

#define STEPS_OF(s) ((uint32_t)((s) / ROD_DT_S + 0.5f))

void rod_runaway_start(rod_runaway_t *r, float rate)
{
    *r = (rod_runaway_t){0};
    r->rate_start = rate;
}

bool rod_runaway_step(rod_runaway_t *r, float torque, float rate)
{
    const uint32_t window = STEPS_OF(ROD_RUNAWAY_WINDOW_S);
    const uint32_t block = STEPS_OF(ROD_RUNAWAY_BLOCK_S) < 2u ? 2u : STEPS_OF(ROD_RUNAWAY_BLOCK_S);
    uint32_t lag = STEPS_OF(ROD_RUNAWAY_LAG_S);
    if (lag >= ROD_RUNAWAY_LAG_MAX) {
        lag = ROD_RUNAWAY_LAG_MAX - 1u;
    }
    if (r->steps >= window) {
        return false;
    }
    r->steps++;

    /* the torque of `lag` periods ago acts on the rate seen now */
    r->lag[r->lag_head] = torque;
    uint32_t tail = (r->lag_head + ROD_RUNAWAY_LAG_MAX - lag) % ROD_RUNAWAY_LAG_MAX;
    float delayed = r->steps > lag ? r->lag[tail] : 0.0f;
    r->lag_head = (r->lag_head + 1u) % ROD_RUNAWAY_LAG_MAX;

    r->impulse += delayed * ROD_DT_S;
    if (++r->in_block < block) {
        return false;
    }
    float dw = rate - r->rate_start;
    r->s_uw += r->impulse * dw;
    r->s_uu += r->impulse * r->impulse;
    r->s_ww += dw * dw;
    if (fabsf(r->impulse) >= ROD_RUNAWAY_MIN_IMPULSE) {
        r->blocks++;
    }
    r->in_block = 0;
    r->impulse = 0.0f;
    r->rate_start = rate;

    if (r->blocks < ROD_RUNAWAY_MIN_BLOCKS || !(r->s_ww > 0.0f)) {
        return false;
    }
    return r->s_uw < -ROD_RUNAWAY_CORRELATION * sqrtf(r->s_uu * r->s_ww);
}
