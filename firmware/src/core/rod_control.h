/* rod_control.h -- modes, catch, safety: one control step per period.
 *
 * Modes and reasons are the protocol's codes (ROD_MODE_*, ROD_REASON_*, rod_protocol_defs.h,
 * generated from firmware/protocol/rodlink.toml; table in docs/architecture.md):
 *   DISARMED  driver off; power-on state; host disarm lands here with reason HOST
 *   CATCH     armed for balance, driver off until theta_1 is within the catch angle of upright
 *   SWING_UP  eq. (22) pumping until theta_1 is within the catch angle, then BALANCE
 *   BALANCE   observer + LQR
 *   IDENTIFY  an identification excitation (rod_identify.h) near hanging; DISARMED, reason
 *             NONE, when it has played to the end
 *   FAULT     driver off, latched until clear-fault; arm is refused (BAD_STATE)
 *
 * Trips (-> FAULT, zero duty, driver off in the same step):
 *   DRIVER_FAULT  nFAULT low, in any mode but FAULT (checked every period)
 *   OVERRUN       armed and this step started > 1.5 periods after the previous one, or the
 *                 previous one took longer than a period (overruns are counted in every mode)
 *   HEARTBEAT     armed and no valid host frame for the heartbeat timeout
 *   SPEED_LIMIT   armed and |base rate| > ROD_SPEED_LIMIT_RAD_S
 *   ANGLE_LIMIT   BALANCE and |theta_1 - the caught upright| > ROD_ANGLE_LIMIT_RAD, or
 *                 IDENTIFY and |theta_1 - the nearest hanging| > ROD_ANGLE_LIMIT_RAD
 *   NON_FINITE    NaN/inf in the estimate, torque or duty
 *   RUNAWAY       in the first second of BALANCE or SWING_UP the base accelerated against the
 *                 torque: a reversed encoder or motor (rod_runaway.h)
 *   IMU           a firmware with the tip IMU (ROD_NY > 1), armed for balance (CATCH, SWING_UP,
 *                 BALANCE), and ROD_IMU_FAULT_PERIODS bad IMU samples in a row (rod_imu.h)
 * ("armed" = CATCH, SWING_UP, BALANCE or IDENTIFY.)
 *
 * Commands come from the host (through the device's command ring) and return a ROD_ACK_*
 * code; a refused command changes nothing.
 */
#ifndef ROD_CONTROL_H
#define ROD_CONTROL_H

#include <stdbool.h>
#include <stdint.h>

#include "rod_angle.h"
#include "rod_config.h"
#include "rod_identify.h"
#include "rod_imu.h"
#include "rod_io.h"
#include "rod_observer.h"
#include "rod_rig.h"
#include "rod_runaway.h"
#include "rod_swingup.h"
#include "rod_trim.h"
#include "rod_protocol_defs.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Run-time settings (SET); defaults from rod_gains.h. */
typedef struct {
    float swing_amplitude;     /* [N m], [0, ROD_TORQUE_MAX_NM] */
    float swing_angle;         /* [rad], (0, pi] */
    float catch_angle;         /* [rad], (0, min(ROD_ANGLE_LIMIT_RAD, pi/2)) */
    float heartbeat_timeout;   /* [s], [0.2, 10] */
    uint32_t heartbeat_timeout_us;
    uint16_t decimation;       /* telemetry every this many steps, 1..1000 */
    rod_rig_t rig;             /* wiring signs: count -> angle, duty -> driver (rod_rig.h) */
} rod_settings_t;

typedef struct {
    uint8_t mode;   /* ROD_MODE_* */
    uint8_t reason; /* ROD_REASON_*: why it last left an armed mode (NONE while armed) */
    rod_settings_t settings;

    /* measurement of this step */
    int32_t count;
    rod_angle_t angle;
    rod_rate_filter_t filter;
    float rate;
    rod_imu_t imu;       /* the tip IMU's health and rest bias (ROD_NY > 1) */
    rod_imu_reading_t imu_reading;
    bool imu_good;       /* this period's sample may correct the estimate */

    /* balance */
    rod_observer_t obs;
    rod_trim_t trim; /* where the rod stands upright (or straightest), found from the torque (rod_trim.h) */
    rod_swingup_t swing;
    int32_t upright_turn; /* the upright being balanced: pi + 2 pi upright_turn */
    rod_runaway_t runaway; /* the sign watch of a driving mode's first second */

    /* identification */
    rod_identify_t ident;

    /* outputs of this step */
    bool enable;
    float duty, torque; /* the controller's duty, before the motor sign */

    /* timing and host liveness */
    bool started;
    uint32_t prev_start_us;
    uint32_t last_step_us;
    uint32_t overruns;
    uint32_t heartbeats_seen;
    uint32_t heartbeat_us; /* when the last valid host frame was noticed */
    bool heartbeat_refresh;
    bool heartbeat_ok;
    bool driver_fault;
} rod_control_t;

void rod_control_init(rod_control_t *c);

/* One period (timer interrupt). heartbeats: the count of valid host frames so far; any change
 * since the previous step means the host is alive. */
void rod_control_step(rod_control_t *c, const rod_inputs_t *in, uint32_t heartbeats, rod_outputs_t *out);

/* Host commands; each returns ROD_ACK_OK, ROD_ACK_BAD_VALUE or ROD_ACK_BAD_STATE. */
/* arm_mode ROD_ARM_BALANCE -> CATCH (or stays BALANCE), ROD_ARM_SWING_UP -> SWING_UP.
 * Refused in FAULT. Arming counts as hearing from the host. */
uint8_t rod_control_arm(rod_control_t *c, uint8_t arm_mode);
/* -> DISARMED, reason HOST; in FAULT it stays FAULT (only clear-fault leaves it). */
uint8_t rod_control_disarm(rod_control_t *c);
/* FAULT -> DISARMED (the reason is kept for the record); elsewhere an OK no-op. */
uint8_t rod_control_clear_fault(rod_control_t *c);
/* DISARMED -> IDENTIFY playing *req (BAD_STATE in any other mode, BAD_VALUE out of range).
 * Starting counts as hearing from the host. */
uint8_t rod_control_identify(rod_control_t *c, const rod_identify_request_t *req);
/* param ROD_PARAM_*; out of bounds, not finite, not an integer where one is needed, or an
 * unknown param -> BAD_VALUE and nothing changes. ENCODER_SIGN / MOTOR_SIGN take +1 or -1, and
 * only while not armed (BAD_STATE); a new encoder sign restarts the rate filter on the next count. */
uint8_t rod_control_set(rod_control_t *c, uint8_t param, float value);

/* The estimate as reported (telemetry, SIL): absolute angles (pi upright) and rates. Outside
 * BALANCE every entry is the measured theta_1 / base rate. */
void rod_control_estimate(const rod_control_t *c, float theta[ROD_N], float rate[ROD_N]);

/* ROD_TLM_FLAG_* bits of this step. */
uint8_t rod_control_flags(const rod_control_t *c);

static inline bool rod_mode_is_armed(uint8_t mode)
{
    return mode == ROD_MODE_BALANCE || mode == ROD_MODE_SWING_UP || mode == ROD_MODE_CATCH
           || mode == ROD_MODE_IDENTIFY;
}

#ifdef __cplusplus
}
#endif

#endif /* ROD_CONTROL_H */
