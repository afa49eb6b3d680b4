/* rod_observer.h -- the balance estimator and LQR feedback (current-estimate form).
 *
 * Deviation coordinates z = x - x_upright, x = [theta_1..N, rates], measurement
 * y = theta_1 - upright (the set-point trim taken off, rod_trim.h). Each period:
 *     z_pred = Ad z + Bd (u_prev + w);   e = y - z_pred[0];   z = z_pred + L e
 *     w = ROD_W_DECAY w + Lw e;   u = -K z - w
 * w is a torque the rod feels at the base beyond the command (the gearbox's dry friction, a
 * torque-constant error, a push), cancelled: a random walk (ROD_W_DECAY 1) or a passing torque,
 * which leaves a steady torque to the trim. The tables come from rod_gains.h (designed for
 * exactly this form and ZOH at the loop rate).
 */
#ifndef ROD_OBSERVER_H
#define ROD_OBSERVER_H

#include <stdbool.h>

#include "rod_config.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    float z[ROD_NX]; /* estimate z[k|k]: angles then rates, relative to upright */
    float w;         /* estimated torque disturbance at the base (dry friction, k_t error) [N m] */
    float u_prev;    /* torque held over the last period [N m] */
    bool finite;     /* false once any estimate entry is NaN or inf */
} rod_observer_t;

/* Estimator initialization at the catch (paper Sec. III-C): every angle deviation = y, every
 * rate = the measured base rate, u_prev = 0. */
void rod_observer_init(rod_observer_t *o, float y, float rate);

/* One period: predict with u_prev, correct with y; returns u = -K z of the new estimate
 * (before any torque limit). Also refreshes o->finite. */
float rod_observer_step(rod_observer_t *o, float y);

/* u = -K z of the current estimate, without advancing it (used on the catch step). */
float rod_observer_feedback(const rod_observer_t *o);

/* Record the torque actually applied for the coming period (after limits): the next
 * prediction must use what the rod felt, not what the LQR asked for. */
void rod_observer_hold(rod_observer_t *o, float u_applied);

#ifdef __cplusplus
}
#endif

#endif /* ROD_OBSERVER_H */
