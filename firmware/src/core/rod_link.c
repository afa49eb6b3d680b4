/* rod_link.c -- host frames to commands, events to frames, across the two rings. */
#include "rod_link.h"

ROD_STATIC_ASSERT(ROD_N <= ROD_PROTO_MAX_N, "telemetry carries at most ROD_PROTO_MAX_N edges");
ROD_STATIC_ASSERT(ROD_LINK_FRAME_MAX <= ROD_PROTO_MAX_FRAME, "frame bound");

void rod_link_init(rod_link_t *l)
{
    rod_spsc_init(&l->command_ring);
    rod_spsc_init(&l->event_ring);
    l->heartbeats = 0;
    l->rx_errors = 0;
    l->tx_drops = 0;
    rod_proto_rx_init(&l->rx);
}

/* ---- main loop ---- */

void rod_link_heartbeat(rod_link_t *l)
{
    l->heartbeats = l->heartbeats + 1u;
}

bool rod_link_post_command(rod_link_t *l, const rod_msg_command_t *cmd)
{
    int32_t i = rod_spsc_claim(&l->command_ring, ROD_COMMAND_RING_SIZE);
    if (i < 0) {
        return false;
    }
    /* Heartbeat before the command: a step that sees the command has seen its heartbeat, so an
     * arm after a long silence never trips on the stale heartbeat. */
    if (cmd->status == ROD_ACK_OK) {
        rod_link_heartbeat(l);
    }
    l->commands[i] = *cmd;
    rod_spsc_publish(&l->command_ring);
    return true;
}

size_t rod_link_rx(rod_link_t *l, const uint8_t *data, size_t n)
{
    size_t used = 0;
    while (used < n && !rod_spsc_full(&l->command_ring, ROD_COMMAND_RING_SIZE)) {
        size_t consumed = 0;
        rod_msg_command_t cmd;
        int got = rod_proto_rx_feed(&l->rx, data + used, n - used, &consumed, &cmd);
        used += consumed;
        if (got) {
            (void)rod_link_post_command(l, &cmd); /* space was checked above */
        }
        if (consumed == 0) {
            break;
        }
    }
    l->rx_errors = l->rx.errors;
    return used;
}

size_t rod_link_tx(rod_link_t *l, uint8_t *out, size_t cap)
{
    for (;;) {
        int32_t i = rod_spsc_peek(&l->event_ring, ROD_EVENT_RING_SIZE);
        if (i < 0) {
            return 0;
        }
        rod_event_t *ev = &l->events[i];
        size_t len = 0;
        switch (ev->type) {
        case ROD_MSG_TELEMETRY:
            ev->u.telemetry.msg.theta_hat = ev->u.telemetry.theta_hat;
            ev->u.telemetry.msg.rate_hat = ev->u.telemetry.rate_hat;
            len = rod_proto_encode_telemetry(&ev->u.telemetry.msg, ev->seq, ev->time_us, out, cap);
            break;
        case ROD_MSG_HELLO:
            len = rod_proto_encode_hello(&ev->u.hello, ev->seq, ev->time_us, out, cap);
            break;
        case ROD_MSG_ACK:
            len = rod_proto_encode_ack(&ev->u.ack, ev->seq, ev->time_us, out, cap);
            break;
        case ROD_MSG_IMU:
            len = rod_proto_encode_imu(&ev->u.imu, ev->seq, ev->time_us, out, cap);
            break;
        default:
            break;
        }
        rod_spsc_release(&l->event_ring);
        if (len > 0) {
            return len;
        }
        rod_link_count_tx_drop(l);
    }
}

void rod_link_count_tx_drop(rod_link_t *l)
{
    l->tx_drops = l->tx_drops + 1u;
}

/* ---- control step ---- */

bool rod_link_take_command(rod_link_t *l, rod_msg_command_t *out)
{
    int32_t i = rod_spsc_peek(&l->command_ring, ROD_COMMAND_RING_SIZE);
    if (i < 0) {
        return false;
    }
    *out = l->commands[i];
    rod_spsc_release(&l->command_ring);
    return true;
}

rod_event_t *rod_link_claim_event(rod_link_t *l)
{
    int32_t i = rod_spsc_claim(&l->event_ring, ROD_EVENT_RING_SIZE);
    return i < 0 ? NULL : &l->events[i];
}

void rod_link_publish_event(rod_link_t *l)
{
    rod_spsc_publish(&l->event_ring);
}
