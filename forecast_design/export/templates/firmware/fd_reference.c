/* fd_reference.c: see fd_reference.h. */
#include <math.h>
#include "fd_reference.h"

static int fd_finite(float x)
{
    return x == x && x - x == 0.0f;
}

int fd_reference_set(fd_reference *r, uint8_t kind, float amplitude, float period, float offset, float rate)
{
    float n;
    uint32_t whole;
    if (kind > 2u || !fd_finite(amplitude) || !fd_finite(period) || !fd_finite(offset)) {
        return 0;
    }
    if ((kind != 0u && !(period > 0.0f)) || (kind == 0u && period < 0.0f) || period > 4.0e6f) {
        return 0;
    }
    n = period * rate;
    whole = (uint32_t)(n + 0.5f);
    r->kind = kind;
    r->amplitude = amplitude;
    r->period = period;
    r->offset = offset;
    r->rate = rate;
    r->samples = (fabsf(n - (float)whole) < 1.0e-3f) ? whole : 0u;
    return 1;
}

float fd_reference_value(const fd_reference *r, uint32_t index)
{
    const float t = (float)index / r->rate;
    switch (r->kind) {
    case 1u: {
        int high;
        if (r->samples > 0u) {
            high = 2u * (index % r->samples) < r->samples;
        } else {
            const float cycles = t / r->period;
            high = (cycles - (float)(uint32_t)cycles) < 0.5f;
        }
        return high ? r->offset + r->amplitude : r->offset - r->amplitude;
    }
    case 2u:
        return r->offset + r->amplitude * sinf(6.28318531f * (t / r->period));
    default:
        if (r->samples > 0u || r->period == 0.0f) {
            return index >= r->samples ? r->offset + r->amplitude : r->offset;
        }
        return t >= r->period ? r->offset + r->amplitude : r->offset;
    }
}
