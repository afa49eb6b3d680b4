/* rod_rig.h -- the rig's wiring signs and encoder counts per output turn, and the bytes that keep
 * them on the board.
 *
 * A reversed encoder or motor, or another encoder or gear ratio, is a fact of the rig, not of the
 * design: `rodctl check` measures it and SAVE_RIG stores it, so the fix needs no reflash. The
 * portable core applies them (count -> angle, duty -> driver), so the SIL exercises them; the board
 * only keeps the bytes (EEPROM) and hands them back at power-on.
 *
 * Stored layout 2 (ROD_RIG_STORE_SIZE bytes, little-endian): 'R' 'G' | 2 | encoder_sign (int8) |
 * motor_sign (int8) | 0 | counts num (u32) | counts den (u16) | 0 0 | CRC-16/CCITT-FALSE of the
 * first 14 bytes. Layout 1 (the first 8 bytes: signs, then the CRC of bytes 0-5 at 6-7) is still
 * read, with the compiled counts per turn.
 */
#ifndef ROD_RIG_H
#define ROD_RIG_H

#include <stddef.h>
#include <stdint.h>

#include "rod_angle.h"

#ifdef __cplusplus
extern "C" {
#endif

#define ROD_RIG_STORE_SIZE 16u

typedef struct {
    int8_t encoder_sign; /* +1, or -1: the count runs backwards */
    int8_t motor_sign;   /* +1, or -1: a positive duty turns the rod clockwise */
    rod_counts_t counts; /* encoder counts per output turn */
} rod_rig_t;

/* These signs with the header's counts per turn. */
rod_rig_t rod_rig_defaults(int8_t encoder_sign, int8_t motor_sign);

void rod_rig_encode(const rod_rig_t *rig, uint8_t out[ROD_RIG_STORE_SIZE]);

/* The stored bytes (NULL or n = 0: nothing stored) -> *rig; returns ROD_RIG_FLAG_STORED for a
 * valid record, 0 for an empty store (every byte 0xFF or 0x00: *rig = defaults) and
 * ROD_RIG_FLAG_STORE_CORRUPT for anything else (*rig = defaults). */
uint8_t rod_rig_decode(const uint8_t *in, size_t n, rod_rig_t defaults, rod_rig_t *rig);

/* ROD_RIG_FLAG_ENCODER_REVERSED / _MOTOR_REVERSED of these signs. */
uint8_t rod_rig_sign_flags(const rod_rig_t *rig);

static inline int32_t rod_rig_count(const rod_rig_t *rig, int32_t raw)
{
    /* unsigned negation: INT32_MIN stays defined (the counter wraps there anyway) */
    return rig->encoder_sign < 0 ? (int32_t)(0u - (uint32_t)raw) : raw;
}

static inline float rod_rig_duty(const rod_rig_t *rig, float duty)
{
    return rig->motor_sign < 0 ? -duty : duty;
}

#ifdef __cplusplus
}
#endif

#endif /* ROD_RIG_H */
