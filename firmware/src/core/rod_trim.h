/* rod_trim.h -- finding upright from the physics: an upright rod needs no holding torque.
 *
 * The encoder's zero is taken at boot to a count (0.37 deg), and the gearbox's play sits between
 * the encoder and the rod: neither says where the rod stands upright to the tenth of a degree a
 * rod near its buckling length needs (its tip leans several times what its foot does). The torque
 * says it: a rod held off upright needs a steady torque to stay there, and the command is known
 * exactly, with no quantization. So the trim moves the balance set-point (the encoder angle the
 * estimator calls upright) while the steady torque lasts:
 *
 *     hold += ROD_TRIM_HOLD_K (u - hold)                     low-passed torque given, compensation included
 *     while every estimated angle is within ROD_TRIM_GATE_RAD of upright (quasi-static):
 *         trim += ROD_TRIM_RATE * dz(hold - ROD_TRIM_TARGET_NM, ROD_TRIM_BAND_NM),   |trim - ROD_TRIM_START_RAD| <= ROD_TRIM_MAX_RAD
 *
 * ROD_TRIM_TARGET_NM is 0 for a straight rod. A rod curved at rest (rod.rest_curvature) has no straight upright
 * shape: its zero-torque shape leans the curvature's way, and the straightest one is held by a steady torque
 * that tilts the hub against the bend (gains/rodgains/trim.py straightest_shape): the trim starts at that shape's
 * hub angle, ROD_TRIM_START_RAD, and seeks its torque.
 *
 * dz is a dead zone: the trim stops once the steady torque is inside the band, not at zero. With
 * backlash the zero-torque point lies inside the gap, where nothing holds the rod's foot; the rod rests
 * on one flank with the small torque that holds it there (0.25 to 0.75 mN m measured alike on Table I's 5 mN m of
 * dry friction, docs/control.md "Finding upright"). The motor's dry friction holds the foot there too, so with
 * less of it the band is wider (gains/rodgains/trim.py band_nm). u includes the friction compensation: left out, its mean on a flank goes unseen
 * and the rod hunts across the gap.
 *
 * ROD_TRIM_RATE [rad per N m per period] makes the trim loop a first-order lag of the design's
 * time constant on the design model (gains/rodgains/trim.py).
 */
#ifndef ROD_TRIM_H
#define ROD_TRIM_H

#include <stdbool.h>

#include "rod_config.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    float trim; /* encoder angle of the balance's set-point (the rod's upright, or its straightest shape's hub),
                 * relative to the encoder's upright [rad] */
    float hold; /* low-passed torque the balance gave, friction compensation included [N m] */
} rod_trim_t;

/* Power-on: the trim at ROD_TRIM_START_RAD (0 but for a rod curved at rest). */
void rod_trim_init(rod_trim_t *t);

/* A new balance (the catch): the steady torque is the new balance's; the trim is the rig's and stays. */
void rod_trim_catch(rod_trim_t *t);

/* One balance period with the torque the motor was given (friction compensation included: its mean
 * over the dither on a flank pushes the rod too); returns the trim [rad]. */
float rod_trim_update(rod_trim_t *t, float torque, bool quasi_static);

#ifdef __cplusplus
}
#endif

#endif /* ROD_TRIM_H */
