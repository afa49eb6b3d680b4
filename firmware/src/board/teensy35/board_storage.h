// board_storage.h -- the rig settings' bytes in the Teensy's EEPROM emulation (FlexRAM).
#ifndef BOARD_STORAGE_H
#define BOARD_STORAGE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

// Where the rig record (rod_rig.h, ROD_RIG_STORE_SIZE bytes) lives in the EEPROM.
#define BOARD_RIG_EEPROM_ADDR 0u

void board_storage_read(uint8_t *out, size_t n);
// true when the bytes read back as written (n <= 32)
bool board_storage_write(const uint8_t *data, size_t n);

#endif  // BOARD_STORAGE_H
