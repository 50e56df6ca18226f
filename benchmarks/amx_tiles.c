// AMX bfloat16 tile products on this CPU, as the batch loop would use them (docs/BENCHMARKS.md, "AMX bfloat16
// tiles"): M rows (a group's voices) times a 32 x 16 weight tile, four accumulators, the weight tiles loaded from
// memory for every product (a window's weights do not stay in tile registers). Prints ns per product and GMAC/s.
//
//     gcc -O2 -mamx-tile -mamx-bf16 benchmarks/amx_tiles.c -o /tmp/amx_tiles && /tmp/amx_tiles 4
#include <immintrin.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

typedef struct {
    uint8_t palette_id, start_row, reserved[14];
    uint16_t colsb[16];
    uint8_t rows[16];
} tile_config;

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

int main(int argc, char** argv) {
    if (syscall(SYS_arch_prctl, 0x1023 /* ARCH_REQ_XCOMP_PERM */, 18 /* XTILEDATA */)) {
        perror("AMX tile data not granted by the kernel");
        return 1;
    }
    const int M = argc > 1 ? atoi(argv[1]) : 16;
    if (M < 1 || M > 16) return 2;
    tile_config c;
    memset(&c, 0, sizeof c);
    c.palette_id = 1;
    for (int t = 0; t < 5; t++) c.rows[t] = M, c.colsb[t] = 64;  // tiles 0-3: M x 16 float sums; 4: M x 32 bf16 rows
    for (int t = 5; t < 8; t++) c.rows[t] = 16, c.colsb[t] = 64;  // 5-7: 32 x 16 bf16 weights, in pairs
    _tile_loadconfig(&c);
    static uint16_t A[16 * 32], B[4][16 * 32];
    static float C[16 * 16];
    for (int i = 0; i < 16 * 32; i++) {
        A[i] = 0x3f80;  // 1.0
        for (int j = 0; j < 4; j++) B[j][i] = 0x3c00;  // 2^-7: the sums stay finite
    }
    _tile_zero(0);
    _tile_zero(1);
    _tile_zero(2);
    _tile_zero(3);
    const long n = 20000000 / M;
    const double t0 = now();
    for (long i = 0; i < n; i++) {
        _tile_loadd(4, A, 64);
        _tile_loadd(5, B[0], 64);
        _tile_dpbf16ps(0, 4, 5);
        _tile_loadd(6, B[1], 64);
        _tile_dpbf16ps(1, 4, 6);
        _tile_loadd(7, B[2], 64);
        _tile_dpbf16ps(2, 4, 7);
        _tile_loadd(5, B[3], 64);
        _tile_dpbf16ps(3, 4, 5);
    }
    const double dt = now() - t0;
    _tile_stored(0, C, 64);
    printf("M=%d: %.2f ns per product, %.1f GMAC/s (bfloat16; check %g)\n", M, dt / n / 4 * 1e9,
           (double)n * 4 * M * 16 * 32 / dt / 1e9, C[0]);
    _tile_release();
    return 0;
}
