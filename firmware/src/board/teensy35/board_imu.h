// board_imu.h -- the tip IMU (TDK ICM-42686-P on SPI0): set-up, and a read pipelined across periods.
//
// Each control step takes the sample whose DMA transfer the previous step started, and then
// starts the next one (board_imu_start): the SPI transfer (13 bytes at 8 MHz, ~15 us) runs during
// the rest of the period instead of inside the step, and the sample the core sees is one period
// old, which the estimator models (sensors.latency = 1 ms). Only a firmware designed with the IMU
// (ROD_NY > 1) drives the part; otherwise every reading is "none".
#ifndef BOARD_IMU_H
#define BOARD_IMU_H

#include <stdbool.h>

#include "rod_io.h"

// Returns whether the part answered (WHO_AM_I) and took its configuration.
bool board_imu_begin(void);
// The sample that arrived since the last call, in the rod's frame and SI units (fresh false: none).
void board_imu_take(rod_imu_reading_t *out);
// Start reading the next sample (from the control step, after the outputs are set).
void board_imu_start(void);

#endif  // BOARD_IMU_H
