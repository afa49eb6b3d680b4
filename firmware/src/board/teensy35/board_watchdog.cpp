// board_watchdog.cpp -- WDOG set-up and refresh.
//
// Sequence as in PaulStoffregen/cores teensy3/mk20dx128.c: ResetHandler unlocks the WDOG
// (WDOG_UNLOCK_SEQ1 then WDOG_UNLOCK_SEQ2, two nops) and the default startup_early_hook writes
// WDOG_STCTRLH = WDOG_STCTRLH_ALLOWUPDATE, i.e. the watchdog is off but may be reconfigured.
// Reconfiguring needs the same unlock, then the writes within the 256-bus-clock window, with
// interrupts off so nothing can stretch it. Register names from teensy3/kinetis.h; the refresh
// pair 0xA602, 0xB480 (within 20 bus clocks) is the K64 reference manual's.
#include <Arduino.h>

#include "board_watchdog.h"

void board_watchdog_begin(uint32_t timeout_ms)
{
    __disable_irq();
    WDOG_UNLOCK = WDOG_UNLOCK_SEQ1;
    WDOG_UNLOCK = WDOG_UNLOCK_SEQ2;
    __asm__ volatile("nop");  // at least one bus clock before the configuration writes
    __asm__ volatile("nop");
    WDOG_TOVALH = (uint16_t)(timeout_ms >> 16);
    WDOG_TOVALL = (uint16_t)(timeout_ms & 0xFFFFu);
    WDOG_PRESC = 0;  // LPO 1 kHz undivided (the reset value divides by 5)
    WDOG_STCTRLH = WDOG_STCTRLH_WDOGEN;  // LPO clock; ALLOWUPDATE cleared: locked until reset
    __enable_irq();
}

void board_watchdog_refresh()
{
    __disable_irq();
    WDOG_REFRESH = 0xA602;
    WDOG_REFRESH = 0xB480;
    __enable_irq();
}
