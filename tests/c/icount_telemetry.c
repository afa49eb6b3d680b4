/* Instruction count of encoding one n=5 telemetry frame on a Cortex-M4F (QEMU, see
 * /work/shared/tools/m4-icount.sh). Build and run:
 *   m4-icount.sh cc /tmp/icount.elf tests/c/icount_telemetry.c firmware/src/core/rod_protocol.c -Ifirmware/src/core
 *   m4-icount.sh run /tmp/icount.elf icount_start icount_stop
 * The window is the encode call only (minus 1 for the start marker's bx lr, per entry).
 * tests/test_protocol.py runs this when arm-none-eabi-gcc and qemu-system-arm are installed. */
#include <stdio.h>

#include "rod_protocol.h"

#define REPS 4

__attribute__((noinline)) void icount_start(void) { __asm__ volatile(""); }
__attribute__((noinline)) void icount_stop(void) { __asm__ volatile(""); }

static uint8_t frame[ROD_TELEMETRY_FRAME_MAX(5)] __attribute__((aligned(4)));

int main(void)
{
    /* Representative values: small counters (many zero bytes, the slow case for COBS). */
    static const float theta[5] = {3.1415f, 3.1201f, 3.0990f, 3.0871f, 3.0712f};
    static const float rate[5] = {0.1234f, -0.2718f, 0.5772f, -1.4142f, 2.2360f};
    rod_msg_telemetry_t m = {
        .mode = ROD_MODE_BALANCE, .reason = ROD_REASON_NONE, .flags = ROD_TLM_FLAG_DRIVER_ENABLED | ROD_TLM_FLAG_HEARTBEAT_OK,
        .n = 5, .encoder_count = 490, .base_rate = 0.0125f, .torque = -0.0125f, .duty = -0.0625f, .step_us = 61,
        .overruns = 0, .frames_dropped = 0, .rx_errors = 0, .theta_hat = theta, .rate_hat = rate,
    };
    size_t len = 0;
    for (unsigned r = 0; r < REPS; r++) {
        icount_start();
        len = rod_proto_encode_telemetry(&m, 1000u + r, 123456789u, frame, sizeof frame);
        icount_stop();
    }
    /* check the frame on the target itself */
    uint8_t pkt[ROD_PROTO_MAX_PACKET];
    rod_packet_t p;
    rod_msg_telemetry_t d;
    float th[ROD_PROTO_MAX_N], ra[ROD_PROTO_MAX_N];
    int ok = len == 91u - 1u && rod_proto_decode_frame(frame, len, pkt, sizeof pkt, &p) == ROD_DECODE_OK &&
             rod_proto_decode_telemetry(&p, &d, th, ra, ROD_PROTO_MAX_N) == ROD_DECODE_OK && p.seq == 1000u + REPS - 1u &&
             d.encoder_count == m.encoder_count && d.duty == m.duty && th[4] == theta[4] && ra[3] == rate[3];
    printf("frame bytes %u reps %u %s\n", (unsigned)len, (unsigned)REPS, ok ? "roundtrip ok" : "ROUNDTRIP FAILED");
    return !ok;
}
