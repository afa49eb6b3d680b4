/* rod_spsc.h -- index pair of a lock-free single-producer single-consumer ring.
 *
 * The control step (timer interrupt) and the main loop run on one core and never wait for each
 * other: each index has one writer, the free-running counters make full (head - tail == size)
 * and empty (head == tail) unambiguous, and compiler fences keep the slot accesses on the right
 * side of the index updates (a single-core Cortex-M4 needs no hardware barrier for this).
 * The slots themselves live in the owner's array of `size` (a power of two) entries.
 */
#ifndef ROD_SPSC_H
#define ROD_SPSC_H

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    volatile uint32_t head; /* written by the producer only */
    volatile uint32_t tail; /* written by the consumer only */
} rod_spsc_t;

static inline void rod_spsc_init(rod_spsc_t *r)
{
    r->head = 0;
    r->tail = 0;
}

/* Producer: slot index to fill, or -1 when full. Fill it, then rod_spsc_publish. */
static inline int32_t rod_spsc_claim(rod_spsc_t *r, uint32_t size)
{
    uint32_t head = r->head;
    if (head - r->tail >= size) {
        return -1;
    }
    __atomic_signal_fence(__ATOMIC_SEQ_CST); /* no slot write before the tail was read */
    return (int32_t)(head & (size - 1u));
}

static inline void rod_spsc_publish(rod_spsc_t *r)
{
    __atomic_signal_fence(__ATOMIC_SEQ_CST); /* the slot is complete before it is visible */
    r->head = r->head + 1u;
}

/* Consumer: slot index to read, or -1 when empty. Read it, then rod_spsc_release. */
static inline int32_t rod_spsc_peek(rod_spsc_t *r, uint32_t size)
{
    uint32_t tail = r->tail;
    if (r->head == tail) {
        return -1;
    }
    __atomic_signal_fence(__ATOMIC_SEQ_CST); /* no slot read before head was read */
    return (int32_t)(tail & (size - 1u));
}

static inline void rod_spsc_release(rod_spsc_t *r)
{
    __atomic_signal_fence(__ATOMIC_SEQ_CST); /* done with the slot before it is handed back */
    r->tail = r->tail + 1u;
}

static inline bool rod_spsc_full(const rod_spsc_t *r, uint32_t size)
{
    return r->head - r->tail >= size;
}

#ifdef __cplusplus
}
#endif

#endif /* ROD_SPSC_H */
