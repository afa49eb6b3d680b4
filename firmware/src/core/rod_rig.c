/* rod_rig.c -- the stored wiring signs (rod_rig.h). */
#include "rod_rig.h"

#include <stdbool.h>

#include "rod_protocol.h"

#define LAYOUT_SIGNS 1u /* 8 bytes: the signs only */
#define BODY_SIGNS 6u
#define LAYOUT 2u
#define BODY 14u

static bool is_sign(int8_t s)
{
    return s == 1 || s == -1;
}

rod_rig_t rod_rig_defaults(int8_t encoder_sign, int8_t motor_sign)
{
    rod_rig_t rig = {encoder_sign, motor_sign, rod_counts_default()};
    return rig;
}

void rod_rig_encode(const rod_rig_t *rig, uint8_t out[ROD_RIG_STORE_SIZE])
{
    uint32_t num = (uint32_t)rig->counts.num;
    uint32_t den = (uint32_t)rig->counts.den;
    out[0] = (uint8_t)'R';
    out[1] = (uint8_t)'G';
    out[2] = LAYOUT;
    out[3] = (uint8_t)rig->encoder_sign;
    out[4] = (uint8_t)rig->motor_sign;
    out[5] = 0u;
    for (int i = 0; i < 4; i++) {
        out[6 + i] = (uint8_t)(num >> (8 * i));
    }
    out[10] = (uint8_t)(den & 0xFFu);
    out[11] = (uint8_t)(den >> 8);
    out[12] = 0u;
    out[13] = 0u;
    uint16_t crc = rod_crc16(out, BODY);
    out[14] = (uint8_t)(crc & 0xFFu);
    out[15] = (uint8_t)(crc >> 8);
}

static bool crc_ok(const uint8_t *in, size_t body)
{
    uint16_t crc = (uint16_t)(in[body] | (uint16_t)in[body + 1] << 8);
    return crc == rod_crc16(in, body);
}

uint8_t rod_rig_decode(const uint8_t *in, size_t n, rod_rig_t defaults, rod_rig_t *rig)
{
    *rig = defaults;
    if (in == NULL || n < BODY_SIGNS + 2u) {
        return 0u;
    }
    bool erased = true;
    for (size_t i = 0; i < n && i < ROD_RIG_STORE_SIZE; i++) {
        erased = erased && (in[i] == 0xFFu || in[i] == 0x00u);
    }
    if (erased) {
        return 0u;
    }
    rod_rig_t stored = defaults;
    stored.encoder_sign = (int8_t)in[3];
    stored.motor_sign = (int8_t)in[4];
    bool ok = in[0] == (uint8_t)'R' && in[1] == (uint8_t)'G' && is_sign(stored.encoder_sign)
              && is_sign(stored.motor_sign);
    if (ok && in[2] == LAYOUT_SIGNS) {
        ok = crc_ok(in, BODY_SIGNS);
    } else if (ok && in[2] == LAYOUT && n >= ROD_RIG_STORE_SIZE && crc_ok(in, BODY)) {
        uint32_t num = (uint32_t)in[6] | (uint32_t)in[7] << 8 | (uint32_t)in[8] << 16 | (uint32_t)in[9] << 24;
        uint32_t den = (uint32_t)in[10] | (uint32_t)in[11] << 8;
        ok = num <= (uint32_t)ROD_COUNTS_NUM_MAX
             && rod_counts_make((int32_t)num, (int32_t)den, &stored.counts);
    } else {
        ok = false;
    }
    if (!ok) {
        return ROD_RIG_FLAG_STORE_CORRUPT;
    }
    *rig = stored;
    return ROD_RIG_FLAG_STORED;
}

uint8_t rod_rig_sign_flags(const rod_rig_t *rig)
{
    uint8_t f = 0u;
    if (rig->encoder_sign < 0) {
        f |= ROD_RIG_FLAG_ENCODER_REVERSED;
    }
    if (rig->motor_sign < 0) {
        f |= ROD_RIG_FLAG_MOTOR_REVERSED;
    }
    return f;
}
