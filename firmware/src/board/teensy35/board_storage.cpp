// board_storage.cpp -- EEPROM reads and writes for the rig record; no logic (rod_rig.c decides).
#include "board_framework.h"

#include "board_storage.h"

#include <string.h>

void board_storage_read(uint8_t *out, size_t n)
{
    eeprom_read_block(out, (const void *)BOARD_RIG_EEPROM_ADDR, (uint32_t)n);
}

bool board_storage_write(const uint8_t *data, size_t n)
{
    uint8_t back[32];
    if (n > sizeof back) {
        return false;  // refused before anything is written: the record could not be read back
    }
    eeprom_write_block(data, (void *)BOARD_RIG_EEPROM_ADDR, (uint32_t)n);
    board_storage_read(back, n);
    return memcmp(back, data, n) == 0;
}
