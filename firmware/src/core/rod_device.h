/* rod_device.h -- the whole firmware behind four calls: what the board (or the SIL) drives.
 *
 *   rod_device_init            once, before the timer starts
 *   rod_device_step            control timer interrupt, once per ROD_LOOP_PERIOD_US
 *   rod_device_rx              main loop: bytes from the host
 *   rod_device_tx              main loop: next frame for the host
 *   rod_device_count_tx_drop   main loop: that frame did not fit the USB buffer
 *
 * Step: commands queued by the main loop are applied (each acked), the control runs one
 * period (rod_control.h), then telemetry every `decimation` steps and a HELLO at start-up,
 * once per second, and on HELLO_REQUEST are queued for the main loop. Every device->host
 * frame takes its sequence number here, in creation order, so a frame lost anywhere (event
 * ring full, USB busy) shows as a gap, and in telemetry.frames_dropped.
 */
#ifndef ROD_DEVICE_H
#define ROD_DEVICE_H

#include <stddef.h>
#include <stdint.h>

#include "rod_control.h"
#include "rod_io.h"
#include "rod_link.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Largest frame rod_device_tx returns. */
#define ROD_DEVICE_FRAME_MAX ROD_LINK_FRAME_MAX

typedef struct {
    rod_control_t control; /* step only */
    rod_link_t link;       /* shared through its rings */
    uint32_t seq;          /* number of the next device->host frame (step only) */
    uint32_t ring_drops;   /* frames lost to a full event ring (step only) */
    uint32_t steps_since_telemetry;
    uint32_t steps_since_hello;
    bool hello_wanted;
    uint8_t board_fault; /* ROD_REASON_* the board reported (rod_device_board_fault), NONE normally */
    uint8_t rig_corrupt; /* ROD_RIG_FLAG_STORE_CORRUPT until SAVE_RIG, when storage held an unreadable record */
    uint8_t rig_kept[ROD_RIG_STORE_SIZE]; /* step only: the record in storage (rod_rig_encode), all 0 when none */
    volatile bool save_wanted; /* SAVE_RIG arrived; the main loop stores save_bytes */
    volatile bool save_writing; /* the main loop has taken save_bytes and not yet reported them written */
    volatile bool save_failed;  /* the last write did not read back: the record kept is not what storage holds */
    uint8_t save_bytes[ROD_RIG_STORE_SIZE]; /* the rig settings as SAVE_RIG found them (rod_rig_encode) */
} rod_device_t;

/* Power-on state: DISARMED, driver off, default settings. */
void rod_device_init(rod_device_t *dev);

/* One control period (timer interrupt). *out is what to apply now: enable=false means nEN
 * high and duty 0. */
void rod_device_step(rod_device_t *dev, const rod_inputs_t *in, rod_outputs_t *out);

/* Main loop: feed host bytes; returns how many were taken. Fewer than n only while the command
 * ring is full: offer the rest again on a later call. */
size_t rod_device_rx(rod_device_t *dev, const uint8_t *data, size_t n);

/* Main loop: writes the next frame for the host into out (cap >= ROD_DEVICE_FRAME_MAX) and
 * returns its length, or 0 when nothing is pending. */
size_t rod_device_tx(rod_device_t *dev, uint8_t *out, size_t cap);

/* Main loop: the frame rod_device_tx returned could not be written (USB buffer full). */
void rod_device_count_tx_drop(rod_device_t *dev);

/* Main loop: queue a command as if it came from the host (the SIL's host-less path); false
 * when the command ring is full. A command with status ROD_ACK_OK counts as a heartbeat. */
bool rod_device_post_command(rod_device_t *dev, const rod_msg_command_t *cmd);

/* Board: it cannot run the control as it should (e.g. ROD_REASON_NO_TIMER: its timer did not
 * start). From then on every step ends in FAULT with this reason, outputs off, and CLEAR_FAULT
 * cannot leave it: only a reset can. Steps keep answering the host, so HELLO and telemetry say why. */
void rod_device_board_fault(rod_device_t *dev, uint8_t reason);

/* Power-on, before the timer starts: the signs the board kept (rod_rig.h; NULL / 0 when it has
 * none), or the compiled defaults when it has none or they are unreadable. HELLO flags STORED while
 * the settings in use are the record in storage, so a SET after a power-on or a SAVE_RIG clears it. */
void rod_device_load_rig(rod_device_t *dev, const uint8_t *stored, size_t n, rod_rig_t defaults);

/* Main loop: after a SAVE_RIG, true once with the bytes to keep (ROD_RIG_STORE_SIZE) in out;
 * the board writes them to its storage (EEPROM), outside the control interrupt, then reports the
 * write with rod_device_saved. */
bool rod_device_take_save(rod_device_t *dev, uint8_t out[ROD_RIG_STORE_SIZE]);

/* Main loop: the bytes rod_device_take_save gave were written (ok: they read back as written). HELLO
 * flags STORED only from here; after a failed write it stays clear until a SAVE_RIG is written. */
void rod_device_saved(rod_device_t *dev, bool ok);

/* Main loop: count a valid host frame (keeps the heartbeat alive without sending one). */
void rod_device_heartbeat(rod_device_t *dev);

#ifdef __cplusplus
}
#endif

#endif /* ROD_DEVICE_H */
