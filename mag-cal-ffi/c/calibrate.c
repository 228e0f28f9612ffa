/* Calibrates a recorded log with mag-cal's C API, then uses the result.
 *
 *   calibrate LOG [f32|f64] [EXPECTED.json]
 *
 * LOG: one reading per line, three integer counts (x,y,z; commas or
 * spaces); other lines are skipped. With EXPECTED.json (the output of
 * `magcal fit --format json` on the same log) the program checks its
 * calibration against it: b and W to 1e-6 of the field (f64) or 1e-4
 * (f32), and exits 1 when they differ.
 *
 * The same file builds for the host (gcc) and for a Cortex-M4F
 * (arm-none-eabi-gcc with newlib's semihosting: under QEMU the log is read
 * from the host and the output goes to its terminal). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mag_cal.h"

#define MAX_SAMPLES 1200
/* Readings of a device lying still before and after the log's turns. */
#define STILL 300

static int16_t samples[MAX_SAMPLES][3];
/* The log with still ends, or two still periods with one reading between. */
static int16_t ends[MAX_SAMPLES + 2 * STILL][3];
/* Caller-owned state of the collector and the smoother: plain storage. */
static MagcalCollector collector;
static MagcalSmoother smoother;

/* Reads up to MAX_SAMPLES rows of three integers; returns the count. */
static size_t read_log(const char *path, size_t *skipped) {
    FILE *f = fopen(path, "r");
    if (!f) {
        printf("cannot open %s\n", path);
        return 0;
    }
    char line[256];
    size_t n = 0;
    *skipped = 0;
    while (n < MAX_SAMPLES && fgets(line, sizeof line, f)) {
        long v[3];
        char *p = line;
        int k = 0;
        for (; k < 3; k++) {
            char *end;
            while (*p == ',' || *p == ' ' || *p == '\t') p++;
            v[k] = strtol(p, &end, 10);
            if (end == p || v[k] < -32768 || v[k] > 32767) break;
            p = end;
        }
        if (k == 3) {
            for (k = 0; k < 3; k++) samples[n][k] = (int16_t)v[k];
            n++;
        } else {
            (*skipped)++;
        }
    }
    fclose(f);
    return n;
}

/* Writes `count` copies of `row` into `ends` from index `at`, each with a
 * count of noise (-1, 0, 0 or +1 per axis, a linear congruential
 * generator): a device lying still. Returns the index after them. */
static size_t lying_still(size_t at, const int16_t row[3], size_t count) {
    static const int noise[4] = {-1, 0, 0, 1};
    static uint32_t state = 12345u;
    for (size_t i = 0; i < count; i++, at++) {
        for (int k = 0; k < 3; k++) {
            state = state * 1664525u + 1013904223u;
            ends[at][k] = (int16_t)(row[k] + noise[state >> 30]);
        }
    }
    return at;
}

/* The numbers after "key": in a JSON text (flattening nested arrays). */
static int json_numbers(const char *json, const char *key, double *out, int count) {
    char pattern[64];
    snprintf(pattern, sizeof pattern, "\"%s\":", key);
    const char *p = strstr(json, pattern);
    if (!p) return 0;
    p += strlen(pattern);
    int k = 0;
    while (k < count && *p) {
        while (*p == '[' || *p == ',' || *p == ' ' || *p == ']') p++;
        char *end;
        double v = strtod(p, &end);
        if (end == p) break;
        out[k++] = v;
        p = end;
    }
    return k;
}

/* Compares with `magcal fit --format json`; returns 0 when they agree. */
static int check(const MagcalCalibration *cal, const char *path, double tol) {
    static char json[16384];
    FILE *f = fopen(path, "r");
    if (!f) {
        printf("cannot open %s\n", path);
        return 1;
    }
    size_t len = fread(json, 1, sizeof json - 1, f);
    fclose(f);
    json[len] = '\0';
    double b[3], w[9], rho;
    if (json_numbers(json, "hard_iron", b, 3) != 3 || json_numbers(json, "soft_iron", w, 9) != 9 ||
        json_numbers(json, "field_strength", &rho, 1) != 1) {
        printf("%s: no hard_iron, soft_iron and field_strength\n", path);
        return 1;
    }
    /* b in units of the field, W times the field: both dimensionless. */
    double db = 0, dw = 0;
    for (int i = 0; i < 3; i++) {
        db = fmax(db, fabs(cal->hard_iron[i] - b[i]) / rho);
        for (int j = 0; j < 3; j++) dw = fmax(dw, fabs(cal->soft_iron[i][j] - w[3 * i + j]) * rho);
    }
    double drho = fabs(cal->field_strength - rho) / rho;
    int ok = db <= tol && dw <= tol && drho <= tol;
    printf("against magcal: |db|/rho %.2e, |dW|*rho %.2e, |drho|/rho %.2e (tolerance %.0e): %s\n", db,
           dw, drho, tol, ok ? "agree" : "DIFFER");
    return ok ? 0 : 1;
}

int main(int argc, char **argv) {
    if (argc < 2) {
        printf("usage: calibrate LOG [f32|f64] [EXPECTED.json]\n");
        return 2;
    }
    int f64 = argc < 3 || strcmp(argv[2], "f32") != 0;
    size_t skipped = 0;
    size_t n = read_log(argv[1], &skipped);
    printf("%s: %u readings, %u other lines skipped\n", argv[1], (unsigned)n, (unsigned)skipped);

    MagcalConfig config;
    magcal_config_default(&config);
    MagcalResult r;
    MagcalStatus s = f64 ? magcal_calibrate_i16_f64((const int16_t(*)[3])samples, n, &config, &r)
                         : magcal_calibrate_i16((const int16_t(*)[3])samples, n, &config, &r);
    if (s != MAGCAL_STATUS_OK) {
        char why[256];
        magcal_refusal_message(&r.refusal, why, sizeof why);
        printf("not calibrated: %s\n", why);
        return 3;
    }
    const MagcalCalibration *cal = &r.calibration;
    printf("precision %s: b = [%.6f, %.6f, %.6f], field strength %.6f\n", f64 ? "f64" : "f32",
           cal->hard_iron[0], cal->hard_iron[1], cal->hard_iron[2], cal->field_strength);
    for (int i = 0; i < 3; i++)
        printf("W[%d] = [%.9e, %.9e, %.9e]\n", i, cal->soft_iron[i][0], cal->soft_iron[i][1],
               cal->soft_iron[i][2]);
    printf("used %u, dropped %u, still %u, screened %u, rejected %u; radial RMS %.5f, fit error %.5f\n",
           (unsigned)r.samples_used, (unsigned)r.samples_dropped, (unsigned)r.dwell,
           (unsigned)r.screened, (unsigned)r.rejected, r.radial_rms, r.fit_error);
    int failed = 0;

    /* A calibrated reading lies on the unit sphere. */
    float raw[3] = {samples[0][0], samples[0][1], samples[0][2]}, u[3];
    magcal_apply(cal, raw, u);
    float norm = sqrtf(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
    printf("|W (y0 - b)| = %.4f, heading %.2f deg\n", norm, magcal_heading_deg(u));
    if (fabsf(norm - 1.0f) > 0.2f) failed = 1;

    /* Headings smoothed on the circle. A reading in counts as the driver
     * gives it (magcal_apply_i16) calibrates as the same reading in float. */
    float mean = 0;
    magcal_smoother_init(&smoother, 15);
    for (size_t i = 0; i < n && i < 30; i++) {
        float y[3] = {samples[i][0], samples[i][1], samples[i][2]}, v[3];
        magcal_apply(cal, y, u);
        if (magcal_apply_i16(cal, samples[i], v) != MAGCAL_STATUS_OK ||
            memcmp(u, v, sizeof u) != 0) {
            printf("reading %u: apply_i16 [%.9g, %.9g, %.9g], apply [%.9g, %.9g, %.9g]\n",
                   (unsigned)i, v[0], v[1], v[2], u[0], u[1], u[2]);
            failed = 1;
        }
        magcal_smoother_push(&smoother, magcal_heading_deg(u), &mean);
    }
    printf("smoothed heading over the first 30 readings: %.2f deg\n", mean);

    /* Stored and read back: the same calibration. */
    uint8_t record[MAGCAL_RECORD_BYTES];
    MagcalCalibration back;
    if (magcal_to_bytes(cal, record, sizeof record) != MAGCAL_STATUS_OK ||
        magcal_from_bytes(record, sizeof record, &back) != MAGCAL_STATUS_OK ||
        fabs(back.field_strength - cal->field_strength) > 1e-6 * cal->field_strength) {
        printf("storage round trip failed\n");
        failed = 1;
    }
    record[10] ^= 0x01;
    s = magcal_from_bytes(record, sizeof record, &back);
    printf("a damaged record: %s\n", magcal_error_str(s));
    if (s != MAGCAL_STATUS_CHECKSUM_MISMATCH) failed = 1;

    /* The collector, as firmware would feed it. */
    magcal_collector_init(&collector, 4.0f);
    for (size_t i = 0; i < n; i++) magcal_collector_offer(&collector, samples[i]);
    MagcalProgress p;
    magcal_collector_progress(&collector, &p);
    printf("collector: %u samples kept, %u/%u cells, %u %%%s\n", (unsigned)p.samples,
           (unsigned)p.cells_visited, (unsigned)p.cells, (unsigned)p.percent,
           p.ready ? ", ready" : "");
    /* The visited cells' bits, one per cell counted. */
    unsigned bits = 0;
    for (uint64_t v = p.visited; v != 0; v &= v - 1) bits++;
    if (bits != p.cells_visited) {
        printf("collector: %u cells in the visited bits, %u counted\n", bits,
               (unsigned)p.cells_visited);
        failed = 1;
    }

    /* Refusals name their cause: a device lying still. */
    int16_t still[200][3];
    for (int i = 0; i < 200; i++) {
        still[i][0] = (int16_t)(120 + i % 3);
        still[i][1] = (int16_t)(-40 + i % 5);
        still[i][2] = (int16_t)(300 + i % 2);
    }
    s = magcal_calibrate_i16((const int16_t(*)[3])still, 200, &config, &r);
    char why[256];
    size_t len = magcal_refusal_message(&r.refusal, why, sizeof why);
    printf("a device lying still: %s\n", why);
    /* The figure and limit that decided it, as numbers too. */
    printf("  (%s %g, limit %g)\n", magcal_refusal_name(&r.refusal), r.refusal.figure,
           r.refusal.limit);
    if (s == MAGCAL_STATUS_OK || r.refusal.status != s || len >= sizeof why ||
        !(r.refusal.figure > r.refusal.limit))
        failed = 1;
    /* The same refusal copied field by field into bytes that were not
     * zero: the library reads the status as the enum's own size (one byte
     * on arm-none-eabi, with three bytes of padding after it). */
    MagcalRefusal copy;
    memset(&copy, 0xA5, sizeof copy);
    copy.status = r.refusal.status;
    copy.figure = r.refusal.figure;
    copy.limit = r.refusal.limit;
    copy.count = r.refusal.count;
    copy.of = r.refusal.of;
    char again[256];
    magcal_refusal_message(&copy, again, sizeof again);
    if (strcmp(again, why) != 0 ||
        strcmp(magcal_refusal_name(&copy), magcal_refusal_name(&r.refusal)) != 0) {
        printf("a refusal copied over padding: '%s' (%s)\n", again, magcal_refusal_name(&copy));
        failed = 1;
    }

    /* Still periods: the log lying still before and after its turns. The
     * rows in a ball about each still position are set aside (no outliers), and
     * every row is counted once (a result of its own: `r` holds the log's
     * calibration, checked below). */
    MagcalResult e;
    memset(&e, 0, sizeof e);
    size_t m = lying_still(0, samples[0], STILL);
    memcpy(ends[m], samples, n * sizeof samples[0]);
    m = lying_still(m + n, samples[n - 1], STILL);
    s = magcal_calibrate_i16((const int16_t(*)[3])ends, m, &config, &e);
    unsigned counted = (unsigned)(e.samples_used + e.samples_dropped + e.dwell + e.screened +
                                  e.rejected);
    printf("lying still %u readings before and after: %s, %u set aside as still, %u used of %u\n",
           (unsigned)STILL, magcal_error_str(s), (unsigned)e.dwell, (unsigned)e.samples_used,
           counted);
    if (s != MAGCAL_STATUS_OK || e.dwell == 0 || counted != m) failed = 1;

    /* One reading of motion between two still periods: refused, the
     * device hardly moved (its own status, the rows counted). */
    m = lying_still(0, samples[0], STILL);
    memcpy(ends[m], samples[n / 2], sizeof samples[0]);
    m = lying_still(m + 1, samples[n - 1], STILL);
    s = magcal_calibrate_i16((const int16_t(*)[3])ends, m, &config, &e);
    magcal_refusal_message(&e.refusal, why, sizeof why);
    printf("one reading between two still periods: %s\n", why);
    /* (The core's sentence, read back from the refusal as C holds it: on
     * the Cortex-M the status is one byte, with padding after it.) */
    if (s != MAGCAL_STATUS_HARDLY_MOVED || e.refusal.status != s || e.refusal.still == 0 ||
        e.refusal.count >= e.refusal.of || strncmp(why, "the device hardly moved: ", 25) != 0)
        failed = 1;

    if (argc >= 4) failed |= check(cal, argv[3], f64 ? 1e-6 : 1e-4);
    printf("%s\n", failed ? "FAILED" : "ok");
    return failed;
}
