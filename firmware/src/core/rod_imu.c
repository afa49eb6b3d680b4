/* rod_imu.c -- see rod_imu.h. */
#include "rod_imu.h"

#include <math.h>

void rod_imu_init(rod_imu_t *m)
{
    *m = (rod_imu_t){0};
}

static bool in_range(float v, float full_scale)
{
    return fabsf(v) < 0.999f * full_scale; /* false for NaN */
}

bool rod_imu_step(rod_imu_t *m, const rod_imu_reading_t *r, int32_t count)
{
    bool stuck = r->gyro == m->last.gyro && r->accel_x == m->last.accel_x && r->accel_y == m->last.accel_y;
    bool good = r->fresh && !stuck && in_range(r->gyro, ROD_IMU_GYRO_RANGE_RAD_S)
                && in_range(r->accel_x, ROD_IMU_ACCEL_RANGE_M_S2) && in_range(r->accel_y, ROD_IMU_ACCEL_RANGE_M_S2);
    if (r->fresh) {
        m->last = *r;
    }
    if (good) {
        m->bad_run = 0u;
    } else if (m->bad_run < UINT32_MAX) { /* held, not wrapped: a part gone for 50 days is still lost */
        m->bad_run++;
    }

    if (count != m->still_count) {
        m->still_count = count;
        m->still = 0;
    } else if (m->still < ROD_IMU_REST_PERIODS) {
        m->still++;
    } else if (good) {
        if (!m->bias_known) {
            m->gyro_bias = r->gyro;
            m->bias_known = true;
        } else {
            m->gyro_bias += ROD_IMU_BIAS_K * (r->gyro - m->gyro_bias);
        }
    }
    return good;
}
