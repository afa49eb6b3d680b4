// board_quadrature.cpp -- FTM1 in quadrature decoder mode (K64 RM "Quadrature Decoder mode").
//
// Registers and bit names from PaulStoffregen/cores teensy3/kinetis.h (FTM1_*, FTM_MODE_*,
// FTM_SC_*). kinetis.h names the QDCTRL/FILTER registers but not their bits, so those are below
// with the reference manual's names. FTM1's clock gate is already on (mk20dx128.c ResetHandler:
// SIM_SCGC6_FTM1), and _init_Teensyduino_internal_ left it running as a PWM timer.
#include <Arduino.h>

#include "board_pins.h"
#include "board_quadrature.h"

#define QDCTRL_QUADEN 0x01u     // quadrature decoder mode enable (QUADMODE 0: phase A/B)
#define QDCTRL_PHBFLTREN 0x40u  // phase B input filter enable
#define QDCTRL_PHAFLTREN 0x80u  // phase A input filter enable
#define FILTER_CH0FVAL(n) ((uint32_t)((n) & 15u) << 0)  // phase A filter (channel 0)
#define FILTER_CH1FVAL(n) ((uint32_t)((n) & 15u) << 4)  // phase B filter (channel 1)

static uint16_t last_hw;
static int32_t extended;

void board_quadrature_begin()
{
    FTM1_SC = 0;  // stop the counter while it is reconfigured
    FTM1_MODE = FTM_MODE_WPDIS;  // write protection off first, then the FTM feature set on
    FTM1_MODE = FTM_MODE_WPDIS | FTM_MODE_FTMEN;
    FTM1_C0SC = 0;  // the core had both channels as PWM outputs
    FTM1_C1SC = 0;
    FTM1_CNTIN = 0;
    FTM1_MOD = 0xFFFF;
    FTM1_FILTER = FILTER_CH0FVAL(BOARD_ENCODER_FILTER) | FILTER_CH1FVAL(BOARD_ENCODER_FILTER);
    FTM1_QDCTRL = QDCTRL_PHAFLTREN | QDCTRL_PHBFLTREN | QDCTRL_QUADEN;
    FTM1_CNT = 0;  // any write loads CNTIN
    FTM1_SC = FTM_SC_CLKS(1) | FTM_SC_PS(0);  // system clock for the filters, no prescaler
    // ALT7 = FTM1_QD_PHA / FTM1_QD_PHB; pull-ups keep the lines defined if the encoder is unplugged.
    CORE_PIN3_CONFIG = PORT_PCR_MUX(7) | PORT_PCR_PE | PORT_PCR_PS;
    CORE_PIN4_CONFIG = PORT_PCR_MUX(7) | PORT_PCR_PE | PORT_PCR_PS;
    last_hw = (uint16_t)FTM1_CNT;
    extended = 0;
}

int32_t board_quadrature_count()
{
    uint16_t hw = (uint16_t)FTM1_CNT;
    // The signed 16-bit difference is the motion since the last call, across counter wrap.
    extended += (int16_t)(uint16_t)(hw - last_hw);
    last_hw = hw;
    return BOARD_ENCODER_SIGN * extended;
}
