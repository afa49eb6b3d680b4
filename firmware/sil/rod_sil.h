/* rod_sil.h -- the firmware core as a host shared library (software in the loop).
 *
 * Built by `rodctl sil-lib` from the same firmware/src/core sources the Teensy runs, against a
 * rod_gains.h generated for the chosen parameters. Stable C ABI (version 1); every function
 * works on one library-global device, so a process holds one SIL controller and one virtual
 * device (rod_dev_*) independently.
 *
 * Mode codes (rod_sil_status, rod_dev_status):
 *   0 DISARMED  1 BALANCE  2 SWING_UP  3 FAULT  4 CATCH  5 IDENTIFY
 * Reason codes (rod_sil_reason, rod_dev_reason):
 *   0 NONE  1 HOST  2 ANGLE_LIMIT  3 SPEED_LIMIT  4 DRIVER_FAULT  5 HEARTBEAT  6 NON_FINITE
 *   7 OVERRUN  8 NO_TIMER  9 RUNAWAY  10 IMU  11 UPLOAD  12 RESET  (the protocol's codes,
 *   firmware/protocol/rodlink.toml)
 * Angles in rad with 0 hanging and pi upright (multi-turn), rates in rad/s, torque in N m at
 * the output shaft, duty signed in [-1, 1].
 */
#ifndef ROD_SIL_H
#define ROD_SIL_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#if defined(_WIN32)
#define ROD_SIL_API __declspec(dllexport)
#else
#define ROD_SIL_API __attribute__((visibility("default")))
#endif

/* ---- controller ABI (version 1) ------------------------------------------------------------
 * As if a host with a live heartbeat were connected; virtual time advances one period per step,
 * so there are no overruns. Commands act at once. */

ROD_SIL_API int rod_sil_abi_version(void);          /* 1 */
ROD_SIL_API void rod_sil_reset(void);               /* power-on: DISARMED, zero torque */
ROD_SIL_API float rod_sil_period(void);             /* control period [s] */
ROD_SIL_API int rod_sil_edges(void);                /* N of the controller's model */
/* 0 disarm, 1 balance (catch near upright), 2 swing up then balance; refused in FAULT. */
ROD_SIL_API void rod_sil_arm(int mode);
/* One control period; returns the torque [N m] at the output shaft, held for the next period. */
ROD_SIL_API float rod_sil_step(int32_t encoder_count);
/* The tip IMU's sample for the next rod_sil_step only (sensor frame, rod_io.h): gyro [rad/s], accelerometer
 * x and y [m/s^2]; fresh 0: none came. A firmware designed without the IMU ignores it. */
ROD_SIL_API void rod_sil_imu(float gyro, float accel_x, float accel_y, int fresh);
/* theta-hat_1..N then their rates, up to cap values; returns the mode code. Outside BALANCE
 * every entry is the measured theta_1 / base rate. */
ROD_SIL_API int rod_sil_status(float *est, int cap);

/* ---- extensions ---- */

ROD_SIL_API float rod_sil_duty(void);               /* duty of the last step */
ROD_SIL_API int rod_sil_enable(void);               /* driver enable of the last step (0/1) */
ROD_SIL_API int rod_sil_reason(void);               /* reason code */
ROD_SIL_API float rod_sil_rate(void);               /* measured base rate of the last step [rad/s] */
/* SET / CLEAR_FAULT as the host sends them; return the ack code (0 OK, 1 BAD_VALUE,
 * 2 BAD_STATE). Params: 1 swing amplitude, 2 swing angle, 3 catch angle, 4 telemetry
 * decimation, 5 heartbeat timeout. */
ROD_SIL_API int rod_sil_set(int param, float value);
ROD_SIL_API int rod_sil_clear_fault(void);
ROD_SIL_API int rod_sil_arm_result(int mode);       /* rod_sil_arm that returns the ack code */
/* IDENTIFY as the host sends it (from DISARMED): excitation 1 chirp, 2 PRBS, 3 steps, 4 release;
 * amplitude [N m], duration [s], shape1 / shape2 as in rodlink.toml (chirp f0 / f1 [Hz], PRBS
 * bit time [s], step hold [s], release pulse [s]); seed = PRBS LFSR start state. Returns the ack
 * code; mode 5 (IDENTIFY) until the excitation ends, then 0 (DISARMED). */
ROD_SIL_API int rod_sil_identify(int excitation, float amplitude, float duration, float shape1, float shape2,
                                 int seed);
/* The balance's own estimates: the set-point trim [rad] (rod_trim.h), the held torque [N m] and the
 * estimated base-torque disturbance w [N m]. Any pointer may be NULL. */
ROD_SIL_API void rod_sil_balance(float *trim, float *hold, float *disturbance);
/* Test hook: poisons the balance estimate with a NaN (the next BALANCE step must trip). */
ROD_SIL_API void rod_sil_inject_nan(void);

/* ---- virtual device (sim://): the real protocol, explicit time, no implicit heartbeat ----- */

/* Power-on; tx_capacity = bytes the emulated USB TX buffer holds (0: default 4096). A frame
 * that does not fit whole is dropped and counted, as on the board. */
ROD_SIL_API void rod_dev_reset(size_t tx_capacity);
/* One period: now_us = step start [us], last_step_us = CPU time of the previous step [us],
 * driver_fault = nFAULT low. Returns the torque; the main loop (rx/tx) runs after it. */
ROD_SIL_API float rod_dev_step(int32_t encoder_count, uint32_t now_us, uint32_t last_step_us, int driver_fault);
/* The tip IMU's sample for the next rod_dev_step only (as rod_sil_imu). */
ROD_SIL_API void rod_dev_imu(float gyro, float accel_x, float accel_y, int fresh);
ROD_SIL_API float rod_dev_duty(void);
ROD_SIL_API int rod_dev_enable(void);
ROD_SIL_API int rod_dev_reason(void);
ROD_SIL_API int rod_dev_status(float *est, int cap);
/* After rod_dev_reset, before the first step: the rig settings the board kept (16 bytes, rod_rig.h;
 * NULL / 0: none, the defaults +1 +1 and the header's counts per turn apply), as the board reads them
 * from its EEPROM at power-on. */
ROD_SIL_API void rod_dev_load_rig(const uint8_t *stored, size_t n);
/* After rod_dev_reset: a fault of the board's own (rod_device_board_fault), held in every step until the
 * next rod_dev_reset; e.g. 12 RESET, the board started after its watchdog with its zero wherever the rod was. */
ROD_SIL_API void rod_dev_board_fault(int reason);
/* After a SAVE_RIG: copies the 16 bytes the board would write to its EEPROM and returns 16, once;
 * otherwise 0. They count as written: HELLO flags STORED from the next step on. */
ROD_SIL_API size_t rod_dev_take_save(uint8_t *out, size_t cap);
/* Host -> device bytes; returns how many the emulated USB RX buffer (4096 bytes) took. */
ROD_SIL_API size_t rod_dev_write(const uint8_t *data, size_t n);
/* Device -> host bytes (COBS frames, each ended by 0x00), oldest first; returns how many were
 * copied. Frames not yet read stay queued up to tx_capacity bytes. */
ROD_SIL_API size_t rod_dev_read(uint8_t *out, size_t cap);

#ifdef __cplusplus
}
#endif

#endif /* ROD_SIL_H */
