// Stand-in for the Teensyduino 3.x API the board layer uses (tests/test_board_layer.py): the
// board sources compile against it for the M4F (-Wall -Wextra -Werror), and on the host it runs
// them (board_harness.cpp). Declarations follow the signatures in PaulStoffregen/cores teensy3/
// (core_pins.h, usb_serial.h, IntervalTimer.h, kinetis.h); registers are plain memory here, and
// the watchdog's refresh register records when it is written.
#ifndef TEENSY_STUB_ARDUINO_H
#define TEENSY_STUB_ARDUINO_H

#include <stddef.h>
#include <stdint.h>

#define F_CPU 120000000
#define HIGH 1
#define LOW 0
#define OUTPUT 1
#define INPUT_PULLUP 2
#define FALLING 2

// Like the real headers, this one has what -Wextra warns about (an unused parameter): the board
// layer must include it through board_framework.h, which silences exactly that.
static inline void stub_framework_hook(int unused_in_framework) {}

void digitalWriteFast(uint8_t pin, uint8_t val);
uint8_t digitalReadFast(uint8_t pin);
void pinMode(uint8_t pin, uint8_t mode);
void analogWrite(uint8_t pin, int val);
uint32_t analogWriteResolution(uint32_t bits);
void analogWriteFrequency(uint8_t pin, float frequency);
void attachInterrupt(uint8_t pin, void (*function)(void), int mode);
uint32_t micros(void);
uint32_t millis(void);
void delayMicroseconds(uint32_t usec);
#define __disable_irq() __asm__ volatile("" ::: "memory")
#define __enable_irq() __asm__ volatile("" ::: "memory")

extern volatile uint32_t stub_reg32[1024];
extern volatile uint16_t stub_reg16[64];
#define STUB_REG32(a) (stub_reg32[((a) >> 2) & 1023u])
#define STUB_REG16(a) (stub_reg16[((a) >> 1) & 63u])
#define IRQ_PORTD 62  /* kinetis.h, MK64FX512 */
#define NVIC_SET_PRIORITY(irq, prio) (STUB_REG32(0xE000E400u + (irq)) = (uint8_t)(prio))
#define ARM_DEMCR STUB_REG32(0xE000EDFCu)
#define ARM_DEMCR_TRCENA (1u << 24)
#define ARM_DWT_CTRL STUB_REG32(0xE0001000u)
#define ARM_DWT_CTRL_CYCCNTENA (1u << 0)
#define ARM_DWT_CYCCNT STUB_REG32(0xE0001004u)

#define FTM1_SC STUB_REG32(0x40039000u)
#define FTM1_CNT STUB_REG32(0x40039004u)
#define FTM1_MOD STUB_REG32(0x40039008u)
#define FTM1_C0SC STUB_REG32(0x4003900Cu)
#define FTM1_C1SC STUB_REG32(0x40039014u)
#define FTM1_CNTIN STUB_REG32(0x4003904Cu)
#define FTM1_MODE STUB_REG32(0x40039054u)
#define FTM1_FILTER STUB_REG32(0x40039078u)
#define FTM1_QDCTRL STUB_REG32(0x40039080u)
#define FTM_SC_CLKS(n) (((n) & 3) << 3)
#define FTM_SC_PS(n) (((n) & 7) << 0)
#define FTM_MODE_WPDIS 0x04
#define FTM_MODE_FTMEN 0x01
#define FTM_FILTER_CH1FVAL(n) (((n) & 15) << 4)
#define FTM_FILTER_CH0FVAL(n) (((n) & 15) << 0)
#define FTM_QDCTRL_PHAFLTREN 0x80
#define FTM_QDCTRL_PHBFLTREN 0x40
#define FTM_QDCTRL_QUADEN 0x01
#define CORE_PIN3_CONFIG STUB_REG32(0x40049030u)
#define CORE_PIN4_CONFIG STUB_REG32(0x40049034u)
#define PORT_PCR_MUX(n) (uint32_t)(((n) & 7) << 8)
#define PORT_PCR_PE (uint32_t)0x00000002
#define PORT_PCR_PS (uint32_t)0x00000001

// the driver's pins as board_failsafe.cpp drives them before the core's startup (nEN pin 7 = PTD2, PWM pin 5 =
// PTD7; kinetis.h / core_pins.h names)
#define SIM_SCGC5 STUB_REG32(0x40048038u)
#define SIM_SCGC5_PORTA (uint32_t)0x00000200
#define SIM_SCGC5_PORTB (uint32_t)0x00000400
#define SIM_SCGC5_PORTC (uint32_t)0x00000800
#define SIM_SCGC5_PORTD (uint32_t)0x00001000
#define SIM_SCGC5_PORTE (uint32_t)0x00002000
#define CORE_PIN5_BITMASK (1 << 7)
#define CORE_PIN5_PORTCLEAR STUB_REG32(0x400FF0C8u)
#define CORE_PIN5_DDRREG STUB_REG32(0x400FF0D4u)
#define CORE_PIN5_CONFIG STUB_REG32(0x4004C01Cu)
#define CORE_PIN7_BITMASK (1 << 2)
#define CORE_PIN7_PORTSET STUB_REG32(0x400FF0C4u)
#define CORE_PIN7_DDRREG STUB_REG32(0x400FF0D4u)
#define CORE_PIN7_CONFIG STUB_REG32(0x4004C008u)

// the reset's cause (kinetis.h: 8-bit registers at 0x4007F000 / 1; here two stand-in slots no other
// register of this file shares)
#define RCM_SRS0 STUB_REG32(0x4007F200u)
#define RCM_SRS0_POR ((uint8_t)0x80)
#define RCM_SRS0_PIN ((uint8_t)0x40)
#define RCM_SRS0_WDOG ((uint8_t)0x20)
#define RCM_SRS0_LOL ((uint8_t)0x08)
#define RCM_SRS0_LOC ((uint8_t)0x04)
#define RCM_SRS0_LVD ((uint8_t)0x02)
#define RCM_SRS1 STUB_REG32(0x4007F204u)
#define RCM_SRS1_SACKERR ((uint8_t)0x20)
#define RCM_SRS1_SW ((uint8_t)0x04)
#define RCM_SRS1_LOCKUP ((uint8_t)0x02)

#define WDOG_STCTRLH STUB_REG16(0x40052000u)
#define WDOG_STCTRLH_WDOGEN (uint16_t)0x0001
#define WDOG_STCTRLH_ALLOWUPDATE (uint16_t)0x0010
#define WDOG_TOVALH STUB_REG16(0x40052004u)
#define WDOG_TOVALL STUB_REG16(0x40052006u)
#define WDOG_UNLOCK STUB_REG16(0x4005200Eu)
#define WDOG_UNLOCK_SEQ1 (uint16_t)0xC520
#define WDOG_UNLOCK_SEQ2 (uint16_t)0xD928
#define WDOG_PRESC STUB_REG16(0x40052016u)

#ifdef __cplusplus
// Writes to the refresh register are recorded with the time they happened.
struct stub_refresh_register {
    stub_refresh_register &operator=(uint16_t value);
};
extern stub_refresh_register stub_wdog_refresh;
#define WDOG_REFRESH stub_wdog_refresh

class usb_serial_class {
  public:
    void begin(long);
    int available();
    size_t readBytes(char *buffer, size_t length);
    void setTimeout(unsigned long timeout_ms);  // Stream's
    int availableForWrite();
    size_t write(const uint8_t *buffer, size_t size);
    uint32_t baud(void);  // the line coding's rate the host set (usb_cdc_line_coding[0]): 134 asks for a reboot
};
extern usb_serial_class Serial;
#endif

#endif
