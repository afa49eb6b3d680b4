/* rod_rig.c -- the stored wiring signs (rod_rig.h). */
#include "rod_rig.h"

#include <stdbool.h>

#include "rod_protocol.h"

#define LAYOUT 1u
#define BODY 6u

static bool is_sign(int8_t s)
{
    return s == 1 || s == -1;
}

void rod_rig_encode(const rod_rig_t *rig, uint8_t out[ROD_RIG_STORE_SIZE])
{
    out[0] = (uint8_t)'R';
    out[1] = (uint8_t)'G';
    out[2] = LAYOUT;
    out[3] = (uint8_t)rig->encoder_sign;
    out[4] = (uint8_t)rig->motor_sign;
    out[5] = 0u;
    uint16_t crc = rod_crc16(out, BODY);
    out[6] = (uint8_t)(crc & 0xFFu);
    out[7] = (uint8_t)(crc >> 8);
}

uint8_t rod_rig_decode(const uint8_t *in, size_t n, rod_rig_t defaults, rod_rig_t *rig)
{
    *rig = defaults;
    if (in == NULL || n < ROD_RIG_STORE_SIZE) {
        return 0u;
    }
    bool erased = true;
    for (size_t i = 0; i < ROD_RIG_STORE_SIZE; i++) {
        erased = erased && (in[i] == 0xFFu || in[i] == 0x00u);
    }
    if (erased) {
        return 0u;
    }
    uint16_t crc = (uint16_t)(in[6] | (uint16_t)in[7] << 8);
    rod_rig_t stored = {(int8_t)in[3], (int8_t)in[4]};
    if (in[0] != (uint8_t)'R' || in[1] != (uint8_t)'G' || in[2] != LAYOUT || crc != rod_crc16(in, BODY)
        || !is_sign(stored.encoder_sign) || !is_sign(stored.motor_sign)) {
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
