/*
 * The no_std release library from C: no allocator, so the context lives in
 * a caller buffer (sheaf_context_create_in); builds a BVH over a small
 * scene and traces rays single and in packets, checking every packet hit
 * against the single ray bit for bit.
 *
 *   cargo build -p sheaf --profile release-nostd --no-default-features --features panic-handler --lib
 *   gcc -std=c99 -Wall -Wextra -Werror -pedantic -Iinclude ffi-tests/nostd/create_in.c \
 *       target/release-nostd/libsheaf.a -lm -o target/nostd-create-in && target/nostd-create-in
 *
 * .ci/run does exactly this. sheaf_context_create does not exist in this
 * library (no allocator); linking needs only libm besides libc.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "sheaf.h"

#define N 16 /* boxes per side: 16 x 16 boxes of 12 triangles */
static float g_v[N * N * 8][3];
static uint32_t g_idx[N * N * 12 * 3];
static uint8_t g_raw[(64u << 20) + SHEAF_CONTEXT_ALIGN];

static uint32_t bits(float f) {
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

int main(void) {
    static const uint32_t quad[12][3] = {{0, 1, 3}, {0, 3, 2}, {4, 6, 7}, {4, 7, 5}, {0, 4, 5}, {0, 5, 1},
                                         {2, 3, 7}, {2, 7, 6}, {0, 2, 6}, {0, 6, 4}, {1, 5, 7}, {1, 7, 3}};
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    sheaf_trace_params p;
    static sheaf_ray rays[64 * 64];
    static sheaf_hit single[64 * 64], packet[64 * 64];
    size_t need = 0;
    uint8_t *buf;
    uint32_t nv = 0, nt = 0, i, j, c, hits = 0, failed = 0;
    for (i = 0; i < N; ++i)
        for (j = 0; j < N; ++j) {
            float x = 2.0f * (float)i, y = 2.0f * (float)j, h = 0.5f + 0.1f * (float)((i * 7 + j * 3) % 10);
            for (c = 0; c < 8; ++c) {
                g_v[nv + c][0] = x + ((c & 1) ? 1.0f : 0.0f);
                g_v[nv + c][1] = y + ((c & 2) ? 1.0f : 0.0f);
                g_v[nv + c][2] = (c & 4) ? h : 0.0f;
            }
            for (c = 0; c < 12; ++c, ++nt) {
                g_idx[3 * nt] = nv + quad[c][0];
                g_idx[3 * nt + 1] = nv + quad[c][1];
                g_idx[3 * nt + 2] = nv + quad[c][2];
            }
            nv += 8;
        }
    if (sheaf_limits_default(nt, &l) != SHEAF_STATUS_OK) return 1;
    l.structures = SHEAF_STRUCTURE_BVH;
    /* The caller's buffer, aligned by hand (C99 has no _Alignas). */
    buf = g_raw + (SHEAF_CONTEXT_ALIGN - (uintptr_t)g_raw % SHEAF_CONTEXT_ALIGN) % SHEAF_CONTEXT_ALIGN;
    if (sheaf_required_bytes(&l, &need) != SHEAF_STATUS_OK || need > (64u << 20)) return 2;
    if (sheaf_context_create_in(buf, need, &l, &ctx) != SHEAF_STATUS_OK) return 3;
    if (sheaf_context_set_geometry(ctx, &g_v[0][0], 12, nv, g_idx, nt) != SHEAF_STATUS_OK) return 4;
    if (sheaf_context_build_bvh(ctx, NULL) != SHEAF_STATUS_OK) return 5;
    for (i = 0; i < 64 * 64; ++i) {
        sheaf_ray *r = &rays[i];
        r->org[0] = -4.0f;
        r->org[1] = -4.0f;
        r->org[2] = 6.0f;
        r->dir[0] = 0.5f * (float)(i % 64);
        r->dir[1] = 0.5f * (float)(i / 64);
        r->dir[2] = -6.0f;
        r->tmin = 0.0f;
        r->tmax = INFINITY;
    }
    if (sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, rays, single, 64 * 64) != SHEAF_STATUS_OK) return 6;
    if (sheaf_trace_params_default(&p) != SHEAF_STATUS_OK) return 7;
    p.method = SHEAF_METHOD_BVH_RANGED;
    p.packet = 8;
    if (sheaf_context_trace_with(ctx, &p, rays, packet, 64 * 64) != SHEAF_STATUS_OK) return 8;
    for (i = 0; i < 64 * 64; ++i) {
        hits += single[i].prim != SHEAF_INVALID_ID;
        failed += single[i].prim != packet[i].prim || bits(single[i].t) != bits(packet[i].t);
    }
    sheaf_context_destroy(ctx);
    printf("no_std library: %u triangles, %u of %u rays hit, %u packet hits differ from single rays\n", nt, hits,
           64 * 64, failed);
    return (hits > 1000 && failed == 0) ? 0 : 10;
}
