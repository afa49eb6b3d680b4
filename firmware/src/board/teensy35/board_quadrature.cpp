// board_quadrature.cpp -- FTM1 in quadrature decoder mode (K64 RM "Quadrature Decoder mode").
//
// Registers and bit names from PaulStoffregen/cores teensy3/kinetis.h: FTM1_*, FTM_MODE_*,
// FTM_SC_*, FTM_QDCTRL_* and FTM_FILTER_CHnFVAL(). FTM1's clock gate is already on
// (mk20dx128.c ResetHandler: SIM_SCGC6_FTM1), and _init_Teensyduino_internal_ left it running
// as a PWM timer.
#include "board_framework.h"

#include "board_pins.h"
#include "board_quadrature.h"

static uint16_t last_hw;
static uint32_t extended;  // unsigned: wraps after 2^32 counts like the core's own count arithmetic (rod_angle.c)

void board_quadrature_begin()
{
    FTM1_SC = 0;  // stop the counter while it is reconfigured
    FTM1_MODE = FTM_MODE_WPDIS;  // write protection off first, then the FTM feature set on
    FTM1_MODE = FTM_MODE_WPDIS | FTM_MODE_FTMEN;
    FTM1_C0SC = 0;  // the core had both channels as PWM outputs
    FTM1_C1SC = 0;
    FTM1_CNTIN = 0;
    FTM1_MOD = 0xFFFF;
    // Channel 0 filters phase A, channel 1 phase B; QUADMODE left 0: phase A/B encoding.
    FTM1_FILTER = FTM_FILTER_CH0FVAL(BOARD_ENCODER_FILTER) | FTM_FILTER_CH1FVAL(BOARD_ENCODER_FILTER);
    FTM1_QDCTRL = FTM_QDCTRL_PHAFLTREN | FTM_QDCTRL_PHBFLTREN | FTM_QDCTRL_QUADEN;
    // ALT7 = FTM1_QD_PHA / FTM1_QD_PHB; pull-ups keep the lines defined if the encoder is unplugged.
    // Muxed before the counter runs: switching a pin to the decoder moves its input to the
    // encoder's level, an edge the filter would pass a few clocks after the count below was read.
    CORE_PIN3_CONFIG = PORT_PCR_MUX(7) | PORT_PCR_PE | PORT_PCR_PS;
    CORE_PIN4_CONFIG = PORT_PCR_MUX(7) | PORT_PCR_PE | PORT_PCR_PS;
    FTM1_SC = FTM_SC_CLKS(1) | FTM_SC_PS(0);  // system clock for the filters, no prescaler
    // The filters start from low and reach the lines' levels within FVAL x 4 clocks (1 us at most):
    // whatever they counted on the way is not motion. Zero after that (any write loads CNTIN).
    delayMicroseconds(BOARD_ENCODER_SETTLE_US);
    FTM1_CNT = 0;
    last_hw = (uint16_t)FTM1_CNT;
    extended = 0;
}

int32_t board_quadrature_count()
{
    uint16_t hw = (uint16_t)FTM1_CNT;
    // The signed 16-bit difference is the motion since the last call, across counter wrap.
    extended += (uint32_t)(int32_t)(int16_t)(uint16_t)(hw - last_hw);
    last_hw = hw;
    return (int32_t)extended;  // the core applies the rig's encoder sign (rod_rig.h)
}
