// Runs the board layer (firmware/src/board/teensy35/*.cpp) on the host against the stand-in API
// in this folder: simulated time, a USB port that records what the board writes (and can fail
// chosen writes), a timer that can refuse to start, and a recording watchdog. Used by
// tests/test_board_layer.py:
//   board_harness SECONDS TIMER_OK(0|1) FAIL_WRITES(first,count) HOST_HEX [UPLOAD_AT_S [SRS0,SRS1]]
// FAIL_WRITES counts the writes of frame data (more than one byte); those write half their bytes.
// UPLOAD_AT_S: when the host sets the port to 134 baud (an upload's reboot request; < 0 never).
// SRS0,SRS1: the reset-cause registers the board starts with (default a power-on's, 0x82,0).
// Prints `serial HEX` (every byte the board wrote), then key=value lines.
#include <stdio.h>
#include <stdlib.h>
#include <signal.h>
#include <string.h>
#include <unistd.h>

#include <vector>

#include "Arduino.h"
#include "IntervalTimer.h"
#include "avr/eeprom.h"

volatile uint32_t stub_reg32[1024];
volatile uint16_t stub_reg16[64];
usb_serial_class Serial;
stub_refresh_register stub_wdog_refresh;

static uint64_t now_us;
static uint8_t pins[64];
static bool nen_low_ever;
static unsigned led_toggles;
static bool timer_ok = true;
static void (*timer_isr)() = nullptr;
static long write_calls, fail_first = -1, fail_count;
static std::vector<uint8_t> out_bytes, host_bytes;
static size_t host_pos;
static std::vector<uint64_t> refresh_ms;
static uint32_t line_baud = 9600;
static long serial_timeout_ms = 1000;  // Stream's default (teensy3/Stream.h)
static uint64_t nen_low_last_us;  // the last time nEN was seen low
static uint16_t last_refresh_value;

// The EEPROM emulation: erased (0xFF) at power-on, as a new Teensy's
static uint8_t eeprom[2048];
static bool eeprom_ready = (memset(eeprom, 0xFF, sizeof eeprom), true);
extern "C" void eeprom_read_block(void *buf, const void *addr, uint32_t len)
{
    memcpy(buf, eeprom + (uintptr_t)addr, len);
}
// HARNESS_EEPROM_FAILS=N: the first N writes change nothing (a worn cell), so they do not read back
static long eeprom_fails = getenv("HARNESS_EEPROM_FAILS") ? atol(getenv("HARNESS_EEPROM_FAILS")) : 0;
extern "C" void eeprom_write_block(const void *buf, void *addr, uint32_t len)
{
    if (eeprom_fails > 0) {
        eeprom_fails--;
        return;
    }
    memcpy(eeprom + (uintptr_t)addr, buf, len);
}

void digitalWriteFast(uint8_t pin, uint8_t val)
{
    if (pin == 13 && pins[pin] != val) {
        led_toggles++;
    }
    pins[pin] = val;
}
uint8_t digitalReadFast(uint8_t pin) { return pin == 8 ? HIGH : pins[pin]; }  // nFAULT: no fault
void pinMode(uint8_t, uint8_t) {}
void analogWrite(uint8_t, int) {}
uint32_t analogWriteResolution(uint32_t) { return 0; }
void analogWriteFrequency(uint8_t, float) {}
void attachInterrupt(uint8_t, void (*)(void), int) {}
uint32_t micros(void) { return (uint32_t)now_us; }
uint32_t millis(void) { return (uint32_t)(now_us / 1000u); }
void delayMicroseconds(uint32_t usec) { now_us += usec; }

stub_refresh_register &stub_refresh_register::operator=(uint16_t value)
{
    if (last_refresh_value == 0xA602 && value == 0xB480) {
        refresh_ms.push_back(now_us / 1000u);
    }
    last_refresh_value = value;
    return *this;
}

bool IntervalTimer::begin(void (*isr)(), unsigned int)
{
    if (timer_ok) {
        timer_isr = isr;
    }
    return timer_ok;
}
void IntervalTimer::priority(uint8_t) {}

void usb_serial_class::begin(long) {}
void usb_serial_class::setTimeout(unsigned long timeout_ms) { serial_timeout_ms = (long)timeout_ms; }
int usb_serial_class::available() { return (int)(host_bytes.size() - host_pos); }
size_t usb_serial_class::readBytes(char *buffer, size_t length)
{
    size_t n = 0;
    while (n < length && host_pos < host_bytes.size()) {
        buffer[n++] = (char)host_bytes[host_pos++];
    }
    return n;
}
int usb_serial_class::availableForWrite() { return 64; }
uint32_t usb_serial_class::baud(void) { return line_baud; }
size_t usb_serial_class::write(const uint8_t *buffer, size_t size)
{
    long call = size > 1 ? write_calls++ : -2;  // frame data, not a lone delimiter
    if (call >= fail_first && call < fail_first + fail_count) {
        size_t half = size / 2;  // a partial write: half the bytes go out
        out_bytes.insert(out_bytes.end(), buffer, buffer + half);
        return half;
    }
    out_bytes.insert(out_bytes.end(), buffer, buffer + size);
    return size;
}

void setup();
void loop();
extern "C" void startup_early_hook(void);
extern "C" void nmi_isr(void);
extern "C" void svcall_isr(void);
extern "C" void debugmonitor_isr(void);
extern "C" void hard_fault_isr(void);

// A fault handler never returns: the alarm reports where the driver's pins stand while it spins.
static void report_spinning_handler(int)
{
    bool off = (CORE_PIN7_PORTSET & CORE_PIN7_BITMASK) && (CORE_PIN7_DDRREG & CORE_PIN7_BITMASK)
               && CORE_PIN7_CONFIG == PORT_PCR_MUX(1) && (CORE_PIN5_PORTCLEAR & CORE_PIN5_BITMASK)
               && CORE_PIN5_CONFIG == PORT_PCR_MUX(1);
    char line[64];
    int n = snprintf(line, sizeof line, "handler_driver_off=%d\n", off ? 1 : 0);
    (void)!write(1, line, (size_t)n);
    _exit(0);
}
static bool early_driver_off;
static unsigned early_wdog;

int main(int argc, char **argv)
{
    double seconds = argc > 1 ? atof(argv[1]) : 1.0;
    timer_ok = argc > 2 ? atoi(argv[2]) != 0 : true;
    if (argc > 3) {
        sscanf(argv[3], "%ld,%ld", &fail_first, &fail_count);
    }
    if (argc > 4) {
        for (const char *p = argv[4]; p[0] && p[1]; p += 2) {
            unsigned v;
            sscanf(p, "%2x", &v);
            host_bytes.push_back((uint8_t)v);
        }
    }
    double upload_at_s = argc > 5 ? atof(argv[5]) : -1.0;
    const char *vector = argc > 7 ? argv[7] : "-";  // an exception to raise at upload_at_s instead
    unsigned srs0 = 0x82, srs1 = 0;  // POR and LVD: a power-on
    if (argc > 6) {
        sscanf(argv[6], "%x,%x", &srs0, &srs1);
    }
    RCM_SRS0 = srs0;
    RCM_SRS1 = srs1;
    // the core's ResetHandler calls the board's early hook before anything else (board_failsafe.cpp)
    startup_early_hook();
    early_driver_off = (CORE_PIN7_PORTSET & CORE_PIN7_BITMASK) && (CORE_PIN7_DDRREG & CORE_PIN7_BITMASK)
                         && CORE_PIN7_CONFIG == PORT_PCR_MUX(1) && (CORE_PIN5_PORTCLEAR & CORE_PIN5_BITMASK)
                         && (CORE_PIN5_DDRREG & CORE_PIN5_BITMASK) && CORE_PIN5_CONFIG == PORT_PCR_MUX(1)
                         && (SIM_SCGC5 & SIM_SCGC5_PORTD);
    early_wdog = WDOG_STCTRLH;
    pins[7] = HIGH;  // nEN's pull-up
    setup();
    uint64_t next_isr = now_us + 1000u;
    uint64_t end = now_us + (uint64_t)(seconds * 1e6);
    uint64_t upload_us = upload_at_s >= 0 ? now_us + (uint64_t)(upload_at_s * 1e6) : UINT64_MAX;
    while (now_us < end) {
        now_us += 50u;
        if (now_us >= upload_us) {
            void (*isr)(void) = !strcmp(vector, "nmi") ? nmi_isr : !strcmp(vector, "svcall") ? svcall_isr
                                : !strcmp(vector, "debugmonitor") ? debugmonitor_isr : !strcmp(vector, "hard") ? hard_fault_isr
                                : nullptr;
            if (isr != nullptr) {
                printf("nen_low_before=%d\n", pins[7] == LOW ? 1 : 0);
                fflush(stdout);
                signal(SIGALRM, report_spinning_handler);
                alarm(1);
                isr();
            }
            line_baud = 134;
        }
        if (timer_isr != nullptr && now_us >= next_isr) {
            next_isr += 1000u;
            timer_isr();
        }
        if (pins[7] == LOW) {
            nen_low_ever = true;
            nen_low_last_us = now_us;
        }
        loop();
    }
    printf("serial ");
    for (uint8_t b : out_bytes) {
        printf("%02x", b);
    }
    printf("\nnen_low_ever=%d\nled_toggles=%u\nwdog_presc=%u\nwdog_stctrlh=%u\nearly_driver_off=%d\n"
           "early_wdog_stctrlh=%u\nnen_low_last_ms=%.3f\nupload_ms=%.3f\nwdog_timeout_ms=%u\nserial_timeout_ms=%ld\nrefresh_ms=", nen_low_ever ? 1 : 0, led_toggles, (unsigned)WDOG_PRESC,
           (unsigned)WDOG_STCTRLH, early_driver_off ? 1 : 0, early_wdog, nen_low_last_us / 1e3,
           upload_us == UINT64_MAX ? -1.0 : upload_us / 1e3, ((unsigned)WDOG_TOVALH << 16) | WDOG_TOVALL,
           serial_timeout_ms);
    for (size_t i = 0; i < refresh_ms.size(); i++) {
        printf(i ? ",%llu" : "%llu", (unsigned long long)refresh_ms[i]);
    }
    printf("\n");
    return 0;
}
