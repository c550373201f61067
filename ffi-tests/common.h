/*
 * Shared helpers of the C tests of sheaf's C ABI (rure style: `bool
 * test_x(void)` functions, a run_test driver, a final "N passed, M failed"
 * line, non-zero exit on failure).
 *
 * Built by tests/c_abi.rs with
 *   gcc -std=c99 -Wall -Wextra -Werror -pedantic -Iinclude ...
 * once against libsheaf.a and once against libsheaf.so.
 */
#ifndef SHEAF_FFI_TESTS_COMMON_H
#define SHEAF_FFI_TESTS_COMMON_H

#include "sheaf.h"

#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---- test driver --------------------------------------------------------- */

#define CHECK(cond)                                                                    \
    do {                                                                               \
        if (!(cond)) {                                                                 \
            fprintf(stderr, "    %s:%d: check failed: %s\n", __FILE__, __LINE__, #cond); \
            return false;                                                              \
        }                                                                              \
    } while (0)

#define CHECK_STATUS(call, want)                                                       \
    do {                                                                               \
        sheaf_status got_ = (call);                                                    \
        if (got_ != (sheaf_status)(want)) {                                            \
            fprintf(stderr, "    %s:%d: %s\n      returned %u (%s), wanted %u (%s)\n",   \
                    __FILE__, __LINE__, #call, (unsigned)got_, sheaf_status_string(got_), \
                    (unsigned)(want), sheaf_status_string((sheaf_status)(want)));      \
            return false;                                                              \
        }                                                                              \
    } while (0)

#define CHECK_OK(call) CHECK_STATUS(call, SHEAF_STATUS_OK)

static inline void run_test(const char *name, bool (*test)(void), int *passed, int *failed) {
    bool ok = test();
    printf("%s: %s\n", ok ? "PASSED" : "FAILED", name);
    fflush(stdout);
    if (ok) {
        ++*passed;
    } else {
        ++*failed;
    }
}

static inline int report(int passed, int failed) {
    printf("%d passed, %d failed\n", passed, failed);
    return failed == 0 ? 0 : 1;
}

/* ---- aligned buffers (C99 has no aligned_alloc) -------------------------- */

/* Round p up to a multiple of a (a power of two). */
static inline void *align_up(void *p, size_t a) {
    uintptr_t u = (uintptr_t)p;
    return (void *)((u + (uintptr_t)(a - 1)) & ~(uintptr_t)(a - 1));
}

/* ---- scenes: xyz + one padding float per vertex (stride 16) -------------- */

#define SCENE_MAX_V 2048
#define SCENE_MAX_T 4096
#define SCENE_STRIDE (4 * sizeof(float))

typedef struct scene {
    float v[SCENE_MAX_V][4];
    uint32_t idx[3 * SCENE_MAX_T];
    uint32_t nv, nt;
} scene;

static inline scene *scene_new(void) {
    scene *s = (scene *)calloc(1, sizeof(scene));
    if (s == NULL) {
        fprintf(stderr, "out of memory\n");
        exit(2);
    }
    return s;
}

static inline uint32_t scene_vertex(scene *s, float x, float y, float z) {
    uint32_t i = s->nv++;
    s->v[i][0] = x;
    s->v[i][1] = y;
    s->v[i][2] = z;
    s->v[i][3] = -1234.5f; /* padding: never read as a coordinate */
    return i;
}

static inline uint32_t scene_tri(scene *s, uint32_t a, uint32_t b, uint32_t c) {
    uint32_t t = s->nt++;
    s->idx[3 * t] = a;
    s->idx[3 * t + 1] = b;
    s->idx[3 * t + 2] = c;
    return t;
}

/* Square [-h, h]^2 at z = 0: triangles (v0, v1, v2) below the diagonal
 * y = x and (v0, v2, v3) above it. */
static inline void scene_ground(scene *s, float h) {
    uint32_t a = scene_vertex(s, -h, -h, 0.0f);
    uint32_t b = scene_vertex(s, h, -h, 0.0f);
    uint32_t c = scene_vertex(s, h, h, 0.0f);
    uint32_t d = scene_vertex(s, -h, h, 0.0f);
    scene_tri(s, a, b, c);
    scene_tri(s, a, c, d);
}

/* Axis-aligned box, 12 triangles. */
static inline void scene_box(scene *s, float x0, float y0, float z0, float x1, float y1, float z1) {
    uint32_t v[8];
    int i;
    for (i = 0; i < 8; ++i) {
        v[i] = scene_vertex(s, (i & 1) ? x1 : x0, (i & 2) ? y1 : y0, (i & 4) ? z1 : z0);
    }
    /* -z, +z, -y, +y, -x, +x */
    scene_tri(s, v[0], v[2], v[3]); scene_tri(s, v[0], v[3], v[1]);
    scene_tri(s, v[4], v[5], v[7]); scene_tri(s, v[4], v[7], v[6]);
    scene_tri(s, v[0], v[1], v[5]); scene_tri(s, v[0], v[5], v[4]);
    scene_tri(s, v[2], v[6], v[7]); scene_tri(s, v[2], v[7], v[3]);
    scene_tri(s, v[0], v[4], v[6]); scene_tri(s, v[0], v[6], v[2]);
    scene_tri(s, v[1], v[3], v[7]); scene_tri(s, v[1], v[7], v[5]);
}

static inline sheaf_status scene_set(sheaf_context *ctx, const scene *s) {
    return sheaf_context_set_geometry(ctx, &s->v[0][0], SCENE_STRIDE, s->nv, s->idx, s->nt);
}

static inline sheaf_ray make_ray(float ox, float oy, float oz, float dx, float dy, float dz, float tmin,
                                 float tmax) {
    sheaf_ray r;
    r.org[0] = ox;
    r.org[1] = oy;
    r.org[2] = oz;
    r.dir[0] = dx;
    r.dir[1] = dy;
    r.dir[2] = dz;
    r.tmin = tmin;
    r.tmax = tmax;
    return r;
}

/* Bits of a float, for exact comparison and printing. */
static inline uint32_t float_bits(float f) {
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

/* A small camera looking at the origin from the front-left, above. */
static inline sheaf_frame default_frame(uint32_t width, uint32_t height) {
    sheaf_frame f;
    memset(&f, 0, sizeof f);
    f.camera.eye[0] = 6.0f;
    f.camera.eye[1] = -8.0f;
    f.camera.eye[2] = 5.0f;
    f.camera.look_at[2] = 0.5f;
    f.camera.up[2] = 1.0f;
    f.camera.fov_y_deg = 40.0f;
    f.light.position[0] = 4.0f;
    f.light.position[1] = -3.0f;
    f.light.position[2] = 8.0f;
    f.light.color[0] = f.light.color[1] = f.light.color[2] = 1.0f;
    (void)sheaf_shading_default(&f.shading);
    f.width = width;
    f.height = height;
    return f;
}

#endif /* SHEAF_FFI_TESTS_COMMON_H */
