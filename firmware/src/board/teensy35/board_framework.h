// board_framework.h -- the Teensyduino headers, included once for the whole board layer.
//
// platformio.ini builds our sources with -Wall -Wextra -Wdouble-promotion, and those flags reach
// the framework's headers when we include them: kinetis.h and CrashReport.h alone give 24
// unused-parameter warnings (core 1.62). Those are not ours to fix, so they are silenced here,
// around the includes only; our own code after this header keeps every warning.
#ifndef BOARD_FRAMEWORK_H
#define BOARD_FRAMEWORK_H

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wdouble-promotion"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wtype-limits"
#pragma GCC diagnostic ignored "-Wimplicit-fallthrough"
#pragma GCC diagnostic ignored "-Wcast-function-type"
#pragma GCC diagnostic ignored "-Wdeprecated-copy"  // DMAChannel.h (cores 1.58 to 1.59)
#include <Arduino.h>
#include <IntervalTimer.h>
#include <SPI.h>
#include <avr/eeprom.h>
#pragma GCC diagnostic pop

#endif  // BOARD_FRAMEWORK_H
