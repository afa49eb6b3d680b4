/* rod_protocol.h -- rodlink v1 codec: COBS framing, CRC-16/CCITT-FALSE, message encode/decode.
 *
 * Portable C11, float only, no allocation, no Arduino. The wire layout (message types, codes,
 * payload offsets and sizes) lives in firmware/protocol/rodlink.toml; rod_protocol_defs.h is
 * generated from it by `rodctl protocol` (docs/protocol.md has the byte tables).
 *
 * Frame on the wire = COBS(packet) 0x00, packet = header(10) | payload | crc16 (LE, over header+payload).
 * Header: 0 u8 version | 1 u8 type | 2 u32 seq | 6 u32 time_us. All fields little-endian.
 */
#ifndef ROD_PROTOCOL_H
#define ROD_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#include "rod_protocol_defs.h" /* generated */

#ifdef __cplusplus
extern "C" {
#endif

/* ---- messages ----------------------------------------------------------------------------- */

/* Device -> host, one per `decimation` control steps. theta_hat/rate_hat point at n floats each
 * (n <= ROD_PROTO_MAX_N); they are read only during the encode call. */
typedef struct {
    uint8_t mode, reason, flags, n; /* ROD_MODE_*, ROD_REASON_*, ROD_TLM_FLAG_* */
    int32_t encoder_count;
    float base_rate, torque, duty;  /* [rad/s], [N m], [-1..1] */
    uint16_t step_us;               /* CPU time of the previous control step [us] */
    uint32_t overruns, frames_dropped, rx_errors;
    const float *theta_hat;         /* [rad], pi upright */
    const float *rate_hat;          /* [rad/s] */
} rod_msg_telemetry_t;

/* Device -> host, on HELLO_REQUEST (and at start-up). */
typedef struct {
    uint8_t fw_major, fw_minor, fw_patch, gains_schema, n, mode, reason;
    uint8_t rig; /* ROD_RIG_FLAG_*: the signs in use and their source */
    uint32_t period_us;
    uint16_t decimation;
    float swing_amplitude, swing_angle, catch_angle, heartbeat_timeout, torque_max;
    uint8_t header_sha256[32];
    uint32_t counts_num; /* encoder counts per output turn = counts_num / counts_den */
    uint16_t counts_den;
} rod_msg_hello_t;

/* Device -> host, after each telemetry frame of a firmware with the tip IMU. */
typedef struct {
    float gyro, accel_x, accel_y; /* the sample [rad/s, m/s^2], rod frame */
    float gyro_bias;              /* [rad/s] */
    float encoder_offset;         /* [rad] */
    uint8_t status;               /* ROD_IMU_FLAG_* */
    uint16_t bad_run;             /* unusable samples in a row */
} rod_msg_imu_t;

/* Device -> host, one per command frame the device received (CRC-valid). */
typedef struct {
    uint8_t command, result;  /* command = the command's message type; result = ROD_ACK_* */
    uint32_t command_seq;     /* the command frame's seq */
    uint8_t mode;             /* mode after the command */
} rod_msg_ack_t;

/* Host -> device command (HEARTBEAT, ARM, DISARM, CLEAR_FAULT, SET, HELLO_REQUEST, IDENTIFY, SAVE_RIG).
 * status: ROD_ACK_OK, or ROD_ACK_UNKNOWN_COMMAND / ROD_ACK_BAD_LENGTH for a CRC-valid frame the
 * device must refuse. The codec checks only type and payload length; the values (arm_mode 1 or 2,
 * param 1..5, value finite and in range) are for the device to judge (ROD_ACK_BAD_VALUE).
 * arm_mode is set for ARM, param/value for SET, excitation..shape2 for IDENTIFY; unused fields are 0. */
typedef struct {
    uint8_t type;
    uint32_t seq, time_us;
    uint8_t status;
    uint8_t arm_mode;
    uint8_t param;
    float value;
    uint8_t excitation;       /* IDENTIFY: ROD_EXCITATION_* */
    uint16_t seed;            /* IDENTIFY: PRBS LFSR start state */
    float amplitude, duration; /* IDENTIFY: [N m], [s] */
    float shape1, shape2;     /* IDENTIFY: per excitation (rodlink.toml) */
} rod_msg_command_t;

/* ---- primitives --------------------------------------------------------------------------- */

/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0); "123456789" -> 0x29B1. */
uint16_t rod_crc16(const uint8_t *data, size_t n);

/* COBS. Encode writes no delimiter; returns the encoded length, 0 if cap is too small.
 * The encoded length is at most ROD_COBS_MAX_ENCODED(n). in and out must not overlap. */
size_t rod_cobs_encode(const uint8_t *in, size_t n, uint8_t *out, size_t cap);
/* Decode one COBS block (without its 0x00 delimiter); returns the decoded length, 0 on malformed
 * input (a zero byte, a code running past the end, empty input) or when cap is too small.
 * out may equal in (decoding in place is safe); otherwise they must not overlap. */
size_t rod_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t cap);

/* ---- encoders: each writes a complete wire frame (COBS + 0x00) and returns its length, ---- */
/* ---- or 0 if cap is too small (or n > ROD_PROTO_MAX_N, or an unknown command type).     ---- */
/* A telemetry frame for n is at most ROD_TELEMETRY_FRAME_MAX(n) bytes.                          */

size_t rod_proto_encode_telemetry(const rod_msg_telemetry_t *m, uint32_t seq, uint32_t time_us, uint8_t *out, size_t cap);
size_t rod_proto_encode_hello(const rod_msg_hello_t *m, uint32_t seq, uint32_t time_us, uint8_t *out, size_t cap);
size_t rod_proto_encode_ack(const rod_msg_ack_t *m, uint32_t seq, uint32_t time_us, uint8_t *out, size_t cap);
size_t rod_proto_encode_imu(const rod_msg_imu_t *m, uint32_t seq, uint32_t time_us, uint8_t *out, size_t cap);
/* Host side (used by the SIL and tests): m->type, m->seq, m->time_us and arm_mode (ARM),
 * param/value (SET) or excitation..shape2 (IDENTIFY); m->status is ignored. */
size_t rod_proto_encode_command(const rod_msg_command_t *m, uint8_t *out, size_t cap);

/* ---- device receive path ------------------------------------------------------------------ */

/* A frame accumulator fed with arbitrary chunks of bytes. */
typedef struct {
    uint8_t buf[ROD_PROTO_MAX_FRAME];
    size_t len;
    uint8_t discarding; /* an oversize frame is being skipped up to its 0x00 */
    uint32_t errors;    /* corrupt frames dropped: bad COBS, CRC, version, too short, too long */
} rod_proto_rx_t;

void rod_proto_rx_init(rod_proto_rx_t *rx);

/* Consumes bytes from data[0..n) up to and including the end of the first complete frame.
 * Returns 1 and fills *out when a CRC-valid frame of this protocol version ended: out->status is
 * ROD_ACK_OK for a host->device command with the right payload length, ROD_ACK_BAD_LENGTH for a
 * command type with the wrong payload length, ROD_ACK_UNKNOWN_COMMAND for any other type.
 * Returns 0 when all n bytes were consumed without completing a valid frame.
 * Corrupt frames (bad COBS, CRC, version, too short, too long) are dropped and counted in
 * rx->errors; decoding resumes at the next 0x00 (an empty frame, 0x00 0x00, is not an error).
 * *consumed is set to the bytes used, so the caller can call again with the rest.
 * Never reads or writes out of bounds; data may be NULL when n == 0. */
int rod_proto_rx_feed(rod_proto_rx_t *rx, const uint8_t *data, size_t n, size_t *consumed, rod_msg_command_t *out);

/* ---- generic decode (host tools, SIL, tests) ---------------------------------------------- */

/* Results of the decoders below (0 = ok, negative = the frame is unusable). */
#define ROD_DECODE_OK 0
#define ROD_DECODE_COBS (-1)    /* malformed COBS */
#define ROD_DECODE_SHORT (-2)   /* shorter than header + crc */
#define ROD_DECODE_LONG (-3)    /* longer than ROD_PROTO_MAX_PACKET */
#define ROD_DECODE_CRC (-4)     /* CRC mismatch */
#define ROD_DECODE_VERSION (-5) /* version != ROD_PROTO_VERSION */
#define ROD_DECODE_TYPE (-6)    /* not the message type asked for */
#define ROD_DECODE_LENGTH (-7)  /* payload length does not fit the type (or n > max_n) */

/* One checked packet: payload points into the packet it was parsed from. */
typedef struct {
    uint8_t version, type;
    uint32_t seq, time_us;
    const uint8_t *payload;
    size_t payload_len;
} rod_packet_t;

/* Checks a COBS-decoded packet (length, CRC, version) and fills *p. */
int rod_proto_parse_packet(const uint8_t *pkt, size_t n, rod_packet_t *p);
/* COBS-decodes one frame (with or without its trailing 0x00) into pkt_buf (cap bytes; use
 * ROD_PROTO_MAX_PACKET), then parses it. */
int rod_proto_decode_frame(const uint8_t *frame, size_t n, uint8_t *pkt_buf, size_t cap, rod_packet_t *p);

/* Payload decoders. decode_telemetry copies n floats into theta_hat[] and rate_hat[] (each with
 * room for max_n) and points m->theta_hat/rate_hat at them. */
int rod_proto_decode_telemetry(const rod_packet_t *p, rod_msg_telemetry_t *m, float *theta_hat, float *rate_hat, size_t max_n);
int rod_proto_decode_hello(const rod_packet_t *p, rod_msg_hello_t *m);
int rod_proto_decode_ack(const rod_packet_t *p, rod_msg_ack_t *m);
int rod_proto_decode_imu(const rod_packet_t *p, rod_msg_imu_t *m);
/* Fills *m from any packet, status as rod_proto_rx_feed gives it; returns ROD_DECODE_OK. */
int rod_proto_decode_command(const rod_packet_t *p, rod_msg_command_t *m);

#ifdef __cplusplus
}
#endif

#endif /* ROD_PROTOCOL_H */
