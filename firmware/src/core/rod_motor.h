/* rod_motor.h -- output torque to signed PWM duty through the DC motor model.
 *
 *     i = tau / kt,   V = i R + ke rate,   duty = V / V_supply
 *
 * kt, ke at the output shaft (gearbox included), rate = measured base rate. The torque is
 * limited to ROD_TORQUE_MAX_NM first, the duty to ROD_DUTY_MAX second; when the duty limit
 * bites, the torque reported is what the limited voltage gives at this rate.
 */
#ifndef ROD_MOTOR_H
#define ROD_MOTOR_H

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    float duty;   /* signed duty [-ROD_DUTY_MAX, ROD_DUTY_MAX] */
    float torque; /* output torque that duty produces at this rate [N m] */
} rod_drive_t;

/* NaN in either input comes out as NaN (never clamped into a finite number), so the caller's
 * non-finite check sees it. */
rod_drive_t rod_motor_drive(float torque, float rate);

/* The gearbox's dry friction, cancelled in the direction of the estimated base rate [N m]:
 * ROD_COULOMB_COMP_NM sat(rate / ROD_FRICTION_RATE_BAND_RAD_S). Uncancelled, a shaft the
 * friction holds tells the observer nothing, and the rod drifts into a bent shape the LQR
 * no longer sees (balance from 30 deg ended 9 deg off with 5 mN m of friction). The rate is
 * the observer's, not the encoder filter's: quantization makes the latter chatter at rest. */
float rod_motor_friction_compensation(float rate);

#ifdef __cplusplus
}
#endif

#endif /* ROD_MOTOR_H */
