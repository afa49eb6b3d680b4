/* rod_identify.h -- excitations for system identification, computed on the board.
 *
 * The host chooses one excitation (IDENTIFY command, firmware/protocol/rodlink.toml) and the
 * board plays it period by period, so the torque sequence does not depend on USB timing and
 * the logged torque is exactly what was asked for. All amplitudes are output-shaft torques
 * [N m]; the caller clamps to the torque limit through rod_motor as in every other mode.
 *
 *   CHIRP    A sin(phi), instantaneous frequency rising linearly from f0 to f1 [Hz] over the
 *            duration (shape1 = f0, shape2 = f1)
 *   PRBS     +-A from a 16-bit maximal-length LFSR, one bit per bit time (shape1 = bit time [s];
 *            seed = the LFSR's start state, 0 taken as 1)
 *   STEPS    the levels +A, 0, -A, 0, ... each held for shape1 [s]
 *   RELEASE  +A for shape1 [s], then zero torque with the driver still enabled (free swing)
 *   SETTLE   A (1 - t / duration) sin(2 pi shape1 t): a push to and fro that fades out, so the
 *            rig ends at rest near hanging whatever the last experiment left swinging in the play
 *            or held off hanging by the dry friction (played between experiments, not fitted)
 *
 * The excitation ends after `duration` [s]; rod_identify_torque then reports done.
 */
#ifndef ROD_IDENTIFY_H
#define ROD_IDENTIFY_H

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* What the host asked for (the IDENTIFY payload). */
typedef struct {
    uint8_t excitation; /* ROD_EXCITATION_* */
    uint16_t seed;      /* PRBS LFSR start state */
    float amplitude;    /* [N m] */
    float duration;     /* [s] */
    float shape1;       /* chirp f0 [Hz] | PRBS bit time [s] | step hold [s] | release pulse [s] | settle frequency [Hz] */
    float shape2;       /* chirp f1 [Hz]; unused (0) otherwise */
} rod_identify_request_t;

typedef struct {
    rod_identify_request_t req;
    uint32_t k;        /* periods played so far */
    uint32_t total;    /* periods in the whole excitation */
    uint32_t hold;     /* periods per PRBS bit / step level / release pulse */
    float phase;       /* chirp phase, kept in [-pi, pi) so float keeps its resolution [rad] */
    float dphase0;     /* chirp phase increment per period at f0 [rad] */
    float ddphase;     /* its growth per period [rad] */
    uint16_t lfsr;
    float level;       /* the current PRBS / steps level [N m] */
} rod_identify_t;

/* Checks the request (amplitude in (0, torque limit], duration in (0, 600] s, shapes in range
 * for the control period) and prepares *id. false (and *id untouched) when out of range. */
bool rod_identify_start(rod_identify_t *id, const rod_identify_request_t *req);

/* Torque of this period [N m]; *done is set (and 0 returned) once the duration has elapsed. */
float rod_identify_torque(rod_identify_t *id, bool *done);

#ifdef __cplusplus
}
#endif

#endif /* ROD_IDENTIFY_H */
