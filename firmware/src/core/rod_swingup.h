/* rod_swingup.h -- swing-up by energy pumping toward the upright energy, with a start from rest.
 *
 * The rod is treated as a rigid pendulum on the shaft for the energy only (its bending modes
 * are filtered out of the rate, not modelled):
 *     w = low-passed base rate,   e = (w / omega0)^2 / 2 + 1 - cos(theta_1)   (2 = upright at rest)
 *     u = amplitude sat((target e - e) / ROD_SWING_ENERGY_BAND) sign(w)   while |theta_1| < swing angle
 *     u = 0                                                              otherwise
 * theta_1 from hanging. Below the target it pumps like eq. (22) of the paper, u = amplitude
 * sign(dtheta_1), but at every angle up to the swing angle; at the target it stops pushing, and
 * above it brakes, so the rod arrives near upright slowly instead of flying over the top.
 * omega0 (the rigid rod + motor pendulum frequency) and the target come from rod_gains.h.
 *
 * The stall watch. Where the pump cannot lift the rod into the catch window (a supply below the
 * design's, a weaker motor, a rod whose bend fools the rigid energy) the swing settles into a steady
 * amplitude short of it and is never caught. A half-swing (bottom to bottom) that turns back no more
 * than ROD_SWING_STALL_RISE_RAD higher than the one before is a stall: each raises the target by
 * ROD_SWING_STALL_TARGET_STEP and the amplitude by ROD_SWING_STALL_GAIN (to ROD_SWING_STALL_GAIN_MAX x),
 * at most ROD_SWING_STALL_STEPS times (0: off). A rod still rising faster is left alone.
 */
#ifndef ROD_SWINGUP_H
#define ROD_SWINGUP_H

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    float rate_lp;    /* base rate through a first-order low-pass [rad/s] */
    float peak;       /* largest |from_bottom| of this half-swing [rad] */
    float last_peak;  /* the last half-swing's [rad]; < 0 before the first */
    float side;       /* sign of from_bottom on this half-swing: -1, 0 (at rest), +1 */
    float target;     /* the energy target, raised by stalls (2 = upright) [-] */
    float gain;       /* the amplitude's factor, raised by stalls [-] */
    int stalls;       /* stalls seen since the swing-up began */
} rod_swingup_t;

void rod_swingup_init(rod_swingup_t *s);

/* One period. from_bottom: theta_1 minus the nearest hanging position [rad]
 * (rod_angle_t.from_bottom); rate: measured base rate [rad/s]. At rest near the bottom sign(rate)
 * is 0 and the rod would never start, so there the law pushes with +amplitude (ROD_SWING_REST_*). */
float rod_swingup_torque(rod_swingup_t *s, float amplitude, float swing_angle, float from_bottom, float rate);

/* The pendulum energy e of the law above (2 = upright at rest) for this angle and rate. */
float rod_swingup_energy(float from_bottom, float rate);

#ifdef __cplusplus
}
#endif

#endif /* ROD_SWINGUP_H */
