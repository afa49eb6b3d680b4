/* Stress of the rodlink C codec for sanitizer builds (-fsanitize=address,undefined), run by
 * tests/test_protocol.py:
 *   rx_fuzz ITERATIONS HEXFRAME...
 * Each HEXFRAME is one valid host->device wire frame (with its 0x00). Every iteration feeds the rx
 * path random garbage, then each valid frame whole, truncated, corrupted, byte by byte or in random
 * chunks; runs COBS decode on random input with random capacities; and encodes telemetry with
 * random n and capacities. Checks: every intact frame after a delimiter is decoded with status OK,
 * consumed never exceeds the input, encoders never report more than cap. Prints one summary line
 * and exits 0, or prints the first failure and exits 1. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "rod_protocol.h"

static uint32_t rng_state = 12345u;
static uint32_t rnd(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 17;
    rng_state ^= rng_state << 5;
    return rng_state;
}

#define FAIL(...)                                                                                                      \
    do {                                                                                                               \
        printf("FAIL: " __VA_ARGS__);                                                                                  \
        printf("\n");                                                                                                  \
        exit(1);                                                                                                       \
    } while (0)

static unsigned long decoded_total, ok_total;

/* Feed data in random chunk sizes (exact-size heap copies so ASan sees any overread); returns frames. */
static unsigned feed_all(rod_proto_rx_t *rx, const uint8_t *data, size_t n, rod_msg_command_t *last)
{
    unsigned frames = 0;
    size_t pos = 0;
    while (pos < n) {
        size_t chunk = 1u + rnd() % 40u;
        if (chunk > n - pos) {
            chunk = n - pos;
        }
        uint8_t *copy = malloc(chunk);
        memcpy(copy, data + pos, chunk);
        size_t off = 0;
        while (off < chunk) {
            size_t used = 0;
            rod_msg_command_t m;
            int r = rod_proto_rx_feed(rx, copy + off, chunk - off, &used, &m);
            if (used > chunk - off || (r == 1 && used == 0)) {
                FAIL("consumed %zu of %zu", used, chunk - off);
            }
            off += used;
            if (r == 1) {
                frames++;
                decoded_total++;
                if (m.status == ROD_ACK_OK) {
                    ok_total++;
                }
                *last = m;
            }
        }
        free(copy);
        pos += chunk;
    }
    return frames;
}

static size_t unhex(const char *s, uint8_t *out, size_t cap)
{
    size_t n = strlen(s) / 2u;
    if (n > cap) {
        FAIL("frame too long");
    }
    for (size_t i = 0; i < n; i++) {
        unsigned v;
        if (sscanf(s + 2 * i, "%2x", &v) != 1) {
            FAIL("bad hex");
        }
        out[i] = (uint8_t)v;
    }
    return n;
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        printf("usage: rx_fuzz ITERATIONS HEXFRAME...\n");
        return 2;
    }
    long iterations = strtol(argv[1], NULL, 10);
    int nframes = argc - 2;
    static uint8_t frames[32][ROD_PROTO_MAX_FRAME];
    size_t lens[32];
    if (nframes > 32) {
        nframes = 32;
    }
    for (int i = 0; i < nframes; i++) {
        lens[i] = unhex(argv[2 + i], frames[i], sizeof frames[i]);
    }
    rod_proto_rx_t rx;
    rod_proto_rx_init(&rx);
    static uint8_t buf[4096];
    unsigned long intact = 0;

    for (long it = 0; it < iterations; it++) {
        /* 1: garbage of random length (sometimes longer than any frame), then a delimiter */
        size_t g = rnd() % (it % 7 == 0 ? 1500u : 60u);
        for (size_t i = 0; i < g; i++) {
            buf[i] = (uint8_t)rnd();
        }
        buf[g] = 0;
        rod_msg_command_t m;
        feed_all(&rx, buf, g + 1u, &m);

        /* 2: one valid frame, possibly damaged */
        int k = (int)(rnd() % (uint32_t)nframes);
        size_t n = lens[k];
        memcpy(buf, frames[k], n);
        int damage = (int)(rnd() % 4u);
        if (damage == 1) {
            n = 1u + rnd() % (n - 2u); /* truncated: part of the frame is lost ... */
            buf[n++] = 0;              /* ... and a delimiter follows */
        } else if (damage == 2) {
            size_t p = rnd() % (n - 1u);
            buf[p] ^= (uint8_t)(1u + rnd() % 255u); /* one corrupt byte (maybe a 0x00 inside) */
        }
        unsigned got = feed_all(&rx, buf, n, &m);
        if (damage == 0 || damage == 3) {
            intact++;
            if (got != 1u || m.status != ROD_ACK_OK) {
                FAIL("iteration %ld: intact frame %d not decoded (got %u, status %u)", it, k, got, m.status);
            }
        }

        /* 3: COBS decode of random bytes with a random capacity, in place half the time */
        size_t rn = 1u + rnd() % 600u, cap = rnd() % 700u;
        uint8_t *in = malloc(rn);
        uint8_t *out = malloc(cap ? cap : 1u);
        for (size_t i = 0; i < rn; i++) {
            in[i] = (uint8_t)(rnd() % 8u == 0u ? 0u : rnd());
        }
        int in_place = (int)(rnd() & 1u);
        size_t dl = rod_cobs_decode(in, rn, in_place ? in : out, in_place ? rn : cap);
        if (dl > rn) {
            FAIL("cobs decode grew: %zu > %zu", dl, rn);
        }
        size_t el = rod_cobs_encode(in, rn, out, cap);
        if (el > cap) {
            FAIL("cobs encode wrote %zu > cap %zu", el, cap);
        }
        free(in);
        free(out);

        /* 4: telemetry with random n (sometimes too large) and capacity */
        float th[70], ra[70];
        for (int i = 0; i < 70; i++) {
            uint32_t bits = rnd();
            memcpy(&th[i], &bits, sizeof bits);
            bits = rnd();
            memcpy(&ra[i], &bits, sizeof bits);
        }
        rod_msg_telemetry_t t = {0};
        t.n = (uint8_t)(rnd() % 70u);
        t.encoder_count = (int32_t)rnd();
        t.theta_hat = th;
        t.rate_hat = ra;
        size_t tcap = rnd() % 700u;
        uint8_t *tout = malloc(tcap ? tcap : 1u);
        size_t tl = rod_proto_encode_telemetry(&t, rnd(), rnd(), tout, tcap);
        if (tl > tcap || (t.n > ROD_PROTO_MAX_N && tl != 0u)) {
            FAIL("telemetry n=%u cap=%zu gave %zu", t.n, tcap, tl);
        }
        if (tl != 0u) {
            uint8_t pkt[ROD_PROTO_MAX_PACKET];
            rod_packet_t p;
            rod_msg_telemetry_t d;
            float dth[ROD_PROTO_MAX_N], dra[ROD_PROTO_MAX_N];
            if (rod_proto_decode_frame(tout, tl, pkt, sizeof pkt, &p) != ROD_DECODE_OK ||
                rod_proto_decode_telemetry(&p, &d, dth, dra, ROD_PROTO_MAX_N) != ROD_DECODE_OK || d.n != t.n ||
                memcmp(dth, th, 4u * t.n) != 0 || memcmp(dra, ra, 4u * t.n) != 0) {
                FAIL("telemetry n=%u did not round-trip", t.n);
            }
        }
        free(tout);
    }
    if (decoded_total != intact) { /* deterministic PRNG: no damaged frame happens to pass the CRC */
        FAIL("decoded %lu frames, %lu were intact", decoded_total, intact);
    }
    printf("ok iterations=%ld intact=%lu decoded=%lu status_ok=%lu rx_errors=%lu\n", iterations, intact, decoded_total,
           ok_total, (unsigned long)rx.errors);
    return 0;
}
