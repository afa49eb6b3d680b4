/* rod_protocol.c -- rodlink v1 codec (see rod_protocol.h; layout: firmware/protocol/rodlink.toml).
 *
 * Portable C11, float only, no allocation. Written for a Cortex-M4 built with -mno-unaligned-access:
 * every multi-byte field is stored and loaded with byte shifts, so no pointer is ever cast to a wider
 * type. Hot path (one telemetry frame per control period): the packet is written straight into the
 * output buffer one byte past the start, and as each byte is stored it is folded into the CRC and,
 * if it is 0x00, linked into the COBS chain (below 254 bytes COBS only turns each 0x00 into the
 * distance to the next one), so the frame is finished when its last byte is written: one pass, no
 * second buffer, no memcpy. About 800 Cortex-M4 instructions for an n = 5 telemetry frame
 * (tests/c/icount_telemetry.c).
 */
#include "rod_protocol.h"

#include <string.h>

#if defined(__GNUC__)
#define ROD_UNLIKELY(x) __builtin_expect(!!(x), 0)
#define ROD_INLINE static inline __attribute__((always_inline))
/* One register value for a byte that is both stored and fed to the CRC (else GCC extracts it twice). */
#define ROD_MATERIALIZE(x) __asm__("" : "+r"(x))
#else
#define ROD_UNLIKELY(x) (x)
#define ROD_INLINE static inline
#define ROD_MATERIALIZE(x) ((void)0)
#endif

#if ROD_PROTO_HEADER_SIZE != 10u || ROD_PROTO_CRC_SIZE != 2u || ROD_HDR_OFF_SEQ != 2u || ROD_HDR_OFF_TIME_US != 6u
#error "rod_protocol.c implements the 10-byte v1 header: regenerate rod_protocol_defs.h or update the codec"
#endif

/* ---- CRC-16/CCITT-FALSE, byte-wise table (poly 0x1021, MSB first), const so it stays in flash ----
 * The running CRC is kept in the upper half of a 32-bit word (c = crc << 16) and the table holds
 * crc_table[i] << 16, so one step is three instructions on a Cortex-M4 (eor, ldr, eor) with no
 * masking: c >> 24 is already 8 bits and c << 8 drops the byte just consumed. */

static const uint32_t crc_table[256] = {
    0x00000000u, 0x10210000u, 0x20420000u, 0x30630000u, 0x40840000u, 0x50A50000u, 0x60C60000u, 0x70E70000u,
    0x81080000u, 0x91290000u, 0xA14A0000u, 0xB16B0000u, 0xC18C0000u, 0xD1AD0000u, 0xE1CE0000u, 0xF1EF0000u,
    0x12310000u, 0x02100000u, 0x32730000u, 0x22520000u, 0x52B50000u, 0x42940000u, 0x72F70000u, 0x62D60000u,
    0x93390000u, 0x83180000u, 0xB37B0000u, 0xA35A0000u, 0xD3BD0000u, 0xC39C0000u, 0xF3FF0000u, 0xE3DE0000u,
    0x24620000u, 0x34430000u, 0x04200000u, 0x14010000u, 0x64E60000u, 0x74C70000u, 0x44A40000u, 0x54850000u,
    0xA56A0000u, 0xB54B0000u, 0x85280000u, 0x95090000u, 0xE5EE0000u, 0xF5CF0000u, 0xC5AC0000u, 0xD58D0000u,
    0x36530000u, 0x26720000u, 0x16110000u, 0x06300000u, 0x76D70000u, 0x66F60000u, 0x56950000u, 0x46B40000u,
    0xB75B0000u, 0xA77A0000u, 0x97190000u, 0x87380000u, 0xF7DF0000u, 0xE7FE0000u, 0xD79D0000u, 0xC7BC0000u,
    0x48C40000u, 0x58E50000u, 0x68860000u, 0x78A70000u, 0x08400000u, 0x18610000u, 0x28020000u, 0x38230000u,
    0xC9CC0000u, 0xD9ED0000u, 0xE98E0000u, 0xF9AF0000u, 0x89480000u, 0x99690000u, 0xA90A0000u, 0xB92B0000u,
    0x5AF50000u, 0x4AD40000u, 0x7AB70000u, 0x6A960000u, 0x1A710000u, 0x0A500000u, 0x3A330000u, 0x2A120000u,
    0xDBFD0000u, 0xCBDC0000u, 0xFBBF0000u, 0xEB9E0000u, 0x9B790000u, 0x8B580000u, 0xBB3B0000u, 0xAB1A0000u,
    0x6CA60000u, 0x7C870000u, 0x4CE40000u, 0x5CC50000u, 0x2C220000u, 0x3C030000u, 0x0C600000u, 0x1C410000u,
    0xEDAE0000u, 0xFD8F0000u, 0xCDEC0000u, 0xDDCD0000u, 0xAD2A0000u, 0xBD0B0000u, 0x8D680000u, 0x9D490000u,
    0x7E970000u, 0x6EB60000u, 0x5ED50000u, 0x4EF40000u, 0x3E130000u, 0x2E320000u, 0x1E510000u, 0x0E700000u,
    0xFF9F0000u, 0xEFBE0000u, 0xDFDD0000u, 0xCFFC0000u, 0xBF1B0000u, 0xAF3A0000u, 0x9F590000u, 0x8F780000u,
    0x91880000u, 0x81A90000u, 0xB1CA0000u, 0xA1EB0000u, 0xD10C0000u, 0xC12D0000u, 0xF14E0000u, 0xE16F0000u,
    0x10800000u, 0x00A10000u, 0x30C20000u, 0x20E30000u, 0x50040000u, 0x40250000u, 0x70460000u, 0x60670000u,
    0x83B90000u, 0x93980000u, 0xA3FB0000u, 0xB3DA0000u, 0xC33D0000u, 0xD31C0000u, 0xE37F0000u, 0xF35E0000u,
    0x02B10000u, 0x12900000u, 0x22F30000u, 0x32D20000u, 0x42350000u, 0x52140000u, 0x62770000u, 0x72560000u,
    0xB5EA0000u, 0xA5CB0000u, 0x95A80000u, 0x85890000u, 0xF56E0000u, 0xE54F0000u, 0xD52C0000u, 0xC50D0000u,
    0x34E20000u, 0x24C30000u, 0x14A00000u, 0x04810000u, 0x74660000u, 0x64470000u, 0x54240000u, 0x44050000u,
    0xA7DB0000u, 0xB7FA0000u, 0x87990000u, 0x97B80000u, 0xE75F0000u, 0xF77E0000u, 0xC71D0000u, 0xD73C0000u,
    0x26D30000u, 0x36F20000u, 0x06910000u, 0x16B00000u, 0x66570000u, 0x76760000u, 0x46150000u, 0x56340000u,
    0xD94C0000u, 0xC96D0000u, 0xF90E0000u, 0xE92F0000u, 0x99C80000u, 0x89E90000u, 0xB98A0000u, 0xA9AB0000u,
    0x58440000u, 0x48650000u, 0x78060000u, 0x68270000u, 0x18C00000u, 0x08E10000u, 0x38820000u, 0x28A30000u,
    0xCB7D0000u, 0xDB5C0000u, 0xEB3F0000u, 0xFB1E0000u, 0x8BF90000u, 0x9BD80000u, 0xABBB0000u, 0xBB9A0000u,
    0x4A750000u, 0x5A540000u, 0x6A370000u, 0x7A160000u, 0x0AF10000u, 0x1AD00000u, 0x2AB30000u, 0x3A920000u,
    0xFD2E0000u, 0xED0F0000u, 0xDD6C0000u, 0xCD4D0000u, 0xBDAA0000u, 0xAD8B0000u, 0x9DE80000u, 0x8DC90000u,
    0x7C260000u, 0x6C070000u, 0x5C640000u, 0x4C450000u, 0x3CA20000u, 0x2C830000u, 0x1CE00000u, 0x0CC10000u,
    0xEF1F0000u, 0xFF3E0000u, 0xCF5D0000u, 0xDF7C0000u, 0xAF9B0000u, 0xBFBA0000u, 0x8FD90000u, 0x9FF80000u,
    0x6E170000u, 0x7E360000u, 0x4E550000u, 0x5E740000u, 0x2E930000u, 0x3EB20000u, 0x0ED10000u, 0x1EF00000u,
};

#define CRC_INIT_SHIFTED ((uint32_t)ROD_PROTO_CRC_INIT << 16)

ROD_INLINE uint32_t crc_step(uint32_t c, uint32_t b) { return (c << 8) ^ crc_table[(c >> 24) ^ b]; }

uint16_t rod_crc16(const uint8_t *data, size_t n)
{
    uint32_t c = CRC_INIT_SHIFTED;
    for (size_t i = 0; i < n; i++) {
        c = crc_step(c, data[i]);
    }
    return (uint16_t)(c >> 16);
}

/* ---- little-endian field reads through byte pointers (writes: wr_* below) ---- */

static inline uint32_t get_u16(const uint8_t *p) { return (uint32_t)p[0] | ((uint32_t)p[1] << 8); }
static inline uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static inline float get_f32(const uint8_t *p)
{
    uint32_t v = get_u32(p);
    float f;
    memcpy(&f, &v, sizeof f);
    return f;
}

/* ---- COBS ---- */

/* Encodes n bytes from in to out; out must have room for ROD_COBS_MAX_ENCODED(n) bytes. In place is
 * allowed when in == out + k with k >= n / 254 + 1: every write lands on a byte already read.
 * A block of 254 non-zero bytes that ends the input gets no extra code byte. */
static size_t cobs_encode_unchecked(const uint8_t *in, size_t n, uint8_t *out)
{
    const uint8_t *end = in + n;
    uint8_t *code_p = out;
    uint8_t *o = out + 1;
    uint32_t code = 1;
    while (in < end) {
        uint8_t b = *in++;
        if (b == 0u) {
            *code_p = (uint8_t)code;
            code_p = o++;
            code = 1;
        } else {
            *o++ = b;
            if (++code == 0xFFu) {
                *code_p = 0xFFu;
                if (in == end) {
                    return (size_t)(o - out);
                }
                code_p = o++;
                code = 1;
            }
        }
    }
    *code_p = (uint8_t)code;
    return (size_t)(o - out);
}

static size_t cobs_encoded_len(const uint8_t *in, size_t n)
{
    size_t len = 1;
    uint32_t code = 1;
    for (size_t i = 0; i < n; i++) {
        len++;
        if (in[i] == 0u) {
            code = 1;
        } else if (++code == 0xFFu && i + 1 < n) {
            len++;
            code = 1;
        }
    }
    return len;
}

size_t rod_cobs_encode(const uint8_t *in, size_t n, uint8_t *out, size_t cap)
{
    if (out == NULL || (in == NULL && n != 0u)) {
        return 0;
    }
    if (cap < ROD_COBS_MAX_ENCODED(n) && cap < cobs_encoded_len(in, n)) {
        return 0;
    }
    return cobs_encode_unchecked(in, n, out);
}

size_t rod_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t cap)
{
    if (in == NULL || out == NULL || n == 0u) {
        return 0;
    }
    size_t i = 0, o = 0;
    while (i < n) {
        uint32_t code = in[i++];
        if (code == 0u || i + code - 1u > n) {
            return 0; /* a zero inside the block, or a code that runs past the end */
        }
        size_t run = code - 1u;
        if (o + run > cap) {
            return 0;
        }
        for (size_t k = 0; k < run; k++) {
            uint8_t b = in[i + k];
            if (b == 0u) {
                return 0;
            }
            out[o + k] = b; /* o <= i - 1 always, so decoding in place is safe */
        }
        i += run;
        o += run;
        if (code != 0xFFu && i < n) {
            if (o >= cap) {
                return 0;
            }
            out[o++] = 0u;
        }
    }
    return o;
}

/* ---- frame assembly ---- */

/* Where the packet goes in out, or 0 if out cannot hold the worst-case frame for this packet.
 * packet = header + payload + crc; frame <= ROD_COBS_MAX_ENCODED(packet) + 1, exact below 254 bytes. */
static inline size_t frame_offset(size_t payload_len, size_t cap)
{
    size_t packet = ROD_PROTO_HEADER_SIZE + payload_len + ROD_PROTO_CRC_SIZE;
    if (cap < ROD_COBS_MAX_ENCODED(packet) + 1u) {
        return 0;
    }
    return packet / 254u + 1u;
}

/* Frame writer: the packet is written at out + off, each byte folded into the CRC as it is stored.
 * In link mode (off == 1: packet + CRC < 254 bytes, every frame but long telemetry) COBS needs one
 * code byte in front and each 0x00 replaced by the distance to the next 0x00 (or to the end), so
 * each zero is linked into that chain as it is written and the frame is complete after the CRC:
 * one pass, no second buffer. Otherwise the zeros stay and wr_finish COBS-encodes in place.
 * `link` is a compile-time constant in every wr_* call (the encoders are instantiated twice), so
 * the fast path costs per byte: extract, store, 3 CRC instructions, one test for zero. */
typedef struct {
    uint8_t *p;     /* next byte */
    uint8_t *last;  /* pending COBS code byte (link mode) */
    uint8_t *start; /* packet start */
    uint32_t c;     /* CRC << 16 */
} wr_t;

ROD_INLINE void wr_begin(wr_t *w, uint8_t *out, size_t off)
{
    w->p = out + off;
    w->last = out;
    w->start = out + off;
    w->c = CRC_INIT_SHIFTED;
}

ROD_INLINE void wr_u8(wr_t *w, uint32_t b, const int link) /* b < 256 */
{
    uint8_t *p = w->p;
    *p = (uint8_t)b;
    w->c = crc_step(w->c, b);
    if (link && ROD_UNLIKELY(b == 0u)) {
        *w->last = (uint8_t)(p - w->last);
        w->last = p;
    }
    w->p = p + 1;
}
ROD_INLINE void wr_u16(wr_t *w, uint32_t v, const int link)
{
    wr_u8(w, v & 0xFFu, link);
    wr_u8(w, (v >> 8) & 0xFFu, link);
}
ROD_INLINE void wr_u32(wr_t *w, uint32_t v, const int link)
{
    uint32_t b1 = (v >> 8) & 0xFFu, b2 = (v >> 16) & 0xFFu;
    ROD_MATERIALIZE(b1);
    ROD_MATERIALIZE(b2);
    wr_u8(w, v & 0xFFu, link);
    wr_u8(w, b1, link);
    wr_u8(w, b2, link);
    wr_u8(w, v >> 24, link);
}
ROD_INLINE void wr_f32(wr_t *w, float f, const int link)
{
    uint32_t v;
    memcpy(&v, &f, sizeof v); /* a register move */
    wr_u32(w, v, link);
}

ROD_INLINE void wr_header(wr_t *w, uint32_t type, uint32_t seq, uint32_t time_us, const int link)
{
    wr_u8(w, ROD_PROTO_VERSION, link);
    wr_u8(w, type, link);
    wr_u32(w, seq, link);
    wr_u32(w, time_us, link);
}

/* Appends the CRC, completes the COBS encoding and the delimiter; returns the frame length. */
ROD_INLINE size_t wr_finish(wr_t *w, uint8_t *out, const int link)
{
    uint32_t crc = w->c >> 16;
    wr_u8(w, crc & 0xFFu, link);
    wr_u8(w, crc >> 8, link);
    if (link) {
        *w->last = (uint8_t)(w->p - w->last);
        *w->p = 0u;
        return (size_t)(w->p - out) + 1u;
    }
    size_t n = cobs_encode_unchecked(w->start, (size_t)(w->p - w->start), out);
    out[n] = 0u;
    return n + 1u;
}

/* ---- encoders (each body is instantiated for link = 1 and link = 0) ---- */

ROD_INLINE size_t telemetry_body(const rod_msg_telemetry_t *m, uint32_t n, uint32_t seq, uint32_t time_us,
                                 uint8_t *out, size_t off, const int link)
{
    const float *theta = m->theta_hat, *rate = m->rate_hat;
    wr_t w;
    wr_begin(&w, out, off);
    wr_header(&w, ROD_MSG_TELEMETRY, seq, time_us, link);
    /* in payload order: ROD_TELEMETRY_OFF_* */
    wr_u8(&w, m->mode, link);
    wr_u8(&w, m->reason, link);
    wr_u8(&w, m->flags, link);
    wr_u8(&w, n, link);
    wr_u32(&w, (uint32_t)m->encoder_count, link);
    wr_f32(&w, m->base_rate, link);
    wr_f32(&w, m->torque, link);
    wr_f32(&w, m->duty, link);
    wr_u16(&w, m->step_us, link);
    wr_u16(&w, 0u, link); /* reserved */
    wr_u32(&w, m->overruns, link);
    wr_u32(&w, m->frames_dropped, link);
    wr_u32(&w, m->rx_errors, link);
    for (uint32_t i = 0; i < n; i++) {
        wr_f32(&w, theta[i], link);
    }
    for (uint32_t i = 0; i < n; i++) {
        wr_f32(&w, rate[i], link);
    }
    return wr_finish(&w, out, link);
}

size_t rod_proto_encode_telemetry(const rod_msg_telemetry_t *m, uint32_t seq, uint32_t time_us, uint8_t *out, size_t cap)
{
    uint32_t n = m->n;
    if (n > ROD_PROTO_MAX_N || out == NULL || (n != 0u && (m->theta_hat == NULL || m->rate_hat == NULL))) {
        return 0;
    }
    size_t off = frame_offset(ROD_TELEMETRY_PAYLOAD_SIZE(n), cap);
    if (off == 1u) {
        return telemetry_body(m, n, seq, time_us, out, off, 1);
    }
    return off == 0u ? 0u : telemetry_body(m, n, seq, time_us, out, off, 0);
}

/* Fixed-size messages are always short enough for link mode (checked at compile time). */
#define ROD_SHORT(payload) (ROD_PROTO_HEADER_SIZE + (payload) + ROD_PROTO_CRC_SIZE < 254u)
_Static_assert(ROD_SHORT(ROD_HELLO_PAYLOAD_SIZE) && ROD_SHORT(ROD_ACK_PAYLOAD_SIZE) && ROD_SHORT(ROD_IMU_PAYLOAD_SIZE) && ROD_SHORT(ROD_SET_PAYLOAD_SIZE) &&
                   ROD_SHORT(ROD_ARM_PAYLOAD_SIZE) && ROD_SHORT(ROD_IDENTIFY_PAYLOAD_SIZE),
               "fixed-size rodlink messages must stay below 254 bytes");

size_t rod_proto_encode_hello(const rod_msg_hello_t *m, uint32_t seq, uint32_t time_us, uint8_t *out, size_t cap)
{
    size_t off = frame_offset(ROD_HELLO_PAYLOAD_SIZE, cap);
    if (off == 0u || out == NULL) {
        return 0;
    }
    wr_t w;
    wr_begin(&w, out, off);
    wr_header(&w, ROD_MSG_HELLO, seq, time_us, 1);
    wr_u8(&w, m->fw_major, 1);
    wr_u8(&w, m->fw_minor, 1);
    wr_u8(&w, m->fw_patch, 1);
    wr_u8(&w, m->gains_schema, 1);
    wr_u8(&w, m->n, 1);
    wr_u8(&w, m->mode, 1);
    wr_u8(&w, m->reason, 1);
    wr_u8(&w, m->rig, 1);
    wr_u32(&w, m->period_us, 1);
    wr_u16(&w, m->decimation, 1);
    wr_u16(&w, 0u, 1); /* reserved2 */
    wr_f32(&w, m->swing_amplitude, 1);
    wr_f32(&w, m->swing_angle, 1);
    wr_f32(&w, m->catch_angle, 1);
    wr_f32(&w, m->heartbeat_timeout, 1);
    wr_f32(&w, m->torque_max, 1);
    for (uint32_t i = 0; i < ROD_HELLO_LEN_HEADER_SHA256; i++) {
        wr_u8(&w, m->header_sha256[i], 1);
    }
    wr_u32(&w, m->counts_num, 1);
    wr_u16(&w, m->counts_den, 1);
    wr_u16(&w, 0u, 1); /* reserved3 */
    return wr_finish(&w, out, 1);
}

size_t rod_proto_encode_ack(const rod_msg_ack_t *m, uint32_t seq, uint32_t time_us, uint8_t *out, size_t cap)
{
    size_t off = frame_offset(ROD_ACK_PAYLOAD_SIZE, cap);
    if (off == 0u || out == NULL) {
        return 0;
    }
    wr_t w;
    wr_begin(&w, out, off);
    wr_header(&w, ROD_MSG_ACK, seq, time_us, 1);
    wr_u8(&w, m->command, 1);
    wr_u8(&w, m->result, 1);
    wr_u32(&w, m->command_seq, 1);
    wr_u8(&w, m->mode, 1);
    wr_u8(&w, 0u, 1); /* reserved */
    return wr_finish(&w, out, 1);
}

size_t rod_proto_encode_imu(const rod_msg_imu_t *m, uint32_t seq, uint32_t time_us, uint8_t *out, size_t cap)
{
    size_t off = frame_offset(ROD_IMU_PAYLOAD_SIZE, cap);
    if (off == 0u || out == NULL) {
        return 0;
    }
    wr_t w;
    wr_begin(&w, out, off);
    wr_header(&w, ROD_MSG_IMU, seq, time_us, 1);
    wr_f32(&w, m->gyro, 1);
    wr_f32(&w, m->accel_x, 1);
    wr_f32(&w, m->accel_y, 1);
    wr_f32(&w, m->gyro_bias, 1);
    wr_f32(&w, m->encoder_offset, 1);
    wr_u8(&w, m->status, 1);
    wr_u8(&w, 0u, 1); /* reserved */
    wr_u16(&w, m->bad_run, 1);
    return wr_finish(&w, out, 1);
}

/* Payload length of a host->device command type, or -1 if the type is not a command. */
static int command_payload_size(uint32_t type)
{
    switch (type) {
    case ROD_MSG_HEARTBEAT: return (int)ROD_HEARTBEAT_PAYLOAD_SIZE;
    case ROD_MSG_ARM: return (int)ROD_ARM_PAYLOAD_SIZE;
    case ROD_MSG_DISARM: return (int)ROD_DISARM_PAYLOAD_SIZE;
    case ROD_MSG_CLEAR_FAULT: return (int)ROD_CLEAR_FAULT_PAYLOAD_SIZE;
    case ROD_MSG_SET: return (int)ROD_SET_PAYLOAD_SIZE;
    case ROD_MSG_HELLO_REQUEST: return (int)ROD_HELLO_REQUEST_PAYLOAD_SIZE;
    case ROD_MSG_IDENTIFY: return (int)ROD_IDENTIFY_PAYLOAD_SIZE;
    case ROD_MSG_SAVE_RIG: return (int)ROD_SAVE_RIG_PAYLOAD_SIZE;
    default: return -1;
    }
}

size_t rod_proto_encode_command(const rod_msg_command_t *m, uint8_t *out, size_t cap)
{
    int size = command_payload_size(m->type);
    if (size < 0 || out == NULL) {
        return 0;
    }
    size_t off = frame_offset((size_t)size, cap);
    if (off == 0u) {
        return 0;
    }
    wr_t w;
    wr_begin(&w, out, off);
    wr_header(&w, m->type, m->seq, m->time_us, 1);
    if (m->type == ROD_MSG_ARM) {
        wr_u8(&w, m->arm_mode, 1);
    } else if (m->type == ROD_MSG_SET) {
        wr_u8(&w, m->param, 1);
        wr_f32(&w, m->value, 1);
    } else if (m->type == ROD_MSG_IDENTIFY) {
        wr_u8(&w, m->excitation, 1);
        wr_u8(&w, 0u, 1); /* reserved */
        wr_u16(&w, m->seed, 1);
        wr_f32(&w, m->amplitude, 1);
        wr_f32(&w, m->duration, 1);
        wr_f32(&w, m->shape1, 1);
        wr_f32(&w, m->shape2, 1);
    }
    return wr_finish(&w, out, 1);
}

/* ---- decoders ---- */

int rod_proto_parse_packet(const uint8_t *pkt, size_t n, rod_packet_t *p)
{
    if (pkt == NULL || n < ROD_PROTO_HEADER_SIZE + ROD_PROTO_CRC_SIZE) {
        return ROD_DECODE_SHORT;
    }
    if (n > ROD_PROTO_MAX_PACKET) {
        return ROD_DECODE_LONG;
    }
    size_t len = n - ROD_PROTO_CRC_SIZE;
    if (rod_crc16(pkt, len) != get_u16(pkt + len)) {
        return ROD_DECODE_CRC;
    }
    if (pkt[ROD_HDR_OFF_VERSION] != ROD_PROTO_VERSION) {
        return ROD_DECODE_VERSION;
    }
    p->version = pkt[ROD_HDR_OFF_VERSION];
    p->type = pkt[ROD_HDR_OFF_TYPE];
    p->seq = get_u32(pkt + ROD_HDR_OFF_SEQ);
    p->time_us = get_u32(pkt + ROD_HDR_OFF_TIME_US);
    p->payload = pkt + ROD_PROTO_HEADER_SIZE;
    p->payload_len = len - ROD_PROTO_HEADER_SIZE;
    return ROD_DECODE_OK;
}

int rod_proto_decode_frame(const uint8_t *frame, size_t n, uint8_t *pkt_buf, size_t cap, rod_packet_t *p)
{
    if (frame != NULL && n > 0u && frame[n - 1u] == 0u) {
        n--; /* the delimiter */
    }
    size_t len = rod_cobs_decode(frame, n, pkt_buf, cap);
    if (len == 0u) {
        return ROD_DECODE_COBS;
    }
    return rod_proto_parse_packet(pkt_buf, len, p);
}

int rod_proto_decode_telemetry(const rod_packet_t *p, rod_msg_telemetry_t *m, float *theta_hat, float *rate_hat, size_t max_n)
{
    if (p->type != ROD_MSG_TELEMETRY) {
        return ROD_DECODE_TYPE;
    }
    const uint8_t *q = p->payload;
    if (p->payload_len < ROD_TELEMETRY_PAYLOAD_FIXED) {
        return ROD_DECODE_LENGTH;
    }
    uint32_t n = q[ROD_TELEMETRY_OFF_N];
    if (n > ROD_PROTO_MAX_N || n > max_n || p->payload_len != ROD_TELEMETRY_PAYLOAD_SIZE(n)) {
        return ROD_DECODE_LENGTH;
    }
    m->mode = q[ROD_TELEMETRY_OFF_MODE];
    m->reason = q[ROD_TELEMETRY_OFF_REASON];
    m->flags = q[ROD_TELEMETRY_OFF_FLAGS];
    m->n = (uint8_t)n;
    m->encoder_count = (int32_t)get_u32(q + ROD_TELEMETRY_OFF_ENCODER_COUNT);
    m->base_rate = get_f32(q + ROD_TELEMETRY_OFF_BASE_RATE);
    m->torque = get_f32(q + ROD_TELEMETRY_OFF_TORQUE);
    m->duty = get_f32(q + ROD_TELEMETRY_OFF_DUTY);
    m->step_us = (uint16_t)get_u16(q + ROD_TELEMETRY_OFF_STEP_US);
    m->overruns = get_u32(q + ROD_TELEMETRY_OFF_OVERRUNS);
    m->frames_dropped = get_u32(q + ROD_TELEMETRY_OFF_FRAMES_DROPPED);
    m->rx_errors = get_u32(q + ROD_TELEMETRY_OFF_RX_ERRORS);
    for (uint32_t i = 0; i < n; i++) {
        theta_hat[i] = get_f32(q + ROD_TELEMETRY_OFF_THETA_HAT + 4u * i);
        rate_hat[i] = get_f32(q + ROD_TELEMETRY_OFF_RATE_HAT(n) + 4u * i);
    }
    m->theta_hat = theta_hat;
    m->rate_hat = rate_hat;
    return ROD_DECODE_OK;
}

int rod_proto_decode_hello(const rod_packet_t *p, rod_msg_hello_t *m)
{
    if (p->type != ROD_MSG_HELLO) {
        return ROD_DECODE_TYPE;
    }
    if (p->payload_len != ROD_HELLO_PAYLOAD_SIZE) {
        return ROD_DECODE_LENGTH;
    }
    const uint8_t *q = p->payload;
    m->fw_major = q[ROD_HELLO_OFF_FW_MAJOR];
    m->fw_minor = q[ROD_HELLO_OFF_FW_MINOR];
    m->fw_patch = q[ROD_HELLO_OFF_FW_PATCH];
    m->gains_schema = q[ROD_HELLO_OFF_GAINS_SCHEMA];
    m->n = q[ROD_HELLO_OFF_N];
    m->mode = q[ROD_HELLO_OFF_MODE];
    m->reason = q[ROD_HELLO_OFF_REASON];
    m->rig = q[ROD_HELLO_OFF_RIG];
    m->period_us = get_u32(q + ROD_HELLO_OFF_PERIOD_US);
    m->decimation = (uint16_t)get_u16(q + ROD_HELLO_OFF_DECIMATION);
    m->swing_amplitude = get_f32(q + ROD_HELLO_OFF_SWING_AMPLITUDE);
    m->swing_angle = get_f32(q + ROD_HELLO_OFF_SWING_ANGLE);
    m->catch_angle = get_f32(q + ROD_HELLO_OFF_CATCH_ANGLE);
    m->heartbeat_timeout = get_f32(q + ROD_HELLO_OFF_HEARTBEAT_TIMEOUT);
    m->torque_max = get_f32(q + ROD_HELLO_OFF_TORQUE_MAX);
    memcpy(m->header_sha256, q + ROD_HELLO_OFF_HEADER_SHA256, ROD_HELLO_LEN_HEADER_SHA256);
    m->counts_num = get_u32(q + ROD_HELLO_OFF_COUNTS_NUM);
    m->counts_den = (uint16_t)get_u16(q + ROD_HELLO_OFF_COUNTS_DEN);
    return ROD_DECODE_OK;
}

int rod_proto_decode_ack(const rod_packet_t *p, rod_msg_ack_t *m)
{
    if (p->type != ROD_MSG_ACK) {
        return ROD_DECODE_TYPE;
    }
    if (p->payload_len != ROD_ACK_PAYLOAD_SIZE) {
        return ROD_DECODE_LENGTH;
    }
    const uint8_t *q = p->payload;
    m->command = q[ROD_ACK_OFF_COMMAND];
    m->result = q[ROD_ACK_OFF_RESULT];
    m->command_seq = get_u32(q + ROD_ACK_OFF_COMMAND_SEQ);
    m->mode = q[ROD_ACK_OFF_MODE];
    return ROD_DECODE_OK;
}

int rod_proto_decode_imu(const rod_packet_t *p, rod_msg_imu_t *m)
{
    if (p->type != ROD_MSG_IMU) {
        return ROD_DECODE_TYPE;
    }
    if (p->payload_len != ROD_IMU_PAYLOAD_SIZE) {
        return ROD_DECODE_LENGTH;
    }
    const uint8_t *q = p->payload;
    m->gyro = get_f32(q + ROD_IMU_OFF_GYRO);
    m->accel_x = get_f32(q + ROD_IMU_OFF_ACCEL_X);
    m->accel_y = get_f32(q + ROD_IMU_OFF_ACCEL_Y);
    m->gyro_bias = get_f32(q + ROD_IMU_OFF_GYRO_BIAS);
    m->encoder_offset = get_f32(q + ROD_IMU_OFF_ENCODER_OFFSET);
    m->status = q[ROD_IMU_OFF_STATUS];
    m->bad_run = (uint16_t)get_u16(q + ROD_IMU_OFF_BAD_RUN);
    return ROD_DECODE_OK;
}

int rod_proto_decode_command(const rod_packet_t *p, rod_msg_command_t *m)
{
    m->type = p->type;
    m->seq = p->seq;
    m->time_us = p->time_us;
    m->arm_mode = 0;
    m->param = 0;
    m->value = 0.0f;
    m->excitation = 0;
    m->seed = 0;
    m->amplitude = m->duration = m->shape1 = m->shape2 = 0.0f;
    int size = command_payload_size(p->type);
    if (size < 0) {
        m->status = ROD_ACK_UNKNOWN_COMMAND;
    } else if (p->payload_len != (size_t)size) {
        m->status = ROD_ACK_BAD_LENGTH;
    } else {
        m->status = ROD_ACK_OK;
        if (p->type == ROD_MSG_ARM) {
            m->arm_mode = p->payload[ROD_ARM_OFF_MODE];
        } else if (p->type == ROD_MSG_SET) {
            m->param = p->payload[ROD_SET_OFF_PARAM];
            m->value = get_f32(p->payload + ROD_SET_OFF_VALUE);
        } else if (p->type == ROD_MSG_IDENTIFY) {
            const uint8_t *q = p->payload;
            m->excitation = q[ROD_IDENTIFY_OFF_EXCITATION];
            m->seed = (uint16_t)get_u16(q + ROD_IDENTIFY_OFF_SEED);
            m->amplitude = get_f32(q + ROD_IDENTIFY_OFF_AMPLITUDE);
            m->duration = get_f32(q + ROD_IDENTIFY_OFF_DURATION);
            m->shape1 = get_f32(q + ROD_IDENTIFY_OFF_SHAPE1);
            m->shape2 = get_f32(q + ROD_IDENTIFY_OFF_SHAPE2);
        }
    }
    return ROD_DECODE_OK;
}

/* ---- device receive path ---- */

void rod_proto_rx_init(rod_proto_rx_t *rx)
{
    rx->len = 0;
    rx->discarding = 0;
    rx->errors = 0;
}

int rod_proto_rx_feed(rod_proto_rx_t *rx, const uint8_t *data, size_t n, size_t *consumed, rod_msg_command_t *out)
{
    size_t i = 0;
    while (i < n) {
        uint8_t b = data[i++];
        if (b != 0u) {
            if (rx->discarding) {
                continue;
            }
            if (rx->len >= sizeof rx->buf) {
                rx->discarding = 1; /* too long for any packet: skip to the next delimiter */
                rx->errors++;
                rx->len = 0;
                continue;
            }
            rx->buf[rx->len++] = b;
            continue;
        }
        /* delimiter */
        size_t len = rx->len;
        rx->len = 0;
        if (rx->discarding) {
            rx->discarding = 0; /* already counted */
            continue;
        }
        if (len == 0u) {
            continue; /* back-to-back delimiters: idle line, not an error */
        }
        rod_packet_t p;
        size_t plen = rod_cobs_decode(rx->buf, len, rx->buf, sizeof rx->buf);
        if (plen == 0u || rod_proto_parse_packet(rx->buf, plen, &p) != ROD_DECODE_OK) {
            rx->errors++;
            continue;
        }
        rod_proto_decode_command(&p, out);
        if (consumed != NULL) {
            *consumed = i;
        }
        return 1;
    }
    if (consumed != NULL) {
        *consumed = n;
    }
    return 0;
}
