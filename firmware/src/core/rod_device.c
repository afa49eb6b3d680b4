/* rod_device.c -- one step: apply commands, run the control, queue numbered frames. */
#include "rod_device.h"

#include <string.h>

#include "rod_version.h"

static const uint8_t gains_sha256[32] = ROD_GAINS_SHA256_BYTES_INIT;

void rod_device_init(rod_device_t *dev)
{
    rod_control_init(&dev->control);
    rod_link_init(&dev->link);
    dev->seq = 0;
    dev->ring_drops = 0;
    dev->steps_since_telemetry = 0;
    dev->steps_since_hello = 0;
    dev->hello_wanted = true; /* announce ourselves on the first step */
    dev->board_fault = ROD_REASON_NONE;
    dev->rig_corrupt = 0u;
    memset(dev->rig_kept, 0, sizeof dev->rig_kept);
    dev->save_wanted = false;
    dev->save_writing = false;
    dev->save_failed = false;
}

void rod_device_load_rig(rod_device_t *dev, const uint8_t *stored, size_t n, rod_rig_t defaults)
{
    uint8_t source = rod_rig_decode(stored, n, defaults, &dev->control.settings.rig);
    dev->rig_corrupt = source & ROD_RIG_FLAG_STORE_CORRUPT;
    if (source & ROD_RIG_FLAG_STORED) {
        /* re-encoded, so an older layout compares equal to the settings it gave */
        rod_rig_encode(&dev->control.settings.rig, dev->rig_kept);
    } else {
        memset(dev->rig_kept, 0, sizeof dev->rig_kept);
    }
}

/* A SAVE_RIG's record is waiting for the main loop, or being written by it (rod_device_saved ends it). */
static bool rig_saving(const rod_device_t *dev)
{
    return dev->save_wanted || dev->save_writing;
}

/* STORED: the settings in use are the record in storage (a SET since then clears it), and any
 * SAVE_RIG's record has been written (rod_device_saved). */
static uint8_t rig_flags(const rod_device_t *dev)
{
    uint8_t now[ROD_RIG_STORE_SIZE];
    rod_rig_encode(&dev->control.settings.rig, now);
    uint8_t flags = (uint8_t)(rod_rig_sign_flags(&dev->control.settings.rig) | dev->rig_corrupt);
    if (!rig_saving(dev) && !dev->save_failed && memcmp(now, dev->rig_kept, sizeof now) == 0) {
        flags |= ROD_RIG_FLAG_STORED;
    }
    return flags;
}

bool rod_device_take_save(rod_device_t *dev, uint8_t out[ROD_RIG_STORE_SIZE])
{
    if (!dev->save_wanted) {
        return false;
    }
    dev->save_writing = true; /* before save_wanted falls: HELLO never sees both clear mid-write */
    __atomic_signal_fence(__ATOMIC_SEQ_CST);
    do { /* a SAVE_RIG during the copy rewrites the bytes and raises the flag again: copy again */
        dev->save_wanted = false;
        __atomic_signal_fence(__ATOMIC_SEQ_CST);
        for (size_t i = 0; i < ROD_RIG_STORE_SIZE; i++) {
            out[i] = dev->save_bytes[i];
        }
        __atomic_signal_fence(__ATOMIC_SEQ_CST);
    } while (dev->save_wanted);
    return true;
}

void rod_device_saved(rod_device_t *dev, bool ok)
{
    /* Ended either way: a write that failed must not hold ARM and IDENTIFY at BUSY until a power cycle; it only
     * keeps STORED off, until a SAVE_RIG's write reads back. */
    dev->save_failed = !ok;
    __atomic_signal_fence(__ATOMIC_SEQ_CST); /* before writing falls: HELLO never sees STORED for a failed write */
    dev->save_writing = false;
}

/* A numbered slot for the next frame; NULL (and one drop, one number used) when the ring is
 * full, so the host sees the loss as a sequence gap. */
static rod_event_t *new_event(rod_device_t *dev, uint8_t type, uint32_t time_us)
{
    uint32_t seq = dev->seq++;
    rod_event_t *ev = rod_link_claim_event(&dev->link);
    if (ev == NULL) {
        dev->ring_drops++;
        return NULL;
    }
    ev->type = type;
    ev->seq = seq;
    ev->time_us = time_us;
    return ev;
}

static uint8_t apply_command(rod_device_t *dev, const rod_msg_command_t *cmd)
{
    rod_control_t *c = &dev->control;
    if (cmd->status != ROD_ACK_OK) {
        return cmd->status; /* unknown type or bad length: refused, nothing changes */
    }
    switch (cmd->type) {
    case ROD_MSG_HEARTBEAT:
        return ROD_ACK_OK;
    case ROD_MSG_ARM:
        if (rig_saving(dev)) {
            return ROD_ACK_BUSY; /* the EEPROM write of a SAVE_RIG holds the main loop: never while armed */
        }
        return rod_control_arm(c, cmd->arm_mode);
    case ROD_MSG_DISARM:
        return rod_control_disarm(c);
    case ROD_MSG_CLEAR_FAULT:
        return rod_control_clear_fault(c);
    case ROD_MSG_SET:
        return rod_control_set(c, cmd->param, cmd->value);
    case ROD_MSG_HELLO_REQUEST:
        dev->hello_wanted = true;
        return ROD_ACK_OK;
    case ROD_MSG_SAVE_RIG:
        if (rod_mode_is_armed(c->mode)) {
            /* The EEPROM emulation holds loop() for milliseconds a write (longer when it compacts),
             * which an armed run spends without heartbeats counted and nearer the watchdog. */
            return ROD_ACK_BAD_STATE;
        }
        /* The settings as they are now: a SET after this one must not reach the stored record,
         * and the main loop must not encode a num / den pair this interrupt is changing. */
        rod_rig_encode(&c->settings.rig, dev->save_bytes);
        memcpy(dev->rig_kept, dev->save_bytes, sizeof dev->rig_kept);
        dev->rig_corrupt = 0u;
        __atomic_signal_fence(__ATOMIC_SEQ_CST);
        dev->save_wanted = true; /* STORED waits for this write, whatever the last one did */
        dev->save_failed = false;
        return ROD_ACK_OK;
    case ROD_MSG_IDENTIFY: {
        if (rig_saving(dev)) {
            return ROD_ACK_BUSY;
        }
        rod_identify_request_t req = {cmd->excitation, cmd->seed, cmd->amplitude, cmd->duration,
                                      cmd->shape1, cmd->shape2};
        return rod_control_identify(c, &req);
    }
    default:
        return ROD_ACK_UNKNOWN_COMMAND;
    }
}

static void latch_board_fault(rod_device_t *dev, rod_outputs_t *out)
{
    if (dev->board_fault == ROD_REASON_NONE) {
        return;
    }
    dev->control.mode = ROD_MODE_FAULT;
    dev->control.reason = dev->board_fault;
    if (out != NULL) {
        out->enable = false;
        out->duty = 0.0f;
        out->torque = 0.0f;
    }
}

static void handle_commands(rod_device_t *dev, uint32_t now_us)
{
    rod_msg_command_t cmd;
    while (rod_link_take_command(&dev->link, &cmd)) {
        uint8_t result = apply_command(dev, &cmd);
        latch_board_fault(dev, NULL);  /* a CLEAR_FAULT cannot leave it, nor open the door to an ARM */
        rod_event_t *ev = new_event(dev, ROD_MSG_ACK, now_us);
        if (ev != NULL) {
            ev->u.ack.command = cmd.type;
            ev->u.ack.result = result;
            ev->u.ack.command_seq = cmd.seq;
            ev->u.ack.mode = dev->control.mode;
            rod_link_publish_event(&dev->link);
        }
    }
}

static void queue_telemetry(rod_device_t *dev, uint32_t now_us)
{
    const rod_control_t *c = &dev->control;
    rod_event_t *ev = new_event(dev, ROD_MSG_TELEMETRY, now_us);
    if (ev == NULL) {
        return;
    }
    rod_msg_telemetry_t *m = &ev->u.telemetry.msg;
    m->mode = c->mode;
    m->reason = c->reason;
    m->flags = rod_control_flags(c);
    m->n = ROD_N;
    m->encoder_count = c->count;
    m->base_rate = c->rate;
    m->torque = c->torque;
    m->duty = c->duty;
    m->step_us = (uint16_t)(c->last_step_us > 0xFFFFu ? 0xFFFFu : c->last_step_us);
    m->overruns = c->overruns;
    m->frames_dropped = dev->ring_drops + dev->link.tx_drops;
    m->rx_errors = dev->link.rx_errors;
    rod_control_estimate(c, ev->u.telemetry.theta_hat, ev->u.telemetry.rate_hat);
    m->theta_hat = ev->u.telemetry.theta_hat;
    m->rate_hat = ev->u.telemetry.rate_hat;
    rod_link_publish_event(&dev->link);
}

#if ROD_NY > 1
static void queue_imu(rod_device_t *dev, uint32_t now_us)
{
    const rod_control_t *c = &dev->control;
    rod_event_t *ev = new_event(dev, ROD_MSG_IMU, now_us);
    if (ev == NULL) {
        return;
    }
    rod_msg_imu_t *m = &ev->u.imu;
    bool balancing = c->mode == ROD_MODE_BALANCE;
    m->gyro = c->imu_reading.gyro;
    m->accel_x = c->imu_reading.accel_x;
    m->accel_y = c->imu_reading.accel_y;
    m->gyro_bias = balancing ? c->obs.a[ROD_OBS_GYRO_BIAS] : c->imu.gyro_bias;
    m->encoder_offset = balancing ? c->obs.a[ROD_OBS_ENCODER_OFFSET] : 0.0f;
    m->status = (uint8_t)((c->imu_reading.fresh ? ROD_IMU_FLAG_FRESH : 0u) | (c->imu_good ? ROD_IMU_FLAG_GOOD : 0u)
                          | (c->imu.bias_known ? ROD_IMU_FLAG_BIAS_KNOWN : 0u));
    m->bad_run = (uint16_t)(c->imu.bad_run > 0xFFFFu ? 0xFFFFu : c->imu.bad_run);
    rod_link_publish_event(&dev->link);
}
#endif

static void queue_hello(rod_device_t *dev, uint32_t now_us)
{
    const rod_control_t *c = &dev->control;
    rod_event_t *ev = new_event(dev, ROD_MSG_HELLO, now_us);
    if (ev == NULL) {
        return;
    }
    rod_msg_hello_t *h = &ev->u.hello;
    h->fw_major = ROD_FW_VERSION_MAJOR;
    h->fw_minor = ROD_FW_VERSION_MINOR;
    h->fw_patch = ROD_FW_VERSION_PATCH;
    h->gains_schema = ROD_GAINS_SCHEMA_VERSION;
    h->n = ROD_N;
    h->mode = c->mode;
    h->reason = c->reason;
    h->rig = rig_flags(dev);
    h->period_us = ROD_LOOP_PERIOD_US;
    h->decimation = c->settings.decimation;
    h->swing_amplitude = c->settings.swing_amplitude;
    h->swing_angle = c->settings.swing_angle;
    h->catch_angle = c->settings.catch_angle;
    h->heartbeat_timeout = c->settings.heartbeat_timeout;
    h->torque_max = ROD_TORQUE_MAX_NM;
    for (int i = 0; i < 32; i++) {
        h->header_sha256[i] = gains_sha256[i];
    }
    h->counts_num = (uint32_t)c->settings.rig.counts.num;
    h->counts_den = (uint16_t)c->settings.rig.counts.den;
    rod_link_publish_event(&dev->link);
}

void rod_device_board_fault(rod_device_t *dev, uint8_t reason)
{
    dev->board_fault = reason;
}

void rod_device_step(rod_device_t *dev, const rod_inputs_t *in, rod_outputs_t *out)
{
    /* Read the heartbeat count before the commands: the main loop counts a frame before it
     * queues it, so every command seen here has its heartbeat counted too. */
    uint32_t heartbeats = dev->link.heartbeats;
    latch_board_fault(dev, NULL);  /* before the commands, so an ARM is refused in FAULT */
    handle_commands(dev, in->now_us);
    rod_control_step(&dev->control, in, heartbeats, out);
    latch_board_fault(dev, out);

    if (++dev->steps_since_telemetry >= dev->control.settings.decimation) {
        dev->steps_since_telemetry = 0;
        queue_telemetry(dev, in->now_us);
#if ROD_NY > 1
        queue_imu(dev, in->now_us);
#endif
    }
    if (++dev->steps_since_hello >= ROD_HELLO_INTERVAL_STEPS) {
        dev->hello_wanted = true;
    }
    if (dev->hello_wanted) {
        dev->hello_wanted = false;
        dev->steps_since_hello = 0;
        queue_hello(dev, in->now_us);
    }
}

size_t rod_device_rx(rod_device_t *dev, const uint8_t *data, size_t n)
{
    return rod_link_rx(&dev->link, data, n);
}

size_t rod_device_tx(rod_device_t *dev, uint8_t *out, size_t cap)
{
    return rod_link_tx(&dev->link, out, cap);
}

void rod_device_count_tx_drop(rod_device_t *dev)
{
    rod_link_count_tx_drop(&dev->link);
}

bool rod_device_post_command(rod_device_t *dev, const rod_msg_command_t *cmd)
{
    return rod_link_post_command(&dev->link, cmd);
}

void rod_device_heartbeat(rod_device_t *dev)
{
    rod_link_heartbeat(&dev->link);
}
