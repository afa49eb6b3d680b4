// board_watchdog.h -- the Kinetis WDOG as a last line of defence.
#ifndef BOARD_WATCHDOG_H
#define BOARD_WATCHDOG_H

#include <stdint.h>

// Enables the watchdog with a timeout of timeout_ms (1 kHz LPO clock); the configuration is
// locked until the next reset. Call at the end of setup().
void board_watchdog_begin(uint32_t timeout_ms);

// Restarts the watchdog timeout. Main loop only.
void board_watchdog_refresh();

#endif  // BOARD_WATCHDOG_H
