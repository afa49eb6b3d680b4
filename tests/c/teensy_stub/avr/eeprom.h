// Stand-in for Teensyduino's avr/eeprom.h (teensy3/avr_functions.h): the declarations the board
// layer uses, with the framework's exact signatures; board_harness.cpp keeps the bytes in memory.
#ifndef STUB_AVR_EEPROM_H
#define STUB_AVR_EEPROM_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

void eeprom_read_block(void *buf, const void *addr, uint32_t len);
void eeprom_write_block(const void *buf, void *addr, uint32_t len);

#ifdef __cplusplus
}
#endif

#endif
