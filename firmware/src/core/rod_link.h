/* rod_link.h -- the mailbox between the USB main loop and the control step, and the framing.
 *
 * Main loop (USB):  host bytes -> rod_link_rx -> decoded commands -> command ring
 *                                            -> heartbeats (one per valid command frame)
 *                   event ring -> rod_link_tx -> one encoded frame at a time
 * Control step:     rod_link_take_command, rod_link_claim_event / rod_link_publish_event
 *
 * Each ring has exactly one producer and one consumer (rod_spsc.h). Counters shared between
 * the two sides have a single writer each and are read whole (aligned 32-bit).
 */
#ifndef ROD_LINK_H
#define ROD_LINK_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "rod_config.h"
#include "rod_protocol.h"
#include "rod_spsc.h"

#ifdef __cplusplus
extern "C" {
#endif

/* A device->host frame as the step creates it: numbered and stamped, encoded later. */
typedef struct {
    uint8_t type; /* ROD_MSG_TELEMETRY, ROD_MSG_HELLO, ROD_MSG_ACK or ROD_MSG_IMU */
    uint32_t seq;
    uint32_t time_us;
    union {
        struct {
            rod_msg_telemetry_t msg; /* msg.theta_hat / rate_hat point at the arrays below */
            float theta_hat[ROD_N];
            float rate_hat[ROD_N];
        } telemetry;
        rod_msg_hello_t hello;
        rod_msg_ack_t ack;
        rod_msg_imu_t imu;
    } u;
} rod_event_t;

/* Largest frame rod_link_tx can return: size the board's TX buffer with this. */
#define ROD_LINK_FRAME_MAX \
    (ROD_TELEMETRY_FRAME_MAX(ROD_N) > ROD_HELLO_FRAME_MAX ? ROD_TELEMETRY_FRAME_MAX(ROD_N) : ROD_HELLO_FRAME_MAX)

typedef struct {
    /* main loop -> step */
    rod_msg_command_t commands[ROD_COMMAND_RING_SIZE];
    rod_spsc_t command_ring;
    volatile uint32_t heartbeats; /* valid host frames so far (main loop writes) */
    volatile uint32_t rx_errors;  /* corrupt host frames so far (main loop writes) */
    volatile uint32_t tx_drops;   /* frames the USB side could not send (main loop writes) */
    /* step -> main loop */
    rod_event_t events[ROD_EVENT_RING_SIZE];
    rod_spsc_t event_ring;
    /* main loop only */
    rod_proto_rx_t rx;
} rod_link_t;

void rod_link_init(rod_link_t *l);

/* ---- main loop ---- */

/* Decodes host bytes; every complete CRC-valid frame becomes a command (acked by the step),
 * and a well-formed one also counts as a heartbeat. Returns the bytes consumed: it stops early
 * while the command ring is full, and the caller offers the rest again later (so commands are
 * delayed by USB flow control, never lost). */
size_t rod_link_rx(rod_link_t *l, const uint8_t *data, size_t n);

/* Queues one command as if it had arrived from the host (counts as a heartbeat when its status
 * is ROD_ACK_OK). false when the command ring is full. */
bool rod_link_post_command(rod_link_t *l, const rod_msg_command_t *cmd);

/* A valid host frame arrived (rod_link_rx does this itself). */
void rod_link_heartbeat(rod_link_t *l);

/* Encodes the oldest pending event into out; returns its length, 0 when none is pending.
 * An event that does not fit cap is dropped and counted. */
size_t rod_link_tx(rod_link_t *l, uint8_t *out, size_t cap);

/* The caller could not send a frame rod_link_tx returned (USB busy). */
void rod_link_count_tx_drop(rod_link_t *l);

/* ---- control step ---- */

/* Oldest queued command into *out; false when none. */
bool rod_link_take_command(rod_link_t *l, rod_msg_command_t *out);

/* Slot for a new event, or NULL when the event ring is full. Fill it, then publish. */
rod_event_t *rod_link_claim_event(rod_link_t *l);
void rod_link_publish_event(rod_link_t *l);

#ifdef __cplusplus
}
#endif

#endif /* ROD_LINK_H */
