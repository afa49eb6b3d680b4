/* libFuzzer target for the whole receive path of the firmware: host bytes -> rod_device_rx
 * (COBS, CRC, parsing, the command ring) -> rod_device_step (commands applied: ARM, SET with any
 * f32, CLEAR_FAULT, ...) -> rod_device_tx (acks and telemetry). Built by .ci/run with
 *   clang -fsanitize=fuzzer,address,undefined
 * together with every firmware/src/core C file and the committed firmware/include/rod_gains.h, and run for
 * a bounded time from the committed seed corpus tests/fuzz/corpus/ (see .ci/run).
 *
 * The input is fed in chunks whose sizes come from the input itself, with control steps between
 * them, so commands land between steps as they do on the board. Besides what the sanitizers catch,
 * it aborts when: rx takes more bytes than offered, tx writes more than its capacity or returns an
 * empty frame, the output duty is not finite or outside [-1, 1], or the driver is enabled while
 * the device is DISARMED or in FAULT, or a setting leaves its rodlink.toml range. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "rod_device.h"

static void check_settings(const rod_settings_t *s)
{
    if (!(s->swing_amplitude >= ROD_PARAM_SWING_AMPLITUDE_MIN && s->swing_amplitude <= ROD_PARAM_SWING_AMPLITUDE_MAX)
        || !(s->swing_angle >= ROD_PARAM_SWING_ANGLE_MIN && s->swing_angle <= ROD_PARAM_SWING_ANGLE_MAX)
        || !(s->catch_angle >= ROD_PARAM_CATCH_ANGLE_MIN && s->catch_angle <= ROD_PARAM_CATCH_ANGLE_MAX)
        || !(s->heartbeat_timeout >= ROD_PARAM_HEARTBEAT_TIMEOUT_MIN
             && s->heartbeat_timeout <= ROD_PARAM_HEARTBEAT_TIMEOUT_MAX)
        || s->decimation < 1u || s->decimation > 1000u) {
        abort();
    }
}

static void drain(rod_device_t *dev)
{
    static uint8_t frame[ROD_DEVICE_FRAME_MAX + 16];
    for (int k = 0; k < 64; k++) {
        size_t n = rod_device_tx(dev, frame, ROD_DEVICE_FRAME_MAX);
        if (n == 0) {
            return;
        }
        if (n > ROD_DEVICE_FRAME_MAX || frame[n - 1] != 0u) {
            abort();
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static rod_device_t dev;
    rod_device_init(&dev);
    rod_inputs_t in = {0, 0u, 0u, false, {0.0f, 0.0f, 0.0f, false}};
    rod_outputs_t out;
    size_t pos = 0;
    while (pos < size) {
        size_t chunk = 1u + (size_t)(data[pos] % 64u); /* the first byte of each chunk sets its size */
        pos++;
        if (chunk > size - pos) {
            chunk = size - pos;
        }
        size_t off = 0;
        for (int tries = 0; off < chunk && tries < 8; tries++) {
            size_t took = rod_device_rx(&dev, data + pos + off, chunk - off);
            if (took > chunk - off) {
                abort();
            }
            off += took;
            in.now_us += ROD_LOOP_PERIOD_US; /* a full command ring drains on the next step */
            in.encoder_count += (int32_t)(chunk % 7u) - 3;
            rod_device_step(&dev, &in, &out);
            if (!isfinite(out.duty) || out.duty > 1.0f || out.duty < -1.0f) {
                abort();
            }
            if (out.enable && (dev.control.mode == ROD_MODE_DISARMED || dev.control.mode == ROD_MODE_FAULT)) {
                abort();
            }
            check_settings(&dev.control.settings);
            drain(&dev);
        }
        pos += chunk;
    }
    return 0;
}
