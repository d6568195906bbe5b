/* fd_reference.h: the force reference tau_r of SET_REFERENCE (docs/protocol.md), per sample index.
 * square: offset + amplitude for the first half of each period, offset - amplitude for the second;
 * sine: offset + amplitude sin(2 pi t / period); step: offset before the delay, offset + amplitude
 * from it on. When period (or delay) x rate is a whole number of samples (within 1e-3), the
 * switching instants are decided on the integer sample index. The host's float64 generator
 * (forecast_design.simulation.references) agrees when its edge times are exact binary fractions
 * (periods such as 0.5 s or 0.125 s at 2 kHz); for others (0.1 s) its mod() may switch one sample
 * early at some edges, which the firmware does not copy. */
#ifndef FD_REFERENCE_H
#define FD_REFERENCE_H

#include <stdint.h>

typedef struct {
    uint8_t kind;        /* 0 step, 1 square, 2 sine */
    float amplitude;     /* [N m] */
    float period;        /* square/sine period, step delay [s] */
    float offset;        /* [N m] */
    float rate;          /* [Hz] */
    uint32_t samples;    /* period (or delay) in samples when whole, else 0 */
} fd_reference;

/* 1 if accepted; 0 (unchanged) for an unknown kind or non-finite / out-of-range values. */
int fd_reference_set(fd_reference *r, uint8_t kind, float amplitude, float period, float offset, float rate);
float fd_reference_value(const fd_reference *r, uint32_t index);

#endif /* FD_REFERENCE_H */
