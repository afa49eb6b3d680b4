// board_failsafe.cpp -- the driver held off where setup() cannot reach: from reset until setup() runs
// (the core's startup and USB enumeration take ~300 ms) and in the fault handlers.
//
// From PaulStoffregen/cores teensy3/mk20dx128.c: ResetHandler unlocks the watchdog and calls the weak
// startup_early_hook() first, before it clocks the GPIO ports and before .data and .bss exist, so the hook
// touches registers only; the core's default hook writes WDOG_STCTRLH = WDOG_STCTRLH_ALLOWUPDATE, which
// this one keeps (board_watchdog.cpp reconfigures it later). hard_fault_isr and the other fault vectors are
// weak aliases of fault_isr (nmi_isr, svcall_isr and debugmonitor_isr of unused_isr, which calls it), which spins
// with every pin as it was: nEN possibly low and the PWM running
// until the watchdog resets the chip. The 10 k pull-up on nEN (docs/wiring.md) covers the reset itself.
#include "board_framework.h"
#include "board_pins.h"

#define BOARD_PIN_REG_(n, what) CORE_PIN##n##_##what
#define BOARD_PIN_REG(n, what) BOARD_PIN_REG_(n, what)  // expands the pin number first

static inline void driver_pins_off(void)
{
    BOARD_PIN_REG(BOARD_PIN_NEN, PORTSET) = BOARD_PIN_REG(BOARD_PIN_NEN, BITMASK);  // latched high, then driven
    BOARD_PIN_REG(BOARD_PIN_NEN, DDRREG) |= BOARD_PIN_REG(BOARD_PIN_NEN, BITMASK);
    BOARD_PIN_REG(BOARD_PIN_NEN, CONFIG) = PORT_PCR_MUX(1);
    BOARD_PIN_REG(BOARD_PIN_PWM, PORTCLEAR) = BOARD_PIN_REG(BOARD_PIN_PWM, BITMASK);
    BOARD_PIN_REG(BOARD_PIN_PWM, DDRREG) |= BOARD_PIN_REG(BOARD_PIN_PWM, BITMASK);
    BOARD_PIN_REG(BOARD_PIN_PWM, CONFIG) = PORT_PCR_MUX(1);  // GPIO low, off the timer
}

extern "C" void startup_early_hook(void)
{
    WDOG_STCTRLH = WDOG_STCTRLH_ALLOWUPDATE;
    SIM_SCGC5 |= SIM_SCGC5_PORTA | SIM_SCGC5_PORTB | SIM_SCGC5_PORTC | SIM_SCGC5_PORTD | SIM_SCGC5_PORTE;
    driver_pins_off();
}

static void driver_off_and_wait(void)
{
    driver_pins_off();
    for (;;) {
        __asm__ volatile("nop");  // the watchdog, once started, resets the chip; until then nothing runs
    }
}

extern "C" void hard_fault_isr(void)
{
    driver_off_and_wait();
}

extern "C" void memmanage_fault_isr(void)
{
    driver_off_and_wait();
}

extern "C" void bus_fault_isr(void)
{
    driver_off_and_wait();
}

extern "C" void usage_fault_isr(void)
{
    driver_off_and_wait();
}

// The core's weak aliases of unused_isr, which spins in fault_isr with the pins as they were. Not
// pendablesrvreq_isr: EventResponder.cpp defines it, and a second definition would not link.
extern "C" void nmi_isr(void)
{
    driver_off_and_wait();
}

extern "C" void svcall_isr(void)
{
    driver_off_and_wait();
}

extern "C" void debugmonitor_isr(void)
{
    driver_off_and_wait();
}
