/* rod_imu.h -- the tip IMU's health, and the gyro's bias measured at rest.
 *
 * Built into every firmware; it only has work to do when the header was designed with the tip IMU
 * (ROD_NY > 1). A sample is bad when none came this period, when all three readings equal the
 * previous ones exactly (a live part's noise moves at least one by an LSB), or when one is at full
 * scale or not finite: the estimator cannot use it. ROD_IMU_FAULT_PERIODS bad samples in a row while
 * armed for balance trip FAULT, reason IMU (rod_control.c): 15 ms at 1 kHz, inside the 20 ms.
 * Base-only gains are not kept as a fallback: a rod that needs the IMU is past what they hold.
 */
#ifndef ROD_IMU_H
#define ROD_IMU_H

#include <stdbool.h>
#include <stdint.h>

#include "rod_config.h"
#include "rod_io.h"

#ifdef __cplusplus
extern "C" {
#endif

#define ROD_IMU_FAULT_PERIODS 15u
/* The gyro's bias is its mean while the encoder has not moved for this many periods [-]. */
#define ROD_IMU_REST_PERIODS 200u
#define ROD_IMU_BIAS_K 0.002f /* per period: a 0.5 s mean at 1 kHz [-] */

typedef struct {
    rod_imu_reading_t last; /* the previous good or bad sample, for the stuck test */
    uint32_t bad_run;       /* bad samples in a row */
    uint32_t still;         /* periods since the encoder count last changed */
    int32_t still_count;
    float gyro_bias;        /* the gyro's mean at rest [rad/s] */
    bool bias_known;
} rod_imu_t;

void rod_imu_init(rod_imu_t *m);

/* One period: judge the sample, and while the rod is still (same count) average the gyro. Returns
 * whether the sample is good. */
bool rod_imu_step(rod_imu_t *m, const rod_imu_reading_t *r, int32_t count);

/* Bad samples in a row reached ROD_IMU_FAULT_PERIODS. */
static inline bool rod_imu_lost(const rod_imu_t *m)
{
    return m->bad_run >= ROD_IMU_FAULT_PERIODS;
}

#ifdef __cplusplus
}
#endif

#endif /* ROD_IMU_H */
