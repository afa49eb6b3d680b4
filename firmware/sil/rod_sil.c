/* rod_sil.c -- the host-side board: drives rod_device as the Teensy's timer and main loop do.
 *
 * Two independent devices: `sil` behind rod_sil_* (heartbeat always fresh, time advancing one
 * period per step) and `vdev` behind rod_dev_* (explicit time and driver fault, host bytes in,
 * device bytes out through bounded buffers like the USB ones).
 */
#include "rod_sil.h"

#include <math.h>
#include <string.h>

#include "rod_config.h"
#include "rod_device.h"

#define SIL_RX_CAPACITY 4096u
#define SIL_TX_DEFAULT 4096u
#define SIL_TX_MAX 65536u

/* ---- controller ABI ------------------------------------------------------------------------ */

static rod_device_t sil;
static rod_outputs_t sil_out;
static uint32_t sil_now_us;
static rod_imu_reading_t sil_imu; /* the next step's IMU sample (rod_sil_imu) */

int rod_sil_abi_version(void)
{
    return 1;
}

void rod_sil_reset(void)
{
    rod_device_init(&sil);
    sil_out = (rod_outputs_t){false, 0.0f, 0.0f};
    sil_now_us = 0;
    sil_imu = (rod_imu_reading_t){0.0f, 0.0f, 0.0f, false};
}

void rod_sil_imu(float gyro, float accel_x, float accel_y, int fresh)
{
    sil_imu = (rod_imu_reading_t){gyro, accel_x, accel_y, fresh != 0};
}

float rod_sil_period(void)
{
    return ROD_DT_S;
}

int rod_sil_edges(void)
{
    return ROD_N;
}

int rod_sil_arm_result(int mode)
{
    if (mode == 0) {
        return rod_control_disarm(&sil.control);
    }
    if (mode < 0 || mode > 255) {
        return ROD_ACK_BAD_VALUE;
    }
    return rod_control_arm(&sil.control, (uint8_t)mode);
}

int rod_sil_identify(int excitation, float amplitude, float duration, float shape1, float shape2, int seed)
{
    if (excitation < 0 || excitation > 255 || seed < 0 || seed > 0xFFFF) {
        return ROD_ACK_BAD_VALUE;
    }
    rod_identify_request_t req = {(uint8_t)excitation, (uint16_t)seed, amplitude, duration, shape1, shape2};
    return rod_control_identify(&sil.control, &req);
}

void rod_sil_arm(int mode)
{
    (void)rod_sil_arm_result(mode);
}

float rod_sil_step(int32_t encoder_count)
{
    rod_inputs_t in = {encoder_count, sil_now_us, 0u, false, sil_imu};
    sil_imu.fresh = false; /* each sample is given once */
    rod_device_heartbeat(&sil);
    rod_device_step(&sil, &in, &sil_out);
    sil_now_us += ROD_LOOP_PERIOD_US;
    /* Nobody reads this device's frames: its event ring fills once and then every new frame
     * is dropped before any encoding work, which keeps the closed-loop simulation cheap. */
    return sil_out.torque;
}

static int status_of(const rod_device_t *dev, float *est, int cap)
{
    float theta[ROD_N], rate[ROD_N];
    rod_control_estimate(&dev->control, theta, rate);
    for (int i = 0; est != NULL && i < cap && i < 2 * ROD_N; i++) {
        est[i] = i < ROD_N ? theta[i] : rate[i - ROD_N];
    }
    return dev->control.mode;
}

int rod_sil_status(float *est, int cap)
{
    return status_of(&sil, est, cap);
}

void rod_sil_balance(float *trim, float *hold, float *disturbance)
{
    const rod_control_t *c = &sil.control;
    if (trim) *trim = c->trim.trim;
    if (hold) *hold = c->trim.hold;
    if (disturbance) *disturbance = c->obs.w;
}

float rod_sil_duty(void)
{
    return sil_out.duty;
}

int rod_sil_enable(void)
{
    return sil_out.enable ? 1 : 0;
}

int rod_sil_reason(void)
{
    return sil.control.reason;
}

float rod_sil_rate(void)
{
    return sil.control.rate;
}

int rod_sil_set(int param, float value)
{
    if (param < 0 || param > 255) {
        return ROD_ACK_BAD_VALUE;
    }
    return rod_control_set(&sil.control, (uint8_t)param, value);
}

int rod_sil_clear_fault(void)
{
    return rod_control_clear_fault(&sil.control);
}

void rod_sil_inject_nan(void)
{
    sil.control.obs.z[0] = NAN;
}

/* ---- virtual device -------------------------------------------------------------------------- */

static rod_device_t vdev;
static rod_outputs_t vdev_out;
static rod_imu_reading_t vdev_imu;
static uint8_t rx_buf[SIL_RX_CAPACITY];
static size_t rx_len;
static uint8_t tx_buf[SIL_TX_MAX];
static size_t tx_len, tx_cap;

/* What the board's loop() does between timer interrupts. */
static void vdev_main_loop(void)
{
    if (rx_len > 0) {
        size_t used = rod_device_rx(&vdev, rx_buf, rx_len);
        memmove(rx_buf, rx_buf + used, rx_len - used);
        rx_len -= used;
    }
    uint8_t frame[ROD_DEVICE_FRAME_MAX];
    size_t n;
    while ((n = rod_device_tx(&vdev, frame, sizeof frame)) > 0) {
        if (tx_len + n <= tx_cap) {
            memcpy(tx_buf + tx_len, frame, n);
            tx_len += n;
        } else {
            rod_device_count_tx_drop(&vdev);
        }
    }
}

void rod_dev_reset(size_t tx_capacity)
{
    rod_device_init(&vdev);
    vdev_out = (rod_outputs_t){false, 0.0f, 0.0f};
    vdev_imu = (rod_imu_reading_t){0.0f, 0.0f, 0.0f, false};
    rx_len = 0;
    tx_len = 0;
    tx_cap = tx_capacity == 0 ? SIL_TX_DEFAULT : (tx_capacity > SIL_TX_MAX ? SIL_TX_MAX : tx_capacity);
}

float rod_dev_step(int32_t encoder_count, uint32_t now_us, uint32_t last_step_us, int driver_fault)
{
    rod_inputs_t in = {encoder_count, now_us, last_step_us, driver_fault != 0, vdev_imu};
    vdev_imu.fresh = false;
    rod_device_step(&vdev, &in, &vdev_out);
    vdev_main_loop();
    return vdev_out.torque;
}

void rod_dev_imu(float gyro, float accel_x, float accel_y, int fresh)
{
    vdev_imu = (rod_imu_reading_t){gyro, accel_x, accel_y, fresh != 0};
}

float rod_dev_duty(void)
{
    return vdev_out.duty;
}

int rod_dev_enable(void)
{
    return vdev_out.enable ? 1 : 0;
}

int rod_dev_reason(void)
{
    return vdev.control.reason;
}

int rod_dev_status(float *est, int cap)
{
    return status_of(&vdev, est, cap);
}

void rod_dev_load_rig(const uint8_t *stored, size_t n)
{
    rod_device_load_rig(&vdev, stored, n, rod_rig_defaults(1, 1));
}

void rod_dev_board_fault(int reason)
{
    rod_device_board_fault(&vdev, (uint8_t)reason);
}

size_t rod_dev_take_save(uint8_t *out, size_t cap)
{
    uint8_t bytes[ROD_RIG_STORE_SIZE];
    if (cap < ROD_RIG_STORE_SIZE || !rod_device_take_save(&vdev, bytes)) {
        return 0;
    }
    memcpy(out, bytes, ROD_RIG_STORE_SIZE);
    rod_device_saved(&vdev, true); /* the host keeps them: the virtual board's EEPROM */
    return ROD_RIG_STORE_SIZE;
}

size_t rod_dev_write(const uint8_t *data, size_t n)
{
    size_t room = SIL_RX_CAPACITY - rx_len;
    size_t take = n < room ? n : room;
    if (take > 0) {
        memcpy(rx_buf + rx_len, data, take);
        rx_len += take;
    }
    vdev_main_loop();
    return take;
}

size_t rod_dev_read(uint8_t *out, size_t cap)
{
    vdev_main_loop();
    size_t n = tx_len < cap ? tx_len : cap;
    if (n > 0) {
        memcpy(out, tx_buf, n);
        memmove(tx_buf, tx_buf + n, tx_len - n);
        tx_len -= n;
    }
    return n;
}
