/* rod_angle.c -- exact count-to-angle reduction and the base-rate tracking filter. */
#include "rod_angle.h"

#include <math.h>

/* Beyond this many turns apart the exact tick difference would not fit int32; the balance
 * checks trip long before (the angle limit is under half a turn). */
#define MAX_TURN_DIFF 1000

/* A wanted fraction this close (count/turn) is taken as exact: a float holds 979.2 to 3e-5. */
#define COUNTS_EXACT 1e-4f

bool rod_counts_make(int32_t num, int32_t den, rod_counts_t *out)
{
    if (num < ROD_COUNTS_NUM_MIN || num > ROD_COUNTS_NUM_MAX || den < 1 || den > ROD_COUNTS_DEN_MAX
        || num > ROD_COUNTS_PRODUCT_MAX / den || num < ROD_COUNTS_PER_TURN_MIN * den) {
        return false;
    }
    out->num = num;
    out->den = den;
    out->rad_per_tick = ROD_PI_F / (float)num;
    out->rad_per_count = ROD_TWO_PI_F * (float)den / (float)num;
    return true;
}

bool rod_counts_from_value(float value, rod_counts_t *out)
{
    if (!(value >= (float)ROD_COUNTS_NUM_MIN && value <= (float)ROD_COUNTS_NUM_MAX)) {
        return false;
    }
    /* The continued fraction's convergents p / q, the first within COUNTS_EXACT: a few steps (a SET may be
     * handled inside the control interrupt, so no search over every denominator). */
    int32_t p0 = 1, q0 = 0;          /* convergent k - 2 ... */
    int32_t p1 = (int32_t)value, q1 = 1; /* ... and k - 1 */
    float rest = value - (float)p1;
    for (int k = 0; k < 32; k++) {
        float scaled = value * (float)q1;
        /* per turn, with the float product's own rounding (about 6e-8 of it) allowed for */
        if (fabsf(scaled - (float)p1) <= (COUNTS_EXACT + 6e-8f * value) * (float)q1 || !(rest > 1e-6f)) {
            break;
        }
        float inv = 1.0f / rest;
        int32_t a = (int32_t)inv;
        rest = inv - (float)a;
        int64_t p2 = (int64_t)a * p1 + p0;
        int64_t q2 = (int64_t)a * q1 + q0;
        if (q2 > ROD_COUNTS_DEN_MAX || p2 > ROD_COUNTS_NUM_MAX || p2 * q2 > ROD_COUNTS_PRODUCT_MAX) {
            break; /* the last convergent that fits is the closest the limits allow */
        }
        p0 = p1;
        q0 = q1;
        p1 = (int32_t)p2;
        q1 = (int32_t)q2;
    }
    return rod_counts_make(p1, q1, out);
}

rod_counts_t rod_counts_default(void)
{
    rod_counts_t c;
    (void)rod_counts_make(ROD_COUNTS_PER_REV_NUM, ROD_COUNTS_PER_REV_DEN, &c);
    return c;
}

void rod_angle_from_count(int32_t count, const rod_counts_t *counts, rod_angle_t *out)
{
    const int32_t NUM = counts->num;
    const int32_t DEN = counts->den;
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
    out->half_turn = NUM;
    out->rad_per_tick = counts->rad_per_tick;

    int32_t up = out->phase - NUM;                                         /* [-NUM, NUM) */
    int32_t down = out->phase < NUM ? out->phase : out->phase - 2 * NUM;   /* [-NUM, NUM) */
    out->from_upright = (float)up * counts->rad_per_tick;
    out->from_bottom = (float)down * counts->rad_per_tick;
    out->theta = (float)out->turn * ROD_TWO_PI_F + (float)out->phase * counts->rad_per_tick;
}

float rod_angle_from_upright_of(const rod_angle_t *a, int32_t turn)
{
    int32_t d = a->turn - turn;
    if (d > MAX_TURN_DIFF) {
        d = MAX_TURN_DIFF;
    } else if (d < -MAX_TURN_DIFF) {
        d = -MAX_TURN_DIFF;
    }
    int32_t ticks = d * 2 * a->half_turn + (a->phase - a->half_turn);
    return (float)ticks * a->rad_per_tick;
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

float rod_rate_filter_step(rod_rate_filter_t *f, int32_t count, float rad_per_count)
{
    /* Unsigned subtraction: defined across int32 wrap of the extended hardware counter. */
    int32_t moved = (int32_t)((uint32_t)count - (uint32_t)f->ref_count);
    float err = (float)moved * rad_per_count - f->pos;
    float pos = f->pos + ROD_DT_S * f->rate + ROD_RATE_FILTER_K1 * err;
    f->rate += ROD_RATE_FILTER_K2 * err;
    /* Re-reference to the new count so pos stays a small number. */
    f->ref_count = count;
    f->pos = pos - (float)moved * rad_per_count;
    return f->rate;
}
