// board_watchdog.cpp -- WDOG set-up and refresh.
//
// Sequence as in PaulStoffregen/cores teensy3/mk20dx128.c: ResetHandler unlocks the WDOG
// (WDOG_UNLOCK_SEQ1 then WDOG_UNLOCK_SEQ2, two nops) and the default startup_early_hook writes
// WDOG_STCTRLH = WDOG_STCTRLH_ALLOWUPDATE, i.e. the watchdog is off but may be reconfigured.
// Reconfiguring needs the same unlock, then the writes within the 256-bus-clock window, with
// interrupts off so nothing can stretch it. Register names from teensy3/kinetis.h; the refresh
// pair 0xA602, 0xB480 (within 20 bus clocks) is the K64 reference manual's.
//
// Clock and cadence. The WDOG runs from the 1 kHz LPO, undivided: the LPO is independent of the
// PLL and bus clock, so a clock failure still ends in a reset, and a 1 ms tick gives the timeout
// in milliseconds. The cost of so slow a clock is that the WDOG takes 2-3 of its clocks (up to
// 3 ms) to apply a new configuration, and two refreshes closer than one WDOG clock (1 ms) apart
// may be taken as a bad refresh sequence and reset the chip. Hence the refresh below is gated:
// never in the first BOARD_WATCHDOG_SETTLE_MS after begin, and at most every
// BOARD_WATCHDOG_REFRESH_MS; both are far inside the timeout (static_asserts in board_watchdog.h).
#include "board_framework.h"

#include "board_watchdog.h"

static uint32_t begun_ms;
static uint32_t refreshed_ms;
static bool refreshed_once;

void board_watchdog_begin(uint32_t timeout_ms)
{
    __disable_irq();
    WDOG_UNLOCK = WDOG_UNLOCK_SEQ1;
    WDOG_UNLOCK = WDOG_UNLOCK_SEQ2;
    __asm__ volatile("nop");  // at least one bus clock before the configuration writes
    __asm__ volatile("nop");
    WDOG_TOVALH = (uint16_t)(timeout_ms >> 16);
    WDOG_TOVALL = (uint16_t)(timeout_ms & 0xFFFFu);
    WDOG_PRESC = 0;  // PRESCVAL (bits 10:8) = 0: LPO 1 kHz undivided (the reset value divides by 5)
    WDOG_STCTRLH = WDOG_STCTRLH_WDOGEN;  // CLKSRC 0 = LPO; ALLOWUPDATE cleared: locked until reset
    __enable_irq();
    begun_ms = millis();
    refreshed_once = false;
}

bool board_watchdog_refresh()
{
    uint32_t now = millis();
    if (now - begun_ms < BOARD_WATCHDOG_SETTLE_MS) {
        return false;  // the new configuration may not be applied yet
    }
    if (refreshed_once && now - refreshed_ms < BOARD_WATCHDOG_REFRESH_MS) {
        return false;  // too soon after the last one
    }
    __disable_irq();
    WDOG_REFRESH = 0xA602;
    WDOG_REFRESH = 0xB480;
    __enable_irq();
    refreshed_ms = now;
    refreshed_once = true;
    return true;
}
