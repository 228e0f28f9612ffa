/* Footprint of the C API on the Cortex-M4F: flash (this program with and
 * without the calibration, -DBASELINE) and the stack high-water mark of one
 * magcal_calibrate_i16 call (n = 1000, float, the default configuration).
 *
 * Stack: the RAM between the end of .bss and the stack pointer is painted
 * with a pattern, the call runs, and the lowest overwritten word gives the
 * depth below the caller's stack pointer (a frame that reserves stack it
 * never writes is not seen). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>

#include "mag_cal.h"

#define N 1000
#define PATTERN 0xA5C35A3Cu

static int16_t samples[N][3];
extern uint32_t __bss_end__;

/* A pole-to-pole spiral on an offset, stretched sphere of 320 counts. */
static void fill(void) {
    for (int i = 0; i < N; i++) {
        float z = 1.0f - 2.0f * ((float)i + 0.5f) / N;
        float r = sqrtf(1.0f - z * z), phi = (float)i * 2.399963f;
        samples[i][0] = (int16_t)lrintf(180.0f + 345.0f * r * cosf(phi));
        samples[i][1] = (int16_t)lrintf(-95.0f + 300.0f * r * sinf(phi) + 20.0f * z);
        samples[i][2] = (int16_t)lrintf(240.0f + 330.0f * z);
    }
}

__attribute__((noinline)) static int run(MagcalResult *r) {
#ifdef BASELINE
    (void)r;
    return samples[7][0] != 0;
#else
    MagcalConfig config;
    magcal_config_default(&config);
    return magcal_calibrate_i16((const int16_t(*)[3])samples, N, &config, r) == MAGCAL_STATUS_OK;
#endif
}

int main(void) {
    fill();
    static MagcalResult r;
    uint32_t *sp;
    __asm volatile("mov %0, sp" : "=r"(sp));
    /* 64 KiB below the stack pointer (newlib's start-up puts the stack
     * where the semihosting host says RAM ends), and above what the heap
     * took before main. */
    uint32_t *bottom = sp - 16384;
    if (bottom < &__bss_end__ + 2048) bottom = &__bss_end__ + 2048;
    uint32_t *top = sp - 64; /* below this frame and the call's own */
    for (uint32_t *p = bottom; p < top; p++) *p = PATTERN;
    int ok = run(&r);
    uint32_t *low = bottom;
    while (low < top && *low == PATTERN) low++;
    printf("FOOTPRINT-C %s ok=%d stack=%u\n",
#ifdef BASELINE
           "baseline",
#else
           "calibrate",
#endif
           ok, (unsigned)((uint8_t *)sp - (uint8_t *)low));
    return ok ? 0 : 1;
}
