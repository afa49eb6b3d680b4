/* rod_control.c -- the mode machine: measure, check, pick the torque law, drive. */
#include "rod_control.h"

#include <math.h>

#include "rod_motor.h"
#include "rod_runaway.h"
#include "rod_swingup.h"

static uint32_t seconds_to_us(float s)
{
    return (uint32_t)(s * 1.0e6f + 0.5f);
}

void rod_control_init(rod_control_t *c)
{
    *c = (rod_control_t){0};
    c->mode = ROD_MODE_DISARMED;
    c->reason = ROD_REASON_NONE;
    c->settings.swing_amplitude = ROD_SWING_AMPLITUDE_NM;
    c->settings.swing_angle = ROD_SWING_ANGLE_RAD;
    c->settings.catch_angle = ROD_CATCH_ANGLE_RAD;
    c->settings.heartbeat_timeout = ROD_HEARTBEAT_TIMEOUT_S;
    c->settings.heartbeat_timeout_us = seconds_to_us(ROD_HEARTBEAT_TIMEOUT_S);
    c->settings.decimation = 1;
    c->settings.rig = rod_rig_defaults(1, 1);
    rod_angle_from_count(0, &c->settings.rig.counts, &c->angle);
    rod_rate_filter_init(&c->filter, 0);
    rod_trim_init(&c->trim);
    rod_imu_init(&c->imu);
}

/* ---- commands ---------------------------------------------------------------------------- */

uint8_t rod_control_arm(rod_control_t *c, uint8_t arm_mode)
{
    if (arm_mode != ROD_ARM_BALANCE && arm_mode != ROD_ARM_SWING_UP) {
        return ROD_ACK_BAD_VALUE;
    }
    if (c->mode == ROD_MODE_FAULT) {
        return ROD_ACK_BAD_STATE;
    }
    if (arm_mode == ROD_ARM_SWING_UP) {
        /* A rod being caught or balanced is not pumped: near upright the pump's torque would throw it (swing-up
         * has no angle limit), and the catch after it would throw away the estimate and the trim mid-balance. */
        if (c->mode == ROD_MODE_CATCH || c->mode == ROD_MODE_BALANCE) {
            return ROD_ACK_BAD_STATE;
        }
        if (c->mode != ROD_MODE_SWING_UP) { /* a repeat changes nothing: the pump's stall watch goes on */
            c->mode = ROD_MODE_SWING_UP;
            rod_swingup_init(&c->swing);
            rod_runaway_start(&c->runaway, c->rate);
        }
    } else if (c->mode != ROD_MODE_BALANCE) {
        c->mode = ROD_MODE_CATCH;
    }
    c->reason = ROD_REASON_NONE;
    c->heartbeat_refresh = true;
    return ROD_ACK_OK;
}

uint8_t rod_control_disarm(rod_control_t *c)
{
    if (c->mode != ROD_MODE_FAULT) {
        c->mode = ROD_MODE_DISARMED;
        c->reason = ROD_REASON_HOST;
    }
    return ROD_ACK_OK;
}

uint8_t rod_control_clear_fault(rod_control_t *c)
{
    if (c->mode == ROD_MODE_FAULT) {
        c->mode = ROD_MODE_DISARMED;
    }
    return ROD_ACK_OK;
}

uint8_t rod_control_identify(rod_control_t *c, const rod_identify_request_t *req)
{
    if (c->mode != ROD_MODE_DISARMED) {
        return ROD_ACK_BAD_STATE;
    }
    if (!rod_identify_start(&c->ident, req)) {
        return ROD_ACK_BAD_VALUE;
    }
    c->mode = ROD_MODE_IDENTIFY;
    c->reason = ROD_REASON_NONE;
    c->heartbeat_refresh = true;
    return ROD_ACK_OK;
}

/* lo < v <= hi or lo <= v <= hi; false for NaN. */
static bool within(float v, float lo, bool lo_open, float hi, bool hi_open)
{
    bool above = lo_open ? v > lo : v >= lo;
    bool below = hi_open ? v < hi : v <= hi;
    return above && below;
}

uint8_t rod_control_set(rod_control_t *c, uint8_t param, float value)
{
    /* Ranges: codes.param min / max / design_max of rodlink.toml (rod_protocol_defs.h), the same
     * numbers `rodctl set` checks, so the host refuses before sending what the device would. */
    rod_settings_t *s = &c->settings;
    switch (param) {
    case ROD_PARAM_SWING_AMPLITUDE:
        if (!within(value, ROD_PARAM_SWING_AMPLITUDE_MIN, false, ROD_PARAM_SWING_AMPLITUDE_MAX, false)) {
            return ROD_ACK_BAD_VALUE;
        }
        s->swing_amplitude = value;
        return ROD_ACK_OK;
    case ROD_PARAM_SWING_ANGLE:
        if (!within(value, ROD_PARAM_SWING_ANGLE_MIN, false, ROD_PARAM_SWING_ANGLE_MAX, false)) {
            return ROD_ACK_BAD_VALUE;
        }
        s->swing_angle = value;
        return ROD_ACK_OK;
    case ROD_PARAM_CATCH_ANGLE:
        if (!within(value, ROD_PARAM_CATCH_ANGLE_MIN, false, ROD_PARAM_CATCH_ANGLE_MAX, false)) {
            return ROD_ACK_BAD_VALUE;
        }
        s->catch_angle = value;
        return ROD_ACK_OK;
    case ROD_PARAM_TELEMETRY_DECIMATION:
        if (!within(value, ROD_PARAM_TELEMETRY_DECIMATION_MIN, false, ROD_PARAM_TELEMETRY_DECIMATION_MAX, false)
            || value != floorf(value)) {
            return ROD_ACK_BAD_VALUE;
        }
        s->decimation = (uint16_t)value;
        return ROD_ACK_OK;
    case ROD_PARAM_HEARTBEAT_TIMEOUT:
        if (!within(value, ROD_PARAM_HEARTBEAT_TIMEOUT_MIN, false, ROD_PARAM_HEARTBEAT_TIMEOUT_MAX, false)) {
            return ROD_ACK_BAD_VALUE;
        }
        s->heartbeat_timeout = value;
        s->heartbeat_timeout_us = seconds_to_us(value);
        return ROD_ACK_OK;
    case ROD_PARAM_ENCODER_SIGN:
    case ROD_PARAM_MOTOR_SIGN:
        if (value != 1.0f && value != -1.0f) {
            return ROD_ACK_BAD_VALUE;
        }
        if (rod_mode_is_armed(c->mode)) {
            return ROD_ACK_BAD_STATE;
        }
        if (param == ROD_PARAM_ENCODER_SIGN) {
            if ((value < 0.0f) != (s->rig.encoder_sign < 0)) {
                c->started = false; /* the counts so far had the other sign */
            }
            s->rig.encoder_sign = value < 0.0f ? (int8_t)-1 : (int8_t)1;
        } else {
            s->rig.motor_sign = value < 0.0f ? (int8_t)-1 : (int8_t)1;
        }
        return ROD_ACK_OK;
    case ROD_PARAM_COUNTS_PER_REV: {
        rod_counts_t counts;
        if (!within(value, ROD_PARAM_COUNTS_PER_REV_MIN, false, ROD_PARAM_COUNTS_PER_REV_MAX, false)
            || !rod_counts_from_value(value, &counts)) {
            return ROD_ACK_BAD_VALUE;
        }
        if (rod_mode_is_armed(c->mode)) {
            return ROD_ACK_BAD_STATE;
        }
        s->rig.counts = counts; /* the count itself is unchanged: 0 is still the boot's hanging */
        return ROD_ACK_OK;
    }
    default:
        return ROD_ACK_BAD_VALUE;
    }
}

/* ---- the step ---------------------------------------------------------------------------- */

static void trip(rod_control_t *c, uint8_t reason)
{
    c->mode = ROD_MODE_FAULT;
    c->reason = reason;
}

/* Timing and liveness first: they decide whether this step may drive at all. Returns whether
 * this step overran. */
static bool track_time(rod_control_t *c, const rod_inputs_t *in, int32_t count, uint32_t heartbeats)
{
    bool overrun = false;
    if (c->started) {
        uint32_t gap = in->now_us - c->prev_start_us; /* unsigned: wraps correctly */
        /* gap > 1.5 periods, in integers: gap > floor(3 P / 2) is the same test. */
        overrun = gap > (3u * ROD_LOOP_PERIOD_US) / 2u || in->last_step_us > ROD_LOOP_PERIOD_US;
        if (overrun) {
            c->overruns++;
        }
    } else {
        /* Power-on: start the rate filter on the first real count. */
        c->started = true;
        rod_rate_filter_init(&c->filter, count);
        c->heartbeat_us = in->now_us;
        c->heartbeats_seen = heartbeats;
    }
    c->prev_start_us = in->now_us;
    c->last_step_us = in->last_step_us;

    if (heartbeats != c->heartbeats_seen || c->heartbeat_refresh) {
        c->heartbeats_seen = heartbeats;
        c->heartbeat_us = in->now_us;
        c->heartbeat_refresh = false;
    }
    c->heartbeat_ok = in->now_us - c->heartbeat_us < c->settings.heartbeat_timeout_us;
    return overrun;
}

static void check_safety(rod_control_t *c, bool overrun)
{
    if (c->mode == ROD_MODE_FAULT) {
        return;
    }
    if (c->driver_fault) {
        trip(c, ROD_REASON_DRIVER_FAULT);
        return;
    }
    if (!rod_mode_is_armed(c->mode)) {
        return;
    }
    if (overrun) {
        trip(c, ROD_REASON_OVERRUN);
    } else if (!c->heartbeat_ok) {
        trip(c, ROD_REASON_HEARTBEAT);
    } else if (!(fabsf(c->rate) <= ROD_SPEED_LIMIT_RAD_S)) {
        trip(c, ROD_REASON_SPEED_LIMIT);
    } else if (c->mode == ROD_MODE_BALANCE
               && !(fabsf(rod_angle_from_upright_of(&c->angle, c->upright_turn)) <= ROD_ANGLE_LIMIT_RAD)) {
        trip(c, ROD_REASON_ANGLE_LIMIT);
    } else if (c->mode == ROD_MODE_IDENTIFY && !(fabsf(c->angle.from_bottom) <= ROD_ANGLE_LIMIT_RAD)) {
        trip(c, ROD_REASON_ANGLE_LIMIT);
    } else if (ROD_NY > 1 && c->mode != ROD_MODE_IDENTIFY && rod_imu_lost(&c->imu)) {
        trip(c, ROD_REASON_IMU);
    }
}

/* Within the catch angle of the nearest upright: start balancing it, with the estimator
 * initialized as in the paper (Sec. III-C). This step's estimate is that initialization, so
 * its torque is -K z0 without a prediction; u_prev then holds that torque for the next one. */
static bool try_catch(rod_control_t *c)
{
    if (!(fabsf(c->angle.from_upright) <= c->settings.catch_angle)) {
        return false;
    }
    c->upright_turn = c->angle.turn;
    rod_trim_catch(&c->trim);
    rod_observer_init(&c->obs, c->angle.from_upright - c->trim.trim, c->rate, c->imu.gyro_bias);
    rod_runaway_start(&c->runaway, c->rate);
    c->mode = ROD_MODE_BALANCE;
    return true;
}

/* The balance's measurement: theta_1 from the upright the trim found, then the IMU's gyro and
 * accelerometer y (the axis that sees the lean). */
static void balance_measurement(const rod_control_t *c, float y[ROD_NY])
{
    y[0] = rod_angle_from_upright_of(&c->angle, c->upright_turn) - c->trim.trim;
#if ROD_NY > 1
    y[1] = c->imu_reading.gyro;
    y[2] = c->imu_reading.accel_y;
#endif
}

/* Near upright and slow, where a steady torque can only be holding the rod off upright. */
static bool quasi_static(const rod_control_t *c)
{
    for (int i = 0; i < ROD_N; i++) {
        if (!(fabsf(c->obs.z[i]) <= ROD_TRIM_GATE_RAD)) {
            return false;
        }
    }
    return true;
}

/* Torque request of this step by mode (0 where the driver stays off). */
static float control_law(rod_control_t *c)
{
    switch (c->mode) {
    case ROD_MODE_CATCH:
        return try_catch(c) ? rod_observer_feedback(&c->obs) : 0.0f;
    case ROD_MODE_SWING_UP:
        if (try_catch(c)) {
            return rod_observer_feedback(&c->obs);
        }
        return rod_swingup_torque(&c->swing, c->settings.swing_amplitude, c->settings.swing_angle,
                                  c->angle.from_bottom, c->rate);
    case ROD_MODE_BALANCE: {
        float y[ROD_NY];
        balance_measurement(c, y);
        return rod_observer_step(&c->obs, y, c->imu_good);
    }
    case ROD_MODE_IDENTIFY: {
        bool done;
        float u = rod_identify_torque(&c->ident, &done);
        if (done) {
            c->mode = ROD_MODE_DISARMED;
            c->reason = ROD_REASON_NONE;
        }
        return u;
    }
    default:
        return 0.0f;
    }
}

void rod_control_step(rod_control_t *c, const rod_inputs_t *in, uint32_t heartbeats, rod_outputs_t *out)
{
    int32_t count = rod_rig_count(&c->settings.rig, in->encoder_count);
    bool overrun = track_time(c, in, count, heartbeats);

    c->count = count;
    c->driver_fault = in->driver_fault;
    rod_angle_from_count(count, &c->settings.rig.counts, &c->angle);
    c->rate = rod_rate_filter_step(&c->filter, count, c->settings.rig.counts.rad_per_count);
#if ROD_NY > 1
    c->imu_reading = in->imu;
    /* the part is mounted turned by the tilt: turn its accelerometer back into the rod's frame */
    c->imu_reading.accel_x = ROD_IMU_TILT_COS * in->imu.accel_x - ROD_IMU_TILT_SIN * in->imu.accel_y;
    c->imu_reading.accel_y = ROD_IMU_TILT_SIN * in->imu.accel_x + ROD_IMU_TILT_COS * in->imu.accel_y;
    c->imu_good = rod_imu_step(&c->imu, &in->imu, count);
#endif

    check_safety(c, overrun);

    float request = control_law(c);
    bool driving = c->mode == ROD_MODE_BALANCE || c->mode == ROD_MODE_SWING_UP || c->mode == ROD_MODE_IDENTIFY;
    rod_drive_t drive = {0.0f, 0.0f};
    /* the observer's model has no dry friction: it is told the torque net of the compensation */
    float friction = c->mode == ROD_MODE_BALANCE ? rod_motor_friction_compensation(c->obs.z[ROD_N]) : 0.0f;
    if (driving) {
        drive = rod_motor_drive(request + friction, c->rate);
        bool estimate_ok = c->mode != ROD_MODE_BALANCE || c->obs.finite;
        bool closed_loop = c->mode == ROD_MODE_BALANCE || c->mode == ROD_MODE_SWING_UP;
        uint8_t stop = ROD_REASON_NONE;
        if (!estimate_ok || !isfinite(drive.torque) || !isfinite(drive.duty)) {
            stop = ROD_REASON_NON_FINITE;
        } else if (closed_loop && rod_runaway_step(&c->runaway, drive.torque, c->rate)) {
            stop = ROD_REASON_RUNAWAY;
        }
        if (stop != ROD_REASON_NONE) {
            trip(c, stop);
            driving = false;
            drive.duty = 0.0f;
            drive.torque = 0.0f;
        } else if (c->mode == ROD_MODE_BALANCE) {
            rod_observer_hold(&c->obs, drive.torque - friction);
            /* the whole torque, compensation included (rod_trim.h says why) */
            rod_trim_update(&c->trim, drive.torque, quasi_static(c));
        }
    }

    c->enable = driving;
    c->duty = drive.duty;
    c->torque = drive.torque;
    out->enable = driving;
    out->duty = rod_rig_duty(&c->settings.rig, drive.duty);
    out->torque = drive.torque;
}

/* ---- reporting --------------------------------------------------------------------------- */

void rod_control_estimate(const rod_control_t *c, float theta[ROD_N], float rate[ROD_N])
{
    if (c->mode == ROD_MODE_BALANCE) {
        float up = rod_angle_upright(c->upright_turn);
        for (int i = 0; i < ROD_N; i++) {
            theta[i] = up + c->obs.z[i];
            rate[i] = c->obs.z[ROD_N + i];
        }
    } else {
        for (int i = 0; i < ROD_N; i++) {
            theta[i] = c->angle.theta;
            rate[i] = c->rate;
        }
    }
}

uint8_t rod_control_flags(const rod_control_t *c)
{
    uint8_t f = 0;
    if (c->enable) {
        f |= ROD_TLM_FLAG_DRIVER_ENABLED;
    }
    if (c->driver_fault) {
        f |= ROD_TLM_FLAG_NFAULT_LOW;
    }
    if (c->heartbeat_ok) {
        f |= ROD_TLM_FLAG_HEARTBEAT_OK;
    }
    return f;
}
