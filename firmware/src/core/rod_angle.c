/* rod_angle.c -- exact count-to-angle reduction and the base-rate tracking filter. */
#include "rod_angle.h"

#define NUM ROD_COUNTS_PER_REV_NUM
#define DEN ROD_COUNTS_PER_REV_DEN

/* Beyond this many turns apart the exact tick difference would not fit int32; the balance
 * checks trip long before (the angle limit is under half a turn). */
#define MAX_TURN_DIFF 1000

void rod_angle_from_count(int32_t count, rod_angle_t *out)
{
    /* count = a NUM + b with 0 <= b < NUM (floor division), so count DEN / NUM splits
     * into a DEN whole turns plus b DEN / NUM, and b DEN never overflows. */
    int32_t a = count / NUM;
    int32_t b = count % NUM;
    if (b < 0) {
        b += NUM;
        a -= 1;
    }
    int32_t bd = b * DEN;
    out->turn = a * DEN + bd / NUM;
    out->phase = 2 * (bd % NUM);

    int32_t up = out->phase - NUM;                                         /* [-NUM, NUM) */
    int32_t down = out->phase < NUM ? out->phase : out->phase - 2 * NUM;   /* [-NUM, NUM) */
    out->from_upright = (float)up * ROD_RAD_PER_TICK;
    out->from_bottom = (float)down * ROD_RAD_PER_TICK;
    out->theta = (float)out->turn * ROD_TWO_PI_F + (float)out->phase * ROD_RAD_PER_TICK;
}

float rod_angle_from_upright_of(const rod_angle_t *a, int32_t turn)
{
    int32_t d = a->turn - turn;
    if (d > MAX_TURN_DIFF) {
        d = MAX_TURN_DIFF;
    } else if (d < -MAX_TURN_DIFF) {
        d = -MAX_TURN_DIFF;
    }
    int32_t ticks = d * ROD_TICKS_PER_REV + (a->phase - NUM);
    return (float)ticks * ROD_RAD_PER_TICK;
}

float rod_angle_upright(int32_t turn)
{
    return ROD_PI_F + (float)turn * ROD_TWO_PI_F;
}

void rod_rate_filter_init(rod_rate_filter_t *f, int32_t count)
{
    f->ref_count = count;
    f->pos = 0.0f;
    f->rate = 0.0f;
}

float rod_rate_filter_step(rod_rate_filter_t *f, int32_t count)
{
    /* Unsigned subtraction: defined across int32 wrap of the extended hardware counter. */
    int32_t moved = (int32_t)((uint32_t)count - (uint32_t)f->ref_count);
    float err = (float)moved * ROD_RAD_PER_COUNT - f->pos;
    float pos = f->pos + ROD_DT_S * f->rate + ROD_RATE_FILTER_K1 * err;
    f->rate += ROD_RATE_FILTER_K2 * err;
    /* Re-reference to the new count so pos stays a small number. */
    f->ref_count = count;
    f->pos = pos - (float)moved * ROD_RAD_PER_COUNT;
    return f->rate;
}
