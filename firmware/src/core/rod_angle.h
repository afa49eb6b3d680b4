/* rod_angle.h -- encoder count to base angle theta_1, and the base-rate tracking filter.
 *
 * The count is reduced to (turn, phase) with integer arithmetic on the exact fraction
 * counts/turn = ROD_COUNTS_PER_REV_NUM / ROD_COUNTS_PER_REV_DEN, in ticks of 1/(2 DEN) count,
 * so hanging (0), upright (489.6 counts) and every later turn land on exact ticks: the
 * distance to upright is never off by a rounded half count, however many turns were made.
 */
#ifndef ROD_ANGLE_H
#define ROD_ANGLE_H

#include <stdint.h>

#include "rod_config.h"

#ifdef __cplusplus
extern "C" {
#endif

/* One turn in ticks; upright of a turn sits at phase ROD_TICKS_PER_REV / 2. */
#define ROD_TICKS_PER_REV (2 * ROD_COUNTS_PER_REV_NUM)
#define ROD_RAD_PER_TICK (ROD_PI_F / (float)ROD_COUNTS_PER_REV_NUM)

typedef struct {
    int32_t turn;       /* floor(count / counts per turn): which turn theta_1 is in */
    int32_t phase;      /* position in that turn [ticks], 0 .. ROD_TICKS_PER_REV - 1 */
    float theta;        /* theta_1, multi-turn [rad] (0 hanging, pi upright) */
    float from_bottom;  /* theta_1 minus the nearest hanging position [rad], [-pi, pi) */
    float from_upright; /* theta_1 minus the nearest upright, pi + 2 pi turn [rad], [-pi, pi) */
} rod_angle_t;

void rod_angle_from_count(int32_t count, rod_angle_t *out);

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
float rod_rate_filter_step(rod_rate_filter_t *f, int32_t count);

#ifdef __cplusplus
}
#endif

#endif /* ROD_ANGLE_H */
