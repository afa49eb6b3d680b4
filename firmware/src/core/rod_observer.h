/* rod_observer.h -- the balance estimator and LQR feedback (current-estimate form).
 *
 * Deviation coordinates z = x - x_upright, x = [theta_1..N, rates], measurement
 * y = theta_1 - upright (the set-point trim taken off, rod_trim.h). Each period:
 *     z_pred = Ad z + Bd (u_prev + w);   e = y - z_pred[0];   z = z_pred + L e
 *     w = ROD_W_DECAY w + Lw e;   u = -K z - w - ROD_K_TORQUE_PREV (u_prev + w)
 * w is a torque the rod feels at the base beyond the command (the gearbox's dry friction, a
 * torque-constant error, a push), cancelled: a random walk (ROD_W_DECAY 1) or a passing torque,
 * which leaves a steady torque to the trim. The tables come from rod_gains.h (designed for
 * exactly this form and ZOH at the loop rate).
 *
 * With the tip IMU (ROD_NY = 3, y = [theta_1, gyro, accelerometer y]) the estimate also carries a =
 * [encoder offset, gyro bias, the IMU's readings in flight] (gains/rodgains/imu.py, ImuEstimator):
 *     a_pred = AZ z + AA a + BA (u_prev + w);  y_hat = CZ z_pred + CA a_pred + DY (u_prev + w_pred)
 *     e = y - y_hat;  z = z_pred + L e;  w = w_pred + Lw e;  a = a_pred + La e
 * The encoder's offset is what finds upright from gravity: the accelerometer sees the tip's lean.
 * The torque then adds ROD_IMU_FLANK_FF_NM, ramped in over ROD_IMU_FLANK_RAMP_STEPS after the catch:
 * the rod held leaning so that gravity keeps one flank of the gearbox loaded (lqr.imu_flank_torque).
 */
#ifndef ROD_OBSERVER_H
#define ROD_OBSERVER_H

#include <stdbool.h>
#include <stdint.h>

#include "rod_config.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Where the IMU's extra states sit in rod_observer_t.a (gains/rodgains/imu.py, ImuEstimator). */
#define ROD_OBS_ENCODER_OFFSET 0 /* [rad] */
#define ROD_OBS_GYRO_BIAS 1      /* [rad/s] */

typedef struct {
    float z[ROD_NX]; /* estimate z[k|k]: angles then rates, relative to upright */
#if ROD_NY > 1
    float a[ROD_IMU_NA]; /* encoder offset [rad], gyro bias [rad/s], IMU readings in flight */
#endif
    float w;         /* estimated torque disturbance at the base (dry friction, k_t error) [N m] */
    float u_prev;    /* torque held over the last period [N m] */
#if ROD_NY > 1
    uint32_t steps;  /* periods since the catch: the flank feed-forward's ramp */
#endif
    bool finite;     /* false once any estimate entry is NaN or inf */
} rod_observer_t;

/* Estimator initialization at the catch (paper Sec. III-C): every angle deviation = y, every
 * rate = the measured base rate, u_prev = 0. With the IMU: the offset 0, the gyro bias as measured at
 * rest, the readings in flight those of this estimate. */
void rod_observer_init(rod_observer_t *o, float y, float rate, float gyro_bias);

/* One period: predict with u_prev, correct with the measurement y[ROD_NY] (y[0] the encoder's
 * theta_1 from upright; y[1..] the IMU's, used only when imu_ok); returns u = -K z of the new
 * estimate (before any torque limit). Also refreshes o->finite. */
float rod_observer_step(rod_observer_t *o, const float y[ROD_NY], bool imu_ok);

/* u = -K z of the current estimate, without advancing it (used on the catch step). */
float rod_observer_feedback(const rod_observer_t *o);

/* Record the torque actually applied for the coming period (after limits): the next
 * prediction must use what the rod felt, not what the LQR asked for. */
void rod_observer_hold(rod_observer_t *o, float u_applied);

#ifdef __cplusplus
}
#endif

#endif /* ROD_OBSERVER_H */
