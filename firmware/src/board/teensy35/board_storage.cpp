// board_storage.cpp -- EEPROM reads and writes for the rig record; no logic (rod_rig.c decides).
#include "board_framework.h"

#include "board_storage.h"

void board_storage_read(uint8_t *out, size_t n)
{
    eeprom_read_block(out, (const void *)BOARD_RIG_EEPROM_ADDR, (uint32_t)n);
}

void board_storage_write(const uint8_t *data, size_t n)
{
    eeprom_write_block(data, (void *)BOARD_RIG_EEPROM_ADDR, (uint32_t)n);
}
