/* rod_runaway.h -- a sign error caught in the first second of a driving mode.
 *
 * A reversed encoder or motor turns every closed loop into positive feedback: the first `arm`
 * of a miswired rig would drive the rod away at full torque until the angle or speed limit. The
 * physics gives the sign away at once. The encoder sits on the motor, whose rotor dominates the
 * base's inertia over a few milliseconds, so the base accelerates WITH the torque on a rig wired
 * right, and AGAINST it on a miswired one, whatever the rod does.
 *
 * So, for ROD_RUNAWAY_WINDOW_S after entering BALANCE or SWING_UP, blocks of
 * ROD_RUNAWAY_BLOCK_STEPS periods pair the torque impulse U_b (the command, delayed by the rate
 * filter's lag) with the measured change of the base rate dw_b, and
 *
 *     trip when  sum U_b dw_b < -ROD_RUNAWAY_CORRELATION * sqrt(sum U_b^2 * sum dw_b^2)
 *                after ROD_RUNAWAY_MIN_BLOCKS blocks of |U_b| >= ROD_RUNAWAY_MIN_IMPULSE
 *
 * (a normalized correlation: no inertia or friction value enters, so a misidentified rig cannot
 * make a right one look wrong). Gravity's share of dw_b is in quadrature with the swing-up's torque
 * and small against the balance's, and friction only shrinks dw_b: neither turns the sign.
 * After the window the detector rests; the angle and speed limits still stand.
 */
#ifndef ROD_RUNAWAY_H
#define ROD_RUNAWAY_H

#include <stdbool.h>
#include <stdint.h>

#include "rod_config.h"

#ifdef __cplusplus
extern "C" {
#endif

#define ROD_RUNAWAY_WINDOW_S 1.0f      /* watch this long after entering a driving mode [s] */
#define ROD_RUNAWAY_BLOCK_S 0.010f     /* one block of torque and rate change [s] */
#define ROD_RUNAWAY_LAG_S 0.004f       /* the rate filter's lag: the torque is paired this much later [s] */
#define ROD_RUNAWAY_CORRELATION 0.5f   /* trip below minus this normalized correlation [-] */
#define ROD_RUNAWAY_MIN_IMPULSE 2.0e-4f /* a block with less torque x time than this says little [N m s] */
#define ROD_RUNAWAY_MIN_BLOCKS 4u      /* evidence needed: this many blocks with at least that impulse [-] */
#define ROD_RUNAWAY_LAG_MAX 32         /* ring size for the delayed torque [periods] */

typedef struct {
    uint32_t steps;       /* periods since the mode was entered */
    uint32_t in_block;    /* periods in the current block */
    float lag[ROD_RUNAWAY_LAG_MAX];
    uint32_t lag_head;
    float impulse;        /* U_b so far [N m s] */
    float rate_start;     /* base rate at the block's start [rad/s] */
    uint32_t blocks;      /* blocks with |U_b| >= ROD_RUNAWAY_MIN_IMPULSE */
    float s_uw, s_uu, s_ww;
} rod_runaway_t;

/* A driving mode starts: watch from here, with the base rate now [rad/s]. */
void rod_runaway_start(rod_runaway_t *r, float rate);

/* One driving period: the torque commanded this period [N m] and the base rate measured at its
 * start [rad/s]. true: the base has been accelerating against the torque (trip RUNAWAY). */
bool rod_runaway_step(rod_runaway_t *r, float torque, float rate);

#ifdef __cplusplus
}
#endif

#endif /* ROD_RUNAWAY_H */
