/* rod_swingup.h -- the swing-up law, eq. (22) of the paper, with a start from rest.
 *
 *     u = amplitude sign(dtheta_1)   while |theta_1| < swing angle (theta_1 from hanging)
 *     u = 0                          otherwise
 */
#ifndef ROD_SWINGUP_H
#define ROD_SWINGUP_H

#ifdef __cplusplus
extern "C" {
#endif

/* from_bottom: theta_1 minus the nearest hanging position [rad] (rod_angle_t.from_bottom);
 * rate: measured base rate [rad/s]. At rest near the bottom sign(rate) is 0 and the rod would
 * never start, so there the law pushes with +amplitude (ROD_SWING_REST_*). */
float rod_swingup_torque(float amplitude, float swing_angle, float from_bottom, float rate);

#ifdef __cplusplus
}
#endif

#endif /* ROD_SWINGUP_H */
