// board_imu.cpp -- ICM-42686-P over SPI0 with an asynchronous (DMA) transfer; see board_imu.h.
//
// Registers (bank 0, the ICM-42688-P's map, DS-000347): DEVICE_CONFIG 0x11 (bit 0 soft reset),
// ACCEL_DATA_X1 0x1F .. GYRO_DATA_Z0 0x2A (big-endian int16, accel then gyro), PWR_MGMT0 0x4E,
// GYRO_CONFIG0 0x4F, ACCEL_CONFIG0 0x50, WHO_AM_I 0x75; bit 7 of the address reads. The 42686-P answers
// 0x44 and its full-scale codes start one step higher: gyro FS_SEL 0 = +-4000 dps, accel FS_SEL 1 = +-16 g
// (Linux inv_icm42600: inv_icm42686_gyro_fs, inv_icm42686_accel_fs).
// SPI API: PaulStoffregen/SPI (SPIClass::transfer(tx, rx, count, EventResponderRef) under
// SPI_HAS_TRANSFER_ASYNC) and cores/teensy3/EventResponder.h (attachImmediate).
#include "board_imu.h"

#include "board_framework.h"
#include "board_pins.h"
#include "rod_config.h"

#if ROD_NY > 1

static const uint8_t REG_DEVICE_CONFIG = 0x11, REG_ACCEL_X1 = 0x1F, REG_PWR_MGMT0 = 0x4E;
static const uint8_t REG_GYRO_CONFIG0 = 0x4F, REG_ACCEL_CONFIG0 = 0x50, REG_WHO_AM_I = 0x75, WHO_AM_I = 0x44;
static const uint8_t READ = 0x80;
// The catch whips the tip to ~3,000 dps (docs/sensors.md): the 42686-P's widest gyro range, FS_SEL 0
// (+-2000 dps on the 42688-P). Its FS_SEL 0 accelerometer range is +-32 g; FS_SEL 1 keeps +-16 g's resolution.
static const uint8_t GYRO_4000DPS_1KHZ = 0x06;   // FS_SEL 000, ODR 0110
static const uint8_t ACCEL_16G_1KHZ = 0x26;      // FS_SEL 001, ODR 0110
static const uint8_t GYRO_ACCEL_LOW_NOISE = 0x0F;
static constexpr float GYRO_RAD_S_PER_LSB = 3.14159265f / 180.0f / 8.192f;  // +-4000 dps: 32768 / 4000 LSB/dps
static constexpr float ACCEL_M_S2_PER_LSB = 9.80665f / 2048.0f;           // +-16 g: 2048 LSB/g
// The core calls a reading past 0.999 of the header's full scale clipped (rod_imu.c): a header designed for a
// wider range would pass clipped readings as good, one for a narrower range call good ones clipped.
static_assert(ROD_IMU_GYRO_RANGE_RAD_S > 0.99f * 32768.0f * GYRO_RAD_S_PER_LSB
                  && ROD_IMU_GYRO_RANGE_RAD_S < 1.001f * 32768.0f * GYRO_RAD_S_PER_LSB,
              "sensors.gyro_range must be this part's full scale, 69.8 rad/s (+-4000 dps)");
static_assert(ROD_IMU_ACCEL_RANGE_M_S2 > 0.99f * 32768.0f * ACCEL_M_S2_PER_LSB
                  && ROD_IMU_ACCEL_RANGE_M_S2 < 1.001f * 32768.0f * ACCEL_M_S2_PER_LSB,
              "sensors.accel_range must be this part's full scale, 156.9 m/s^2 (+-16 g)");
static const size_t FRAME = 13;  // address, then 6 accel and 6 gyro bytes

static const SPISettings settings(BOARD_IMU_SPI_HZ, MSBFIRST, SPI_MODE0);
static EventResponder done_event;
static uint8_t tx[FRAME] = {REG_ACCEL_X1 | READ};
static uint8_t rx[FRAME];
static volatile bool done, busy;
static bool alive;

static void write_reg(uint8_t reg, uint8_t value)
{
    SPI.beginTransaction(settings);
    digitalWriteFast(BOARD_PIN_IMU_CS, LOW);
    SPI.transfer(reg);
    SPI.transfer(value);
    digitalWriteFast(BOARD_PIN_IMU_CS, HIGH);
    SPI.endTransaction();
}

static uint8_t read_reg(uint8_t reg)
{
    SPI.beginTransaction(settings);
    digitalWriteFast(BOARD_PIN_IMU_CS, LOW);
    SPI.transfer((uint8_t)(reg | READ));
    uint8_t v = SPI.transfer(0);
    digitalWriteFast(BOARD_PIN_IMU_CS, HIGH);
    SPI.endTransaction();
    return v;
}

static void transfer_done(EventResponderRef)
{
    digitalWriteFast(BOARD_PIN_IMU_CS, HIGH);
    SPI.endTransaction();
    done = true;  // before busy: a control step in between takes this sample, not a transfer over it
    busy = false;
}

static int16_t be16(const uint8_t *p)
{
    return (int16_t)(((uint16_t)p[0] << 8) | p[1]);
}

bool board_imu_begin(void)
{
    pinMode(BOARD_PIN_IMU_CS, OUTPUT);
    digitalWriteFast(BOARD_PIN_IMU_CS, HIGH);
    SPI.setSCK(BOARD_PIN_IMU_SCK);  // pin 13 is the LED
    SPI.begin();
    write_reg(REG_DEVICE_CONFIG, 0x01);
    delay(2);  // the soft reset takes 1 ms
    if (read_reg(REG_WHO_AM_I) != WHO_AM_I) {
        return false;
    }
    write_reg(REG_GYRO_CONFIG0, GYRO_4000DPS_1KHZ);
    write_reg(REG_ACCEL_CONFIG0, ACCEL_16G_1KHZ);
    write_reg(REG_PWR_MGMT0, GYRO_ACCEL_LOW_NOISE);
    delay(50);  // the gyro starts within 30 ms of PWR_MGMT0
    done_event.attachImmediate(transfer_done);
    // The SPI library allocates its DMA channels (operator new) on the first asynchronous transfer:
    // make that one here, before the control interrupt runs, and wait for it.
    alive = true;
    board_imu_start();
    const uint32_t t0 = millis();
    while (busy && millis() - t0 < 10u) {
    }
    alive = !busy;
    done = false;
    return alive;
}

void board_imu_take(rod_imu_reading_t *out)
{
    // no sample is zeros, not the stack's leftovers: the reading goes out in the IMU telemetry frame as it is
    out->fresh = false;
    out->accel_x = 0.0f;
    out->accel_y = 0.0f;
    out->gyro = 0.0f;
    if (!alive || !done) {
        return;  // a part given up at boot stays silent, even if its first transfer ends late
    }
    done = false;
    __atomic_signal_fence(__ATOMIC_SEQ_CST);  // rx (DMA-written, not volatile) is read after done, not before
    // the part's axes to the rod's frame (board_pins.h): x along the rod to the tip, y toward +theta
    const float a[3] = {be16(rx + 1) * ACCEL_M_S2_PER_LSB, be16(rx + 3) * ACCEL_M_S2_PER_LSB, be16(rx + 5) * ACCEL_M_S2_PER_LSB};
    const float g[3] = {be16(rx + 7) * GYRO_RAD_S_PER_LSB, be16(rx + 9) * GYRO_RAD_S_PER_LSB, be16(rx + 11) * GYRO_RAD_S_PER_LSB};
    out->accel_x = BOARD_IMU_X_SIGN * a[BOARD_IMU_X_AXIS];
    out->accel_y = BOARD_IMU_Y_SIGN * a[BOARD_IMU_Y_AXIS];
    out->gyro = BOARD_IMU_Z_SIGN * g[BOARD_IMU_Z_AXIS];
    out->fresh = true;
}

void board_imu_start(void)
{
    if (!alive || busy) {
        return;  // a transfer still under way: this period's sample is skipped, the core sees none
    }
    busy = true;
    SPI.beginTransaction(settings);
    digitalWriteFast(BOARD_PIN_IMU_CS, LOW);
    if (!SPI.transfer(tx, rx, FRAME, done_event)) {
        digitalWriteFast(BOARD_PIN_IMU_CS, HIGH);
        SPI.endTransaction();
        busy = false;
    }
}

#else  // a firmware designed without the IMU never touches its pins

bool board_imu_begin(void)
{
    return false;
}

void board_imu_take(rod_imu_reading_t *out)
{
    out->fresh = false;
}

void board_imu_start(void) {}

#endif
