// board_pins.h -- every pin and board constant of the Teensy 3.5 rod testbed, in one place.
//
// Checked against PaulStoffregen/cores teensy3/core_pins.h (MK64FX512 section: CORE_PINn_CONFIG)
// and the K64 signal multiplexing (PTA12/PTA13 ALT7 = FTM1_QD_PHA/PHB).
#ifndef BOARD_PINS_H
#define BOARD_PINS_H

// Encoder, hardware quadrature on FTM1 (pin mux ALT7).
#define BOARD_PIN_ENC_A 3   // PTA12 = FTM1_QD_PHA (CORE_PIN3_CONFIG = PORTA_PCR12)
#define BOARD_PIN_ENC_B 4   // PTA13 = FTM1_QD_PHB (CORE_PIN4_CONFIG = PORTA_PCR13)

// MAX14870 driver.
#define BOARD_PIN_PWM 5     // PTD7 = FTM0_CH7, analogWrite
#define BOARD_PIN_DIR 6     // PTD4, GPIO
#define BOARD_PIN_NEN 7     // PTD2, GPIO, low = driver enabled
#define BOARD_PIN_NFAULT 8  // PTD3, open drain from the driver: INPUT_PULLUP, low = fault
#define BOARD_PIN_LED 13    // PTC5, on-board LED

// Tip IMU (ICM-42686-P), SPI0; used only by a firmware designed with sensors.tip_imu. SCK moves to
// its alternate pin 14 (PTD1) because 13 is the LED.
#define BOARD_PIN_IMU_CS 10    // PTC4, GPIO chip select
#define BOARD_PIN_IMU_MOSI 11  // PTC6 = SPI0_SOUT
#define BOARD_PIN_IMU_MISO 12  // PTC7 = SPI0_SIN
#define BOARD_PIN_IMU_SCK 14   // PTD1 = SPI0_SCK (alternate)
#define BOARD_IMU_SPI_HZ 8000000u  // the part takes 24 MHz; 8 MHz keeps the flex cable to the tip clean
                                   // (SPISettings rounds down to a bus divider: 7.5 MHz at F_BUS 60 MHz)
// The part's axes (0 x, 1 y, 2 z) and signs that give the rod's frame (rod_io.h): x along the rod
// toward the tip, y toward increasing theta, gyro z = d theta / dt. As mounted on the flex with the
// part's x toward the tip and its z out of the swing plane toward the viewer; `rodctl identify
// --imu` checks them on the hanging rod.
#define BOARD_IMU_X_AXIS 0
#define BOARD_IMU_X_SIGN 1.0f
#define BOARD_IMU_Y_AXIS 1
#define BOARD_IMU_Y_SIGN 1.0f
#define BOARD_IMU_Z_AXIS 2
#define BOARD_IMU_Z_SIGN 1.0f

// The wiring's signs when the board has none stored: theta_1 and the count must rise together, and
// a positive duty must accelerate theta_1 positively. `rodctl check --fix` measures them and stores
// them on the board (SAVE_RIG), which then wins over these; the core applies them (rod_rig.h).
#define BOARD_ENCODER_SIGN 1
#define BOARD_MOTOR_DIR_SIGN 1

// analogWrite resolution for the PWM pin; at 20 kHz FTM0 counts to 3000 (60 MHz bus), so 12
// bits is finer than the hardware and loses nothing.
#define BOARD_PWM_RESOLUTION_BITS 12

// Encoder input filters: a phase edge must be stable 4 x FVAL bus clocks (K64 RM, FTMx_FILTER):
// 8 -> 32 clocks = 0.53 us at 60 MHz, far below the 120 us between counts at no-load speed.
#define BOARD_ENCODER_FILTER 8
// Time the filters take to settle on the lines' levels at start-up, before the count is zeroed [us]
#define BOARD_ENCODER_SETTLE_US 5

// NVIC priorities (lower = more urgent; the K64 implements the top 4 bits). USB runs at 112
// (usb_dev.c usb_init), IntervalTimer defaults to 128, SysTick at 32 (mk20dx128.c).
#define BOARD_CONTROL_IRQ_PRIORITY 64  // the control step preempts USB
#define BOARD_NFAULT_IRQ_PRIORITY 32   // a driver fault preempts the control step

// Kinetis watchdog: reset when the main loop stops, or the control interrupt stops running. A
// healthy loop() can already be held 70 ms by one USB write, plus the 10 ms refresh pace and an
// EEPROM write (disarmed), on a clock (the LPO) that is itself a few per cent off; and a restart
// from the watchdog holds the board in FAULT until a power-on (RESET: its zero is lost), so a false
// one must not happen. A stopped control interrupt, which leaves the driver as it was, is what the
// margin costs: the fault handlers turn the driver off at once (board_failsafe.cpp), a hung step
// within this timeout.
#define BOARD_WATCHDOG_ENABLED 1
#define BOARD_WATCHDOG_TIMEOUT_MS 250

#endif  // BOARD_PINS_H
