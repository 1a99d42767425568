/*
 * Dump this CPU's SSE approximate reciprocal square root and reciprocal (RSQRTPS, RCPPS).
 *
 * Why: the authors' ARCF release computes fHOG with Piotr's toolbox, whose gradMag takes each
 * pixel's orientation from (int)(gx * rsqrt(m2) * 10000) and its magnitude from
 * rcp(rsqrt(m2)). These instructions are ~12-bit approximations whose last bits differ
 * between CPU vendors, and a release-compatible tracker follows the release's boxes only as
 * long as it reproduces them bit for bit (see docs/results-fidelity.md, "Arithmetic sensitivity",
 * and benchmarks/arithmetic_sensitivity.py). Run this on the machine that produced the
 * reference traces, and arcf can replay that machine's arithmetic (the AMD EPYC's ships with
 * the package: arcf/features/tables/).
 *
 * What it writes (text, to stdout): a header with the CPU model, then one line per input
 * bucket, "rsqrt <k> <result>" for k = 0..8191 and "rcp <k> <result>" for k = 0..4095, results
 * as float32 bit patterns in hex. A bucket is the part of the input the hardware is expected
 * to look at: rsqrt, x in [1, 4): k = (exponent parity) * 4096 + top 12 mantissa bits;
 * rcp, x in [1, 2): k = top 12 mantissa bits.
 *
 * It checks that assumption exhaustively instead of trusting it: every float32 in [1, 4)
 * (rsqrt) and [1, 2) (rcp) is evaluated, and a bucket whose inputs do not all give the same
 * result is reported; so is any exponent e in [-100, 100] (even for rsqrt) at which
 * f(x * 2^e) != f(x) * 2^(-e/2) (rsqrt) or 2^(-e) (rcp) for a bucket's first input. The exit
 * status is 0 only if both hold, i.e. if the table describes the instruction completely on
 * normal inputs (zero, denormals and overflow are not covered and not needed by fHOG).
 *
 *     gcc -O2 -msse2 -o sse_approx_dump tools/sse_approx_dump.c && ./sse_approx_dump > sse.txt
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <xmmintrin.h>

static float from_bits(uint32_t b) { float f; memcpy(&f, &b, 4); return f; }
static uint32_t to_bits(float f) { uint32_t b; memcpy(&b, &f, 4); return b; }

/* Packed instructions, as the toolbox uses them; 4 inputs per call. */
static void rsqrt4(const uint32_t *in, uint32_t *out) {
    __m128 v = _mm_castsi128_ps(_mm_loadu_si128((const __m128i *)in));
    _mm_storeu_si128((__m128i *)out, _mm_castps_si128(_mm_rsqrt_ps(v)));
}
static void rcp4(const uint32_t *in, uint32_t *out) {
    __m128 v = _mm_castsi128_ps(_mm_loadu_si128((const __m128i *)in));
    _mm_storeu_si128((__m128i *)out, _mm_castps_si128(_mm_rcp_ps(v)));
}

/* All inputs of [2^e0, 2^(e0 + n_exp)) in buckets of 2^11 consecutive bit patterns. */
static long dump(const char *name, void (*f)(const uint32_t *, uint32_t *), int n_exp, int sqrt_) {
    const uint32_t first = 127u << 23, count = (uint32_t)n_exp << 23, bucket = 1u << 11;
    long bad_buckets = 0, bad_scaling = 0;
    uint32_t in[4], out[4];
    for (uint32_t k = 0; k < count / bucket; k++) {
        uint32_t ref = 0;
        int constant = 1;
        for (uint32_t j = 0; j < bucket; j += 4) {
            for (int l = 0; l < 4; l++) in[l] = first + k * bucket + j + (uint32_t)l;
            f(in, out);
            if (j == 0) ref = out[0];
            for (int l = 0; l < 4; l++) constant &= out[l] == ref;
        }
        if (!constant) bad_buckets++;
        /* Exponent invariance, checked on the bucket's first input. */
        for (int e = -100; e <= 100; e += sqrt_ ? 2 : 1) {
            float x = ldexpf(from_bits(first + k * bucket), e);
            float want = ldexpf(from_bits(ref), sqrt_ ? -e / 2 : -e);
            in[0] = in[1] = in[2] = in[3] = to_bits(x);
            f(in, out);
            if (out[0] != to_bits(want)) { bad_scaling++; break; }
        }
        printf("%s %u %08x\n", name, k, ref);
    }
    fprintf(stderr, "%s: %u buckets, %ld not constant, %ld not scaling with the exponent\n",
            name, count / bucket, bad_buckets, bad_scaling);
    return bad_buckets + bad_scaling;
}

int main(void) {
    char model[256] = "unknown";
    FILE *cpu = fopen("/proc/cpuinfo", "r");
    if (cpu) {
        char line[512];
        while (fgets(line, sizeof line, cpu))
            if (sscanf(line, "model name : %255[^\n]", model) == 1) break;
        fclose(cpu);
    }
    printf("# SSE RSQRTPS / RCPPS results per input bucket (tools/sse_approx_dump.c)\n");
    printf("# cpu: %s\n", model);
    long bad = dump("rsqrt", rsqrt4, 2, 1);
    bad += dump("rcp", rcp4, 1, 0);
    return bad ? 1 : 0;
}
