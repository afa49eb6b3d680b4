/* rod_io.h -- what the board hands the control step each period, and what it gets back. */
#ifndef ROD_IO_H
#define ROD_IO_H

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* The tip IMU's newest sample, in the sensor frame on the rod (rodgains/imu.py): x along the rod toward
 * the tip, y its normal toward increasing theta, z the gyro axis that reads the edge's rate. The board
 * maps the part's axes and scales to these; a board without the IMU leaves fresh false. */
typedef struct {
    float gyro;    /* rate about z [rad/s] */
    float accel_x; /* specific force along x [m/s^2] */
    float accel_y; /* specific force along y [m/s^2] */
    bool fresh;    /* a new sample came this period */
} rod_imu_reading_t;

typedef struct {
    int32_t encoder_count; /* quadrature count, 0 hanging at power-on, rises with theta_1 */
    uint32_t now_us;       /* start time of this step [us], free-running (wraps) */
    uint32_t last_step_us; /* CPU time the previous step took [us] (0 on the first step) */
    bool driver_fault;     /* driver nFAULT pin reads low */
    rod_imu_reading_t imu; /* the tip IMU (a firmware designed with it, ROD_NY > 1) */
} rod_inputs_t;

typedef struct {
    bool enable;  /* drive the driver's nEN low */
    float duty;   /* signed PWM duty [-1, 1]: sign -> DIR pin, magnitude -> PWM */
    float torque; /* output torque this duty gives [N m] (for telemetry and the SIL) */
} rod_outputs_t;

#ifdef __cplusplus
}
#endif

#endif /* ROD_IO_H */
