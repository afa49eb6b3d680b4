/* rod_config.h -- the generated gains plus the firmware's own constants, checked at compile time.
 *
 * Every core file includes this instead of rod_gains.h, so a header from another generator
 * version, or parameters the firmware cannot run, stop the build here with a message instead
 * of misbehaving on the rig.
 */
#ifndef ROD_CONFIG_H
#define ROD_CONFIG_H

#include "rod_gains.h"
#include "rod_protocol_defs.h"

/* ---- the header's layout ---------------------------------------------------------------- */

/* The macro set this firmware was written against (gains/codegen.py HEADER_SCHEMA_VERSION). */
#define ROD_GAINS_SCHEMA_EXPECTED 5

#ifndef ROD_GAINS_SCHEMA_VERSION
#error "rod_gains.h has no ROD_GAINS_SCHEMA_VERSION: regenerate it with `rodctl gains`"
#elif ROD_GAINS_SCHEMA_VERSION != ROD_GAINS_SCHEMA_EXPECTED
#error "rod_gains.h has a different ROD_GAINS_SCHEMA_VERSION than this firmware expects (5): regenerate it with the rodctl of this checkout (`rodctl gains`)"
#endif

#if !defined(ROD_N) || !defined(ROD_NX) || !defined(ROD_LOOP_PERIOD_US) || !defined(ROD_DT_S) \
    || !defined(ROD_COUNTS_PER_REV_NUM) || !defined(ROD_COUNTS_PER_REV_DEN) \
    || !defined(ROD_RATE_FILTER_K1) || !defined(ROD_RATE_FILTER_K2) \
    || !defined(ROD_MOTOR_KT_NM_PER_A) || !defined(ROD_MOTOR_KE_V_S_PER_RAD) || !defined(ROD_MOTOR_R_OHM) \
    || !defined(ROD_SUPPLY_V) || !defined(ROD_TORQUE_MAX_NM) || !defined(ROD_DUTY_MAX) \
    || !defined(ROD_PWM_FREQUENCY_HZ) || !defined(ROD_COULOMB_COMP_NM) || !defined(ROD_SWING_AMPLITUDE_NM) || !defined(ROD_SWING_ANGLE_RAD) \
    || !defined(ROD_SWING_OMEGA0_RAD_S) || !defined(ROD_SWING_ENERGY_TARGET) || !defined(ROD_SWING_RATE_LP_K) || !defined(ROD_SWING_STALL_STEPS) \
    || !defined(ROD_CATCH_ANGLE_RAD) || !defined(ROD_ANGLE_LIMIT_RAD) || !defined(ROD_SPEED_LIMIT_RAD_S) \
    || !defined(ROD_HEARTBEAT_TIMEOUT_S) || !defined(ROD_GAINS_SHA256_BYTES_INIT) \
    || !defined(ROD_AD_INIT) || !defined(ROD_BD_INIT) || !defined(ROD_K_INIT) || !defined(ROD_L_INIT) \
    || !defined(ROD_L_DISTURBANCE) || !defined(ROD_W_DECAY) || !defined(ROD_K_TORQUE_PREV) \
    || !defined(ROD_TRIM_HOLD_K) || !defined(ROD_TRIM_RATE) || !defined(ROD_TRIM_BAND_NM) || !defined(ROD_TRIM_TARGET_NM) || !defined(ROD_TRIM_START_RAD) \
    || !defined(ROD_TRIM_GATE_RAD) || !defined(ROD_TRIM_MAX_RAD) || !defined(ROD_NY) \
    || !defined(ROD_IMU_GYRO_RANGE_RAD_S) || !defined(ROD_IMU_ACCEL_RANGE_M_S2) \
    || !defined(ROD_IMU_TILT_COS) || !defined(ROD_IMU_TILT_SIN)
#error "rod_gains.h lacks a macro the firmware needs: regenerate it with `rodctl gains`"
#endif
#if ROD_NY != 1 && ROD_NY != 3
#error "ROD_NY must be 1 (the encoder) or 3 (the encoder and the tip IMU)"
#endif
#if ROD_NY > 1 && (!defined(ROD_IMU_NA) || !defined(ROD_IMU_L_INIT) || !defined(ROD_IMU_LW_INIT) \
    || !defined(ROD_IMU_LA_INIT) || !defined(ROD_IMU_AZ_INIT) || !defined(ROD_IMU_AA_INIT) || !defined(ROD_IMU_BA_INIT) \
    || !defined(ROD_IMU_CZ_INIT) || !defined(ROD_IMU_CA_INIT) || !defined(ROD_IMU_DY_INIT) \
    || !defined(ROD_IMU_FLANK_FF_NM) || !defined(ROD_IMU_FLANK_RAMP_STEPS))
#error "rod_gains.h was designed with the tip IMU but lacks its tables: regenerate it with `rodctl gains`"
#endif

/* ---- integer assumptions (preprocessor) ------------------------------------------------- */

#if ROD_NX != 2 * ROD_N
#error "ROD_NX must be 2 * ROD_N (angles then rates)"
#endif
#if ROD_N < 1 || ROD_N > 64
#error "ROD_N must be 1..64 (telemetry carries at most 64 edges)"
#endif
#if ROD_COUNTS_PER_REV_DEN < 1 || ROD_COUNTS_PER_REV_NUM < 16 * ROD_COUNTS_PER_REV_DEN
#error "counts per revolution must be a fraction NUM / DEN of at least 16 (SET COUNTS_PER_REV's minimum)"
#endif
/* rod_angle works in ticks of 1/(2 DEN) count; one turn is 2 NUM ticks, and NUM * DEN products
 * must stay far inside int32 (with room for a few turns of difference). */
#if ROD_COUNTS_PER_REV_NUM > 1000000 || ROD_COUNTS_PER_REV_DEN > 1000 \
    || ROD_COUNTS_PER_REV_NUM * ROD_COUNTS_PER_REV_DEN > 10000000
#error "counts per revolution fraction too large for rod_angle's int32 tick arithmetic"
#endif
#if ROD_LOOP_PERIOD_US < 50 || ROD_LOOP_PERIOD_US > 100000
#error "ROD_LOOP_PERIOD_US outside 50 us .. 100 ms"
#endif
#if ROD_PWM_FREQUENCY_HZ < 1000 || ROD_PWM_FREQUENCY_HZ > 100000
#error "ROD_PWM_FREQUENCY_HZ outside 1 kHz .. 100 kHz"
#endif

/* ---- firmware constants ----------------------------------------------------------------- */

#define ROD_PI_F 3.14159265f
#define ROD_TWO_PI_F 6.28318531f
#define ROD_HALF_PI_F 1.57079633f

/* Swing-up starts from rest, where sign(rate) of eq. (22) is 0: below this base speed and
 * within this angle of hanging the pump pushes in the + direction instead. The rate filter
 * reads 0 at rest, and a single count of motion already reads about 0.6 rad/s, so a small
 * threshold separates "at rest" from "moving" (it also acts briefly at the turning points of
 * a small swing, which only adds a millisecond of + torque there). */
#define ROD_SWING_REST_RATE_RAD_S 0.05f
#define ROD_SWING_REST_ANGLE_RAD 0.1f

/* Energy pumping: the pump torque falls from full to zero over this much pendulum energy below
 * the target (2 = upright at rest), and brakes likewise above it [-]. Narrow: the pump stays
 * bang-bang (eq. 22) until the rod is nearly there. */
#define ROD_SWING_ENERGY_BAND 0.1f

/* The swing-up's stall watch (rod_swingup.h): a half-swing rising no more than this is a stall
 * [rad] (5 deg: Table I's rod on a 10.5 V supply rises 54 and then 21 deg before it is caught;
 * on 10 V it turns back at 148 and then 147 deg); each stall adds the step to the energy target
 * (2 = upright) [-] and multiplies the pump by the gain [-], up to the gain's ceiling [-]. Stalls
 * allowed: ROD_SWING_STALL_STEPS (rod_gains.h, swing_up.stall_steps). */
#define ROD_SWING_STALL_RISE_RAD 0.0872665f
#define ROD_SWING_STALL_TARGET_STEP 0.1f
#define ROD_SWING_STALL_GAIN 1.25f
#define ROD_SWING_STALL_GAIN_MAX 2.0f

/* Friction compensation ramps over this base rate [rad/s]: about the rate one count per
 * 0.1 s gives, so it follows the motion without flipping on quantization noise. */
#define ROD_FRICTION_RATE_BAND_RAD_S 0.05f

/* Runtime-setting bounds (SET): ROD_PARAM_*_MIN / _MAX in rod_protocol_defs.h, generated from the
 * ranges in rodlink.toml, the one definition `rodctl set` reads too. */

/* Unprompted HELLO interval, in control steps (about once per second). */
#define ROD_HELLO_INTERVAL_STEPS ((1000000u + ROD_LOOP_PERIOD_US / 2u) / ROD_LOOP_PERIOD_US)

/* Ring capacities (powers of two). Commands are drained every step, so a few suffice; events
 * cover USB stalls of ~30 steps at decimation 1 before frames are dropped (and counted). */
#define ROD_COMMAND_RING_SIZE 16u
#define ROD_EVENT_RING_SIZE 32u

/* ---- float assumptions ------------------------------------------------------------------
 * C11 has no floating constant expressions (comparing floats in _Static_assert is a GCC
 * extension that clang rejects), so these are checked twice elsewhere:
 *  - by the generator: rodgains.params.check_firmware_limits refuses parameters that break any
 *    of them (one line, exit 2), so `rodctl gains` never writes such a header;
 *  - here in C++ only, where they are constant expressions: main.cpp includes this file, so
 *    every firmware build still stops on a hand-edited header.
 * Keep this list and check_firmware_limits in step (tests/test_params_firmware_limits.py pairs them). */

#ifdef __cplusplus
static_assert(ROD_TORQUE_MAX_NM > 0.0f, "torque ceiling must be positive");
static_assert(ROD_DUTY_MAX > 0.0f && ROD_DUTY_MAX <= 1.0f, "duty ceiling must be in (0, 1]");
static_assert(ROD_MOTOR_KT_NM_PER_A > 0.0f && ROD_MOTOR_R_OHM > 0.0f && ROD_SUPPLY_V > 0.0f,
              "motor model needs positive kt, R and supply voltage");
static_assert(ROD_MOTOR_KE_V_S_PER_RAD >= 0.0f, "back-EMF constant must not be negative");
static_assert(ROD_ANGLE_LIMIT_RAD > 0.0f && ROD_ANGLE_LIMIT_RAD <= ROD_PI_F, "angle limit must be in (0, pi]");
static_assert(ROD_SPEED_LIMIT_RAD_S > 0.0f, "speed limit must be positive");
static_assert(ROD_DT_S > 0.0f, "control period must be positive");
/* The defaults must pass the same bounds a SET would. */
static_assert(ROD_SWING_AMPLITUDE_NM >= ROD_PARAM_SWING_AMPLITUDE_MIN && ROD_SWING_AMPLITUDE_NM <= ROD_PARAM_SWING_AMPLITUDE_MAX,
              "default swing amplitude outside the SET range (at most the torque ceiling)");
static_assert(ROD_SWING_ANGLE_RAD >= ROD_PARAM_SWING_ANGLE_MIN && ROD_SWING_ANGLE_RAD <= ROD_PARAM_SWING_ANGLE_MAX,
              "default swing angle outside the SET range");
static_assert(ROD_CATCH_ANGLE_RAD >= ROD_PARAM_CATCH_ANGLE_MIN && ROD_CATCH_ANGLE_RAD <= ROD_PARAM_CATCH_ANGLE_MAX,
              "default catch angle outside the SET range (at most min(angle limit, 90 deg))");
static_assert(ROD_HEARTBEAT_TIMEOUT_S >= ROD_PARAM_HEARTBEAT_TIMEOUT_MIN && ROD_HEARTBEAT_TIMEOUT_S <= ROD_PARAM_HEARTBEAT_TIMEOUT_MAX,
              "default heartbeat timeout outside the SET range");
#endif

/* ---- integer assumptions (C11 and C++ alike) -------------------------------------------- */

#ifdef __cplusplus
#define ROD_STATIC_ASSERT(cond, msg) static_assert(cond, msg)
#else
#define ROD_STATIC_ASSERT(cond, msg) _Static_assert(cond, msg)
#endif

ROD_STATIC_ASSERT((ROD_COMMAND_RING_SIZE & (ROD_COMMAND_RING_SIZE - 1u)) == 0u, "ring sizes are powers of two");
ROD_STATIC_ASSERT((ROD_EVENT_RING_SIZE & (ROD_EVENT_RING_SIZE - 1u)) == 0u, "ring sizes are powers of two");

#endif /* ROD_CONFIG_H */
