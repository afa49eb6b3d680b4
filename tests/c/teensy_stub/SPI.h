// Stand-in for the Teensyduino SPI library (PaulStoffregen/SPI, Teensy 3.x) and EventResponder
// (cores/teensy3/EventResponder.h): the declarations the board layer uses, with their signatures.
#ifndef TEENSY_STUB_SPI_H
#define TEENSY_STUB_SPI_H

#include <stddef.h>
#include <stdint.h>

#define MSBFIRST 1
#define SPI_MODE0 0x00
#define SPI_HAS_TRANSFER_ASYNC 1

void delay(uint32_t msec);

class EventResponder;
typedef EventResponder &EventResponderRef;
typedef void (*EventResponderFunction)(EventResponderRef);
class EventResponder {
  public:
    constexpr EventResponder() {}
    void attachImmediate(EventResponderFunction function);
    void triggerEvent(int status = 0, void *data = nullptr);
    EventResponderFunction fn = nullptr;
};

class SPISettings {
  public:
    constexpr SPISettings(uint32_t clock, uint8_t bitOrder, uint8_t dataMode) : c(clock), o(bitOrder), m(dataMode) {}
    uint32_t c;
    uint8_t o, m;
};

class SPIClass {
  public:
    void begin();
    void setSCK(uint8_t pin);
    void beginTransaction(SPISettings settings);
    void endTransaction(void);
    uint8_t transfer(uint8_t data);
    bool transfer(const void *txBuffer, void *rxBuffer, size_t count, EventResponderRef event_responder);
};
extern SPIClass SPI;

#endif
