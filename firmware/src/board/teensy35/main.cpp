// main.cpp -- the Teensy 3.5 board: pins, timer, USB. The firmware itself is rod_device (core).
//
// Control step: IntervalTimer interrupt every ROD_LOOP_PERIOD_US at a priority above USB; it reads
// the encoder and nFAULT, runs rod_device_step, and drives DIR / PWM / nEN. USB: only in loop(),
// which does not wait on the host: host bytes go to rod_device_rx (leftovers kept while the core's
// command ring is full); frames from rod_device_tx are written only as far as the current USB
// packet has room (usb_serial_write_buffer_free() is the room in one 64-byte packet, not the whole
// queue), and a frame that finds no room at all is dropped and counted. One wait remains: the USB
// start-of-frame interrupt can take the packet between availableForWrite() and write()
// (usb_serial.c's own TODO), and write() then waits up to TX_TIMEOUT_MSEC (70 ms) once. Control
// runs on in its interrupt meanwhile, and 70 ms plus the 10 ms refresh period stays well inside the
// 250 ms watchdog (board_pins.h).
//
// Teensyduino API checked in PaulStoffregen/cores teensy3/: IntervalTimer.h (priority(),
// begin(f, unsigned us)), usb_serial.h (available, readBytes, availableForWrite, write, baud),
// usb_serial.c (write_buffer_free semantics), usb_dev.c (134 baud: reboot), pins_teensy.c
// (analogWrite*, micros is ISR-safe), core_pins.h (digitalWriteFast, delayMicroseconds,
// CORE_PINn_*), kinetis.h (NVIC_SET_PRIORITY, IRQ_PORTD, RCM_SRS0/1).
#include "board_framework.h"

#include <math.h>

#include "board_imu.h"
#include "board_pins.h"
#include "board_quadrature.h"
#include "board_storage.h"
#include "board_watchdog.h"
#include "rod_device.h"

// ARMv7-M debug registers (architecture addresses), in case this kinetis.h lacks the names.
#ifndef ARM_DWT_CYCCNT
#define ARM_DEMCR (*(volatile uint32_t *)0xE000EDFC)
#define ARM_DEMCR_TRCENA (1u << 24)
#define ARM_DWT_CTRL (*(volatile uint32_t *)0xE0001000)
#define ARM_DWT_CTRL_CYCCNTENA (1u << 0)
#define ARM_DWT_CYCCNT (*(volatile uint32_t *)0xE0001004)
#endif

static rod_device_t device;
static IntervalTimer control_timer;

static volatile bool nfault_seen;    // set by the nFAULT edge, consumed by the next step
static volatile uint32_t steps_run;  // advances every step: the watchdog's proof of life
static uint32_t last_step_us;        // CPU time of the previous step (control ISR only)
static uint32_t pwm_level = 0;       // last analogWrite value (control ISR only)
static bool timer_failed;            // control_timer.begin() refused: loop() steps, driver off

static const uint32_t PWM_FULL = 1u << BOARD_PWM_RESOLUTION_BITS;

// Falling nFAULT: the driver reports a fault. Off at once, before the next control step sees it.
static void nfault_falling()
{
    digitalWriteFast(BOARD_PIN_NEN, HIGH);
    nfault_seen = true;
}

static void apply(const rod_outputs_t &out)
{
    if (!out.enable) {
        digitalWriteFast(BOARD_PIN_NEN, HIGH);  // off first, then the PWM
    }
    float duty = out.enable ? out.duty : 0.0f;  // signed by the core (the rig's motor sign)
    uint32_t level = (uint32_t)(fabsf(duty) * (float)PWM_FULL + 0.5f);
    if (level > PWM_FULL) {
        level = PWM_FULL;
    }
    digitalWriteFast(BOARD_PIN_DIR, duty < 0.0f ? HIGH : LOW);
    if (level != pwm_level) {
        analogWrite(BOARD_PIN_PWM, (int)level);  // 0 and PWM_FULL become a steady low / high
        pwm_level = level;
    }
    if (out.enable) {
        // A fault edge arriving after this step read nFAULT must still win: check and enable
        // without being interrupted in between.
        __disable_irq();
        if (!nfault_seen) {
            digitalWriteFast(BOARD_PIN_NEN, LOW);
        }
        __enable_irq();
    }
}

// The host asks for the bootloader by setting the port to 134 baud (Teensy Loader, PlatformIO's
// upload); 15 ms later the USB interrupt halts the CPU with a breakpoint (usb_dev.c
// usb_reboot_timer), where the PWM and nEN would hold their levels, and the watchdog with them
// (it does not run while the core is halted), until the bootloader resets the chip. So the driver
// goes off on the first step that sees the request.
static bool upload_requested()
{
    // usb_dev.c copies the line coding a byte at a time, and this step may preempt that copy: it then
    // reads a mix of two rates for one period, and 134 only from a host that sets a rate no host uses
    return Serial.baud() == 134u;
}

static void control_step()
{
    uint32_t start = ARM_DWT_CYCCNT;
    if (upload_requested()) {
        rod_device_board_fault(&device, ROD_REASON_UPLOAD);  // this step ends with the outputs off
    }
    rod_inputs_t in;
    in.now_us = micros();
    in.encoder_count = board_quadrature_count();
    in.last_step_us = last_step_us;
    bool edge = nfault_seen;
    in.driver_fault = edge || digitalReadFast(BOARD_PIN_NFAULT) == LOW;
    board_imu_take(&in.imu);

    rod_outputs_t out;
    rod_device_step(&device, &in, &out);
    if (edge) {
        nfault_seen = false;  // reported: the core has latched FAULT and disabled the outputs
    }
    apply(out);
    board_imu_start();  // the next step's sample, read while this period runs on

    steps_run = steps_run + 1;
    last_step_us = (ARM_DWT_CYCCNT - start) / (F_CPU / 1000000u);
}

// ---- main loop: USB both ways, not waiting on the host ----------------------------------------

static uint8_t rx_buf[64];
static size_t rx_len, rx_used;

static void service_rx()
{
    if (rx_used == rx_len) {
        int avail = Serial.available();
        if (avail <= 0) {
            return;
        }
        size_t want = (size_t)avail < sizeof rx_buf ? (size_t)avail : sizeof rx_buf;
        rx_len = Serial.readBytes((char *)rx_buf, want);  // want <= available, timeout 0: returns at once
        rx_used = 0;
    }
    rx_used += rod_device_rx(&device, rx_buf + rx_used, rx_len - rx_used);
}

static uint8_t tx_buf[ROD_DEVICE_FRAME_MAX];
static size_t tx_len, tx_sent;
static bool tx_cut;  // part of a dropped frame went out: end it with a delimiter before the next

static void service_tx()
{
    if (tx_cut) {
        // Without this 0x00 the host would glue the next frame onto the cut one and lose both.
        if (Serial.availableForWrite() <= 0) {
            return;
        }
        static const uint8_t delimiter = 0;
        if (Serial.write(&delimiter, 1) != 1) {
            return;
        }
        tx_cut = false;
    }
    for (;;) {
        if (tx_sent == tx_len) {
            tx_len = rod_device_tx(&device, tx_buf, sizeof tx_buf);
            tx_sent = 0;
            if (tx_len == 0) {
                return;
            }
            if (Serial.availableForWrite() <= 0) {
                // Host not reading (or not connected): drop this frame, keep the queue fresh.
                rod_device_count_tx_drop(&device);
                tx_len = 0;
                continue;
            }
        }
        int room = Serial.availableForWrite();
        if (room <= 0) {
            return;  // finish this frame once USB has taken the previous packets
        }
        size_t n = tx_len - tx_sent;
        if (n > (size_t)room) {
            n = (size_t)room;
        }
        size_t written = Serial.write(tx_buf + tx_sent, n);  // usb_serial_write: bytes taken, or 0 on error
        if (written != n) {
            // Failed or partial (usb_serial_write's -1 becomes a huge size_t): the frame is dropped
            // and counted (a sequence gap on the host). Whatever part of it went out is cut off by
            // a delimiter first thing next time (a spare 0x00 is harmless: an idle line).
            rod_device_count_tx_drop(&device);
            tx_cut = true;
            tx_len = 0;
            tx_sent = 0;
            return;
        }
        tx_sent += n;
    }
}

// SAVE_RIG: the EEPROM emulation blocks for a few ms per write, so it happens here, never in the
// control interrupt.
static void service_storage()
{
    uint8_t bytes[ROD_RIG_STORE_SIZE];
    if (rod_device_take_save(&device, bytes)) {
        rod_device_saved(&device, board_storage_write(bytes, sizeof bytes));
    }
}

static void service_watchdog()
{
#if BOARD_WATCHDOG_ENABLED
    // Refresh only while the control interrupt is alive too: a stopped timer also resets.
    // (When the timer failed, fallback_step below advances steps_run: the loop is then the proof.)
    static uint32_t steps_at_refresh;
    uint32_t steps = steps_run;
    if (steps != steps_at_refresh && board_watchdog_refresh()) {
        steps_at_refresh = steps;
    }
#endif
}

// Without the control timer: step the device from loop() about once a period, outputs never
// applied (nEN stays high). rod_device_board_fault keeps it in FAULT, so it only reports.
static void fallback_step()
{
    static uint32_t last_us;
    uint32_t now = micros();
    if (now - last_us < ROD_LOOP_PERIOD_US) {
        return;
    }
    last_us = now;
    rod_inputs_t in;
    in.now_us = now;
    in.encoder_count = board_quadrature_count();
    in.last_step_us = 0;
    in.driver_fault = digitalReadFast(BOARD_PIN_NFAULT) == LOW;
    board_imu_take(&in.imu);  // none: nothing starts a transfer without the timer
    rod_outputs_t out;
    rod_device_step(&device, &in, &out);
    digitalWriteFast(BOARD_PIN_NEN, HIGH);
    steps_run = steps_run + 1;
}

static void service_led()
{
    uint8_t mode = device.control.mode;  // one byte, written by the step: a stale read is harmless
    uint32_t ms = millis();
    bool on;
    if (mode == ROD_MODE_BALANCE) {
        on = true;
    } else if (mode == ROD_MODE_SWING_UP || mode == ROD_MODE_CATCH || mode == ROD_MODE_IDENTIFY) {
        on = (ms / 250u) % 2u == 0u;
    } else if (mode == ROD_MODE_FAULT) {
        on = (ms / 60u) % 2u == 0u;
    } else {
        on = (ms / 1000u) % 10u == 0u;  // disarmed: a short blink every 10 s
    }
    digitalWriteFast(BOARD_PIN_LED, on ? HIGH : LOW);
}

void setup()
{
    // Driver disabled before anything else: latch high, then make it an output (no low glitch).
    digitalWriteFast(BOARD_PIN_NEN, HIGH);
    pinMode(BOARD_PIN_NEN, OUTPUT);
    digitalWriteFast(BOARD_PIN_DIR, LOW);
    pinMode(BOARD_PIN_DIR, OUTPUT);
    analogWriteResolution(BOARD_PWM_RESOLUTION_BITS);
    analogWriteFrequency(BOARD_PIN_PWM, (float)ROD_PWM_FREQUENCY_HZ);
    analogWrite(BOARD_PIN_PWM, 0);
    pinMode(BOARD_PIN_LED, OUTPUT);

    pinMode(BOARD_PIN_NFAULT, INPUT_PULLUP);
    attachInterrupt(BOARD_PIN_NFAULT, nfault_falling, FALLING);
    NVIC_SET_PRIORITY(IRQ_PORTD, BOARD_NFAULT_IRQ_PRIORITY);

    // The startup code leaves the cycle counter off; the step times itself with it.
    ARM_DEMCR |= ARM_DEMCR_TRCENA;
    ARM_DWT_CTRL |= ARM_DWT_CTRL_CYCCNTENA;

    board_quadrature_begin();
    (void)board_imu_begin();  // a missing part leaves every sample "none": the core trips IMU if armed
    // Waits up to 2 s for a host to open the port once enumerated (750 ms if not; teensy3/usb_serial.h since
    // 2021). Nothing depends on it: the driver is already off (nEN high above), the control timer and
    // watchdog start after it, and every USB call in loop() copes with no host without waiting for one
    // (frames are dropped and counted).
    Serial.begin(115200);  // USB: the baud rate is ignored
    // Stream's timeout is 1 s: readBytes would spin that long if the host re-enumerates between available()
    // and it (usb_dev.c frees the queued packets), and the 250 ms watchdog would reset the board into FAULT.
    Serial.setTimeout(0);
    rod_device_init(&device);
    {
        uint8_t stored[ROD_RIG_STORE_SIZE];
        board_storage_read(stored, sizeof stored);
        // BOARD_*_SIGN and the header's counts per turn are the compiled defaults, for a board with
        // nothing (or nothing readable) stored
        rod_device_load_rig(&device, stored, sizeof stored,
                            rod_rig_defaults((int8_t)BOARD_ENCODER_SIGN, (int8_t)BOARD_MOTOR_DIR_SIGN));
    }

    // The encoder's zero is the count at start-up, taken as hanging. After a power-on, a pin reset (the
    // bootloader's, after an upload) or a debugger's the rod hangs, the driver having been off; after any
    // restart of the running board it is wherever the run left it (upright, mid-swing), and every angle
    // would be off by that much: the watchdog, a lockup, a software reset, a lost clock or PLL lock, a stop
    // mode error, and a low-voltage reset without a power-on (the USB 5 V dipping as the motor starts).
    if ((RCM_SRS0 & (RCM_SRS0_WDOG | RCM_SRS0_LOC | RCM_SRS0_LOL)) ||
        ((RCM_SRS0 & RCM_SRS0_LVD) && !(RCM_SRS0 & RCM_SRS0_POR)) ||
        (RCM_SRS1 & (RCM_SRS1_LOCKUP | RCM_SRS1_SW | RCM_SRS1_SACKERR))) {
        rod_device_board_fault(&device, ROD_REASON_RESET);
    }

    control_timer.priority(BOARD_CONTROL_IRQ_PRIORITY);  // before begin(): begin applies it
    if (!control_timer.begin(control_step, ROD_LOOP_PERIOD_US)) {
        // No PIT channel (or a period out of range): nothing would run the control. The driver
        // stays off for good; loop() steps the device itself so HELLO and telemetry tell the host
        // (FAULT, reason NO_TIMER), and the LED shows the FAULT pattern.
        timer_failed = true;
        rod_device_board_fault(&device, ROD_REASON_NO_TIMER);
    }
#if BOARD_WATCHDOG_ENABLED
    board_watchdog_begin(BOARD_WATCHDOG_TIMEOUT_MS);
#endif
}

void loop()
{
    if (timer_failed) {
        fallback_step();
    }
    service_rx();
    service_tx();
    service_storage();
    service_watchdog();
    service_led();
}
