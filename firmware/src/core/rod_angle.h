/* rod_angle.h -- encoder count to base angle theta_1, and the base-rate tracking filter.
 *
 * The count is reduced to (turn, phase) with integer arithmetic on the exact fraction
 * counts/turn = num / den (rod_counts_t), in ticks of 1/(2 den) count, so hanging (0), upright
 * (489.6 counts) and every later turn land on exact ticks: the distance to upright is never off
 * by a rounded half count, however many turns were made. The fraction is a run-time setting
 * (SET COUNTS_PER_REV, kept with the rig's signs) whose default is the header's
 * ROD_COUNTS_PER_REV_NUM / ROD_COUNTS_PER_REV_DEN.
 */
#ifndef ROD_ANGLE_H
#define ROD_ANGLE_H

#include <stdbool.h>
#include <stdint.h>

#include "rod_config.h" /* and rod_protocol_defs.h: ROD_PARAM_COUNTS_PER_REV_MIN */

#ifdef __cplusplus
extern "C" {
#endif

/* Limits that keep every tick product inside int32, with room for ROD_ANGLE_MAX_TURN_DIFF turns. */
#define ROD_COUNTS_NUM_MIN 2
#define ROD_COUNTS_NUM_MAX 1000000
#define ROD_COUNTS_DEN_MAX 1000
#define ROD_COUNTS_PRODUCT_MAX 10000000
/* The fewest counts per turn SET accepts (rodlink.toml COUNTS_PER_REV min): a stored record may not load
 * what SET refuses, and with num >= 16 den the whole turns (count / num) times den stay below |count| / 16. */
#define ROD_COUNTS_PER_TURN_MIN ((int32_t)ROD_PARAM_COUNTS_PER_REV_MIN)

/* Encoder counts per output turn, num / den exactly; one turn is 2 num ticks. */
typedef struct {
    int32_t num;
    int32_t den;
    float rad_per_tick;  /* pi / num [rad] */
    float rad_per_count; /* 2 pi den / num [rad] */
} rod_counts_t;

/* num / den within the limits above -> *out (true); false and *out untouched otherwise. */
bool rod_counts_make(int32_t num, int32_t den, rod_counts_t *out);

/* The simplest fraction with den <= ROD_COUNTS_DEN_MAX within 1e-4 count/turn of `value` (979.2 ->
 * 4896 / 5), or the closest one when none is that close; false for a value outside
 * [ROD_COUNTS_NUM_MIN, ROD_COUNTS_NUM_MAX] or not finite. */
bool rod_counts_from_value(float value, rod_counts_t *out);

/* The header's fraction (checked at compile time by rod_config.h). */
rod_counts_t rod_counts_default(void);

typedef struct {
    int32_t turn;       /* floor(count / counts per turn): which turn theta_1 is in */
    int32_t phase;      /* position in that turn [ticks], 0 .. 2 num - 1 */
    int32_t half_turn;  /* num: the phase of upright [ticks] */
    float rad_per_tick; /* of the fraction the count was reduced with [rad] */
    float theta;        /* theta_1, multi-turn [rad] (0 hanging, pi upright) */
    float from_bottom;  /* theta_1 minus the nearest hanging position [rad], [-pi, pi) */
    float from_upright; /* theta_1 minus the nearest upright, pi + 2 pi turn [rad], [-pi, pi) */
} rod_angle_t;

void rod_angle_from_count(int32_t count, const rod_counts_t *counts, rod_angle_t *out);

/* theta_1 minus the upright of `turn` (pi + 2 pi turn), exact to float rounding. */
float rod_angle_from_upright_of(const rod_angle_t *a, int32_t turn);

/* pi + 2 pi turn: the absolute angle of that turn's upright [rad]. */
float rod_angle_upright(int32_t turn);

/* Critically damped tracking loop on the count (gains ROD_RATE_FILTER_K1/K2). Its position
 * is kept relative to the latest count so it stays small and exact after any number of turns.
 * The rate is exactly 0 until the count first moves, and settles back toward 0 (critically
 * damped, 50 Hz by default) once it stops. */
typedef struct {
    int32_t ref_count; /* count the position is measured from */
    float pos;         /* tracked position relative to ref_count [rad] */
    float rate;        /* tracked base rate [rad/s] */
} rod_rate_filter_t;

void rod_rate_filter_init(rod_rate_filter_t *f, int32_t count);
/* One period; returns the rate [rad/s]. */
float rod_rate_filter_step(rod_rate_filter_t *f, int32_t count, float rad_per_count);

#ifdef __cplusplus
}
#endif

#endif /* ROD_ANGLE_H */
