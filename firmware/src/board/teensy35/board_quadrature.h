// board_quadrature.h -- the encoder count from FTM1's hardware quadrature decoder.
#ifndef BOARD_QUADRATURE_H
#define BOARD_QUADRATURE_H

#include <stdint.h>

// Configures FTM1 (taking it over from the core's PWM set-up) and the two pins; count = 0.
void board_quadrature_begin();

// The 16-bit hardware counter extended to 32 bits. Call at least once per 32767 counts of
// motion (every control period: the motor turns < 10 counts per period); control ISR only.
int32_t board_quadrature_count();

#endif  // BOARD_QUADRATURE_H
