// Stand-in (see Arduino.h here): begin() returns whether a PIT channel started.
#ifndef TEENSY_STUB_INTERVALTIMER_H
#define TEENSY_STUB_INTERVALTIMER_H

class IntervalTimer {
  public:
    bool begin(void (*isr)(), unsigned int period_us);
    void priority(uint8_t n);
};

#endif
