/* rod_identify.c -- chirp, PRBS, steps, release and settle, one torque per control period. */
#include "rod_identify.h"

#include <math.h>

#include "rod_config.h"
#include "rod_protocol_defs.h"

/* Long enough for any experiment at the rig, short enough that the period count (and the
 * chirp's k * ddphase) stays exact in float (< 2^24 periods). */
#define ROD_IDENTIFY_DURATION_MAX_S 600.0f
/* x^16 + x^14 + x^13 + x^11 + 1 (Galois form): period 65535, so no bit pattern repeats within
 * an experiment. */
#define ROD_IDENTIFY_LFSR_TAPS 0xB400u

/* Periods in s seconds, rounded; 0 for non-finite or non-positive s. */
static uint32_t periods_of(float s)
{
    if (!(s > 0.0f && s <= ROD_IDENTIFY_DURATION_MAX_S)) {
        return 0u;
    }
    return (uint32_t)(s * (1.0f / ROD_DT_S) + 0.5f);
}

bool rod_identify_start(rod_identify_t *id, const rod_identify_request_t *req)
{
    if (!(req->amplitude > 0.0f && req->amplitude <= ROD_TORQUE_MAX_NM)) {
        return false;
    }
    uint32_t total = periods_of(req->duration);
    if (total == 0u) {
        return false;
    }
    uint32_t hold = 0u;
    float dphase0 = 0.0f, ddphase = 0.0f;
    const float nyquist_hz = 0.5f / ROD_DT_S;
    switch (req->excitation) {
    case ROD_EXCITATION_CHIRP:
        if (!(req->shape1 >= 0.0f && req->shape2 >= req->shape1 && req->shape2 > 0.0f && req->shape2 <= nyquist_hz)) {
            return false;
        }
        dphase0 = 2.0f * ROD_PI_F * req->shape1 * ROD_DT_S;
        ddphase = 2.0f * ROD_PI_F * (req->shape2 - req->shape1) * ROD_DT_S / (float)total;
        break;
    case ROD_EXCITATION_PRBS:
    case ROD_EXCITATION_STEPS:
        hold = periods_of(req->shape1);
        if (hold == 0u || hold > total) {
            return false;
        }
        break;
    case ROD_EXCITATION_RELEASE:
        hold = periods_of(req->shape1);
        if (hold == 0u || hold >= total) {
            return false; /* a release needs some free swing after the pulse */
        }
        break;
    case ROD_EXCITATION_SETTLE:
        if (!(req->shape1 > 0.0f && req->shape1 <= nyquist_hz)) {
            return false;
        }
        dphase0 = 2.0f * ROD_PI_F * req->shape1 * ROD_DT_S;
        break;
    default:
        return false;
    }
    *id = (rod_identify_t){0};
    id->req = *req;
    id->total = total;
    id->hold = hold;
    id->dphase0 = dphase0;
    id->ddphase = ddphase;
    id->lfsr = req->seed != 0u ? req->seed : 1u;
    return true;
}

static float prbs_bit(rod_identify_t *id)
{
    uint16_t lsb = (uint16_t)(id->lfsr & 1u);
    id->lfsr = (uint16_t)(id->lfsr >> 1);
    if (lsb != 0u) {
        id->lfsr ^= (uint16_t)ROD_IDENTIFY_LFSR_TAPS;
    }
    return lsb != 0u ? id->req.amplitude : -id->req.amplitude;
}

/* sin of the phase at period k, then the phase moved on to period k + 1. */
static float next_sine(rod_identify_t *id, uint32_t k)
{
    float s = sinf(id->phase);
    /* Wrapped every period: the phase grows to thousands of rad over a long chirp, where
     * float would lose the fine increments. */
    id->phase += id->dphase0 + ((float)k + 0.5f) * id->ddphase; /* midpoint: phi(k dt) exact */
    while (id->phase >= ROD_PI_F) {
        id->phase -= 2.0f * ROD_PI_F;
    }
    return s;
}

float rod_identify_torque(rod_identify_t *id, bool *done)
{
    if (id->k >= id->total) {
        *done = true;
        return 0.0f;
    }
    *done = false;
    uint32_t k = id->k++;
    float a = id->req.amplitude;
    switch (id->req.excitation) {
    case ROD_EXCITATION_CHIRP:
        return a * next_sine(id, k);
    case ROD_EXCITATION_SETTLE: /* one frequency (ddphase 0), its amplitude fading to 0 at the end */
        return a * next_sine(id, k) * (1.0f - (float)k / (float)id->total);
    case ROD_EXCITATION_PRBS:
        if (k % id->hold == 0u) {
            id->level = prbs_bit(id);
        }
        return id->level;
    case ROD_EXCITATION_STEPS: {
        static const float sign[4] = {1.0f, 0.0f, -1.0f, 0.0f};
        return a * sign[(k / id->hold) % 4u];
    }
    case ROD_EXCITATION_RELEASE:
        return k < id->hold ? a : 0.0f;
    default:
        *done = true;
        return 0.0f;
    }
}
