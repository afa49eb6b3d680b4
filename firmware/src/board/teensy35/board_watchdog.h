// board_watchdog.h -- the Kinetis WDOG as a last line of defence.
#ifndef BOARD_WATCHDOG_H
#define BOARD_WATCHDOG_H

#include <stdint.h>

#include "board_pins.h"

// Refresh cadence (why: board_watchdog.cpp). The WDOG clock is the 1 kHz LPO, so these are in
// WDOG clocks too: the first refresh waits for the 2-3 clocks a new configuration takes to apply,
// and refreshes stay many clocks apart.
#define BOARD_WATCHDOG_SETTLE_MS 5u
#define BOARD_WATCHDOG_REFRESH_MS 10u

static_assert(BOARD_WATCHDOG_TIMEOUT_MS >= 4u * (BOARD_WATCHDOG_SETTLE_MS + BOARD_WATCHDOG_REFRESH_MS),
              "watchdog timeout must leave room for several refresh periods");

// Enables the watchdog with a timeout of timeout_ms (1 kHz LPO clock); the configuration is
// locked until the next reset. Call at the end of setup().
void board_watchdog_begin(uint32_t timeout_ms);

// Restarts the watchdog timeout when the cadence allows (not within BOARD_WATCHDOG_SETTLE_MS of
// begin, not within BOARD_WATCHDOG_REFRESH_MS of the last refresh); returns whether it did.
// Main loop only: call it as often as you like.
bool board_watchdog_refresh();

#endif  // BOARD_WATCHDOG_H
