/* The driver `mag_read` of the README's C example, simulated: `cargo xtask
 * c` compiles the example as the README gives it, links it with this file
 * and the host library, and runs it.
 *
 * The sensor: hard iron (180, -95, 240) counts, a symmetric soft iron (a
 * field of 300-345 counts), noise of up to 2 counts, rounded to int16_t.
 * The device turns about the vertical, 6.3 deg a reading, while tilting up
 * and down to +-80 deg and back every 483 readings. At exit the program
 * prints the true heading of the last reading (atan2(-y, x) of its field
 * direction); the test compares it with the heading the example prints. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

static const float B[3] = {180.0f, -95.0f, 240.0f};
static const float D[3][3] = {
    {345.0f, 12.0f, -8.0f}, {12.0f, 300.0f, 20.0f}, {-8.0f, 20.0f, 330.0f}};
static float truth;

static void print_truth(void) { printf("true heading %.1f deg\n", truth); }

/* Uniform in [-2, 2) counts (a linear congruential generator). */
static float noise(void) {
    static uint32_t state = 12345u;
    state = state * 1664525u + 1013904223u;
    return 4.0f * (float)(state >> 8) / 16777216.0f - 2.0f;
}

void mag_read(int16_t raw[3]);

void mag_read(int16_t raw[3]) {
    static unsigned i;
    if (i == 0) atexit(print_truth);
    float t = (float)i++, lon = 0.11f * t, lat = 1.4f * sinf(0.013f * t);
    float m[3] = {cosf(lat) * cosf(lon), cosf(lat) * sinf(lon), sinf(lat)};
    for (int a = 0; a < 3; a++)
        raw[a] = (int16_t)lrintf(B[a] + D[a][0] * m[0] + D[a][1] * m[1] + D[a][2] * m[2] + noise());
    truth = atan2f(-m[1], m[0]) * (180.0f / 3.14159265f);
}
