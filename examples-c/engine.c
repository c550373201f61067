/*
 * engine.c: an engine's frame loop on a two-level scene through sheaf's C
 * ABI.
 *
 * Four geometries: a static level (a floor and four pillars, built once),
 * a cloth-like grid whose vertices move every frame (REFIT: the same index
 * buffer, vertices written in place), a box placed 16 times in a ring
 * that turns (the geometry never changes; only the instances' transforms
 * do), and a perforated grille placed twice: an alpha-tested mesh whose
 * holes are cut out by an any-hit filter (sheaf_filter_fn) from each
 * candidate's (u, v), so its shadow on the floor has the holes too. Every
 * frame: update what moved, move the instances, commit the top
 * level, trace camera rays as 8x8 frustum-first packets and shadow rays toward a
 * light, shade by geometry, print a table line; the last frame is written
 * as a binary PPM.
 *
 * Build and run from the repository root:
 *   make -C examples-c engine
 *   examples-c/engine [out.ppm] [frames]
 */
#define _POSIX_C_SOURCE 199309L
#include "sheaf.h"

#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define W 320
#define H 240
#define GRID 32 /* the cloth: GRID x GRID quads */
#define RING 16
#define GRILLE 10 /* the grille: GRILLE x GRILLE quads */

static double now_ms(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec * 1e3 + t.tv_nsec / 1e6;
}

/* A mesh being built: vertices (x, y, z) and triangles. */
typedef struct {
    float v[4096][3];
    uint32_t i[8192][3];
    uint32_t nv, nt;
} mesh;

static uint32_t vtx(mesh *m, float x, float y, float z) {
    m->v[m->nv][0] = x;
    m->v[m->nv][1] = y;
    m->v[m->nv][2] = z;
    return m->nv++;
}

static void quad(mesh *m, uint32_t a, uint32_t b, uint32_t c, uint32_t d) {
    uint32_t t[2][3] = {{a, b, c}, {a, c, d}};
    memcpy(m->i[m->nt], t, sizeof t);
    m->nt += 2;
}

/* An axis-aligned box [x0, x1] x [y0, y1] x [z0, z1]. */
static void box(mesh *m, float x0, float y0, float z0, float x1, float y1, float z1) {
    uint32_t c[8], k;
    for (k = 0; k < 8; ++k)
        c[k] = vtx(m, k & 1 ? x1 : x0, k & 2 ? y1 : y0, k & 4 ? z1 : z0);
    quad(m, c[0], c[1], c[3], c[2]);
    quad(m, c[4], c[6], c[7], c[5]);
    quad(m, c[0], c[4], c[5], c[1]);
    quad(m, c[2], c[3], c[7], c[6]);
    quad(m, c[0], c[2], c[6], c[4]);
    quad(m, c[1], c[5], c[7], c[3]);
}

static sheaf_mesh as_mesh(const mesh *m) {
    sheaf_mesh s;
    s.vertices = &m->v[0][0];
    s.vertex_stride_bytes = 3 * sizeof(float);
    s.vertex_count = m->nv;
    s.indices = &m->i[0][0];
    s.triangle_count = m->nt;
    return s;
}

/* The cloth's heights at time t (written in place: a refit reads them). */
static void wave(mesh *m, float t) {
    uint32_t x, z;
    for (z = 0; z <= GRID; ++z)
        for (x = 0; x <= GRID; ++x)
            m->v[z * (GRID + 1) + x][1] = 1.2f + 0.25f * sinf(0.6f * x + 1.7f * t) * cosf(0.5f * z + t);
}

/* Row-major 3x4: rotation about y by `a`, uniform scale `s`, translation. */
static void placed(float m[12], float a, float s, float x, float y, float z) {
    float c = cosf(a) * s, n = sinf(a) * s;
    float r[12] = {c, 0, n, x, 0, s, 0, y, -n, 0, c, z};
    memcpy(m, r, sizeof r);
}

/* The grille's cut-out: a round hole in every triangle, around its
 * centroid (u = v = 1/3). A pure function of the candidate; `user` counts
 * the calls (one thread traces here, so a plain counter will do). */
static bool grille_filter(void *user, const sheaf_candidate *c) {
    float du = c->u - 1.0f / 3.0f, dv = c->v - 1.0f / 3.0f;
    ++*(unsigned long *)user;
    return du * du + dv * dv + du * dv > 0.018f;
}

#define CHECK(call)                                                                          \
    do {                                                                                     \
        sheaf_status st_ = (call);                                                           \
        if (st_ != SHEAF_STATUS_OK) {                                                        \
            fprintf(stderr, "%s: %s\n", #call, sheaf_status_string(st_));                  \
            return 1;                                                                        \
        }                                                                                    \
    } while (0)

static mesh level, cloth, cube, grille;
static sheaf_ray rays[W * H], shadow[W * H];
static sheaf_scene_hit hits[W * H];
static uint8_t occluded[W * H];
static uint32_t pixel[W * H]; /* ray k's pixel, row-major */
static unsigned char image[W * H * 3];

int main(int argc, char **argv) {
    const char *out = argc > 1 ? argv[1] : "engine.ppm";
    int frames = argc > 2 ? atoi(argv[2]) : 8;
    const float eye[3] = {0.0f, 3.0f, 9.0f}, light[3] = {3.0f, 8.0f, 6.0f};
    sheaf_limits limits;
    sheaf_context *ctx = NULL;
    sheaf_geometry_params gp;
    sheaf_trace_params tp;
    sheaf_mesh m;
    float xf[12];
    uint32_t x, z, k, n = 0;
    unsigned long filter_calls = 0, calls_before;
    int f;

    /* The level: a floor and four pillars. The cloth: a GRID x GRID grid. */
    quad(&level, vtx(&level, -8, 0, -8), vtx(&level, -8, 0, 8), vtx(&level, 8, 0, 8), vtx(&level, 8, 0, -8));
    for (k = 0; k < 4; ++k)
        box(&level, (k & 1 ? 4.0f : -5.0f), 0.0f, (k & 2 ? 4.0f : -5.0f), (k & 1 ? 5.0f : -4.0f), 4.0f,
            (k & 2 ? 5.0f : -4.0f));
    for (z = 0; z <= GRID; ++z)
        for (x = 0; x <= GRID; ++x)
            vtx(&cloth, -3.0f + 6.0f * x / GRID, 1.2f, -3.0f + 6.0f * z / GRID);
    for (z = 0; z < GRID; ++z)
        for (x = 0; x < GRID; ++x) {
            uint32_t a = z * (GRID + 1) + x;
            quad(&cloth, a, a + GRID + 1, a + GRID + 2, a + 1);
        }
    box(&cube, -0.3f, 0.0f, -0.3f, 0.3f, 0.6f, 0.3f);
    /* The grille: upright, 2.4 wide and high, in the plane z = 0. */
    for (z = 0; z <= GRILLE; ++z)
        for (x = 0; x <= GRILLE; ++x)
            vtx(&grille, -1.2f + 2.4f * x / GRILLE, 0.2f + 2.4f * z / GRILLE, 0.0f);
    for (z = 0; z < GRILLE; ++z)
        for (x = 0; x < GRILLE; ++x) {
            uint32_t a = z * (GRILLE + 1) + x;
            quad(&grille, a, a + 1, a + GRILLE + 2, a + GRILLE + 1);
        }

    CHECK(sheaf_limits_default(16, &limits));
    limits.structures = SHEAF_STRUCTURE_BVH;
    limits.max_threads = 1;
    limits.max_geometries = 4;
    limits.max_instances = 4 + RING;
    limits.max_scene_triangles = level.nt + cloth.nt + cube.nt + grille.nt;
    CHECK(sheaf_context_create(&limits, &ctx));

    CHECK(sheaf_geometry_params_default(&gp)); /* STATIC, binned SAH */
    m = as_mesh(&level);
    CHECK(sheaf_context_set_scene_geometry(ctx, 0, &m, &gp));
    m = as_mesh(&cube);
    CHECK(sheaf_context_set_scene_geometry(ctx, 2, &m, &gp));
    gp.filter = grille_filter; /* the grille: alpha-tested */
    gp.filter_user = &filter_calls;
    m = as_mesh(&grille);
    CHECK(sheaf_context_set_scene_geometry(ctx, 3, &m, &gp));
    gp.filter = NULL;
    gp.filter_user = NULL;
    gp.mode = SHEAF_UPDATE_MODE_REFIT;
    wave(&cloth, 0.0f);
    m = as_mesh(&cloth);
    CHECK(sheaf_context_set_scene_geometry(ctx, 1, &m, &gp));
    placed(xf, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f);
    CHECK(sheaf_context_set_instance(ctx, 0, 0, xf, ~0u));
    CHECK(sheaf_context_set_instance(ctx, 1, 1, xf, ~0u));
    /* Two grilles between the light and the floor, turned a little. */
    placed(xf, 0.4f, 1.0f, -1.6f, 0.0f, 2.5f);
    CHECK(sheaf_context_set_instance(ctx, 2 + RING, 3, xf, ~0u));
    placed(xf, -0.5f, 1.0f, 1.8f, 0.0f, 3.0f);
    CHECK(sheaf_context_set_instance(ctx, 3 + RING, 3, xf, ~0u));

    /* Camera rays, 8x8 pixel tiles in order, 2x2 quads row by row inside
     * each tile: sheaf_context_trace_scene takes every run of 64 rays as
     * one 8x8 packet of 2x2 quads, so neighbours go together. pixel[k]
     * remembers ray k's pixel for shading. */
    for (k = 0; k < W * H; ++k) {
        uint32_t tile = k / 64, q = (k % 64) / 4, l = k % 4;
        uint32_t px = (tile % (W / 8)) * 8 + (q % 4) * 2 + (l % 2);
        uint32_t py = (tile / (W / 8)) * 8 + (q / 4) * 2 + (l / 2);
        float dx = (px + 0.5f - W / 2.0f) / H * 1.1f, dy = -(py + 0.5f - H / 2.0f) / H * 1.1f;
        pixel[k] = py * W + px;
        memcpy(rays[k].org, eye, sizeof eye);
        rays[k].dir[0] = dx;
        rays[k].dir[1] = dy - 0.3f;
        rays[k].dir[2] = -1.0f;
        rays[k].tmin = 0.0f;
        rays[k].tmax = INFINITY;
    }
    CHECK(sheaf_trace_params_default(&tp));
    tp.method = SHEAF_METHOD_BVH_FRUSTUM; /* the fastest packets through instances */
    tp.packet = 8;

    printf("%5s %9s %8s %10s %10s %9s %8s %13s\n", "frame", "update ms", "SAH x", "commit ms", "trace ms", "hits", "lit",
           "filter calls");
    for (f = 0; f < frames; ++f) {
        float t = 0.3f * f;
        sheaf_refit_info ri;
        sheaf_scene_info si;
        double t0, t1, t2, t3;
        uint32_t n_hit = 0, n_lit = 0;
        /* 1. What moved: the cloth's vertices (refit) and the ring. */
        wave(&cloth, t);
        m = as_mesh(&cloth);
        t0 = now_ms();
        CHECK(sheaf_context_update_scene_geometry(ctx, 1, &m, &ri));
        for (k = 0; k < RING; ++k) {
            float a = t * 0.5f + 6.2831853f * k / RING;
            placed(xf, 2.0f * a, 1.0f, 6.0f * cosf(a), 0.0f, 6.0f * sinf(a));
            CHECK(sheaf_context_set_instance(ctx, 2 + k, 2, xf, ~0u));
        }
        t1 = now_ms();
        CHECK(sheaf_context_commit_scene(ctx, &si));
        t2 = now_ms();
        calls_before = filter_calls;
        /* 2. Camera rays, then shadow rays from their hits to the light. */
        CHECK(sheaf_context_trace_scene(ctx, &tp, rays, hits, W * H, ~0u, 0));
        for (k = 0; k < W * H; ++k) {
            float p[3];
            int a;
            for (a = 0; a < 3; ++a)
                p[a] = rays[k].org[a] + 0.9995f * hits[k].t * rays[k].dir[a];
            memcpy(shadow[k].org, p, sizeof p);
            for (a = 0; a < 3; ++a)
                shadow[k].dir[a] = light[a] - p[a];
            shadow[k].tmin = 0.0f;
            shadow[k].tmax = hits[k].prim == SHEAF_INVALID_ID ? 0.0f : 1.0f; /* misses: empty rays */
        }
        CHECK(sheaf_context_occluded_scene(ctx, &tp, shadow, occluded, W * H, ~0u, 0));
        t3 = now_ms();
        /* 3. Shade: a colour per geometry, darker in shadow. */
        for (k = 0; k < W * H; ++k) {
            static const unsigned char colour[4][3] = {
                {200, 190, 170}, {220, 90, 60}, {70, 200, 90}, {240, 200, 60}};
            unsigned char *o = &image[3 * pixel[k]];
            int a;
            if (hits[k].prim == SHEAF_INVALID_ID) {
                o[0] = 140, o[1] = 170, o[2] = 210;
                continue;
            }
            ++n_hit;
            n_lit += !occluded[k];
            for (a = 0; a < 3; ++a)
                o[a] = (unsigned char)(colour[hits[k].geometry][a] * (occluded[k] ? 0.35f : 1.0f));
        }
        n = si.instances;
        printf("%5d %9.3f %8.3f %10.3f %10.2f %9u %8u %13lu\n", f, t1 - t0,
               ri.sah_before > 0 ? ri.sah_after / ri.sah_before : 1.0, t2 - t1, t3 - t2, n_hit, n_lit,
               filter_calls - calls_before);
    }
    printf("%u instances; the last frame in %s\n", n, out);
    {
        FILE *fp = fopen(out, "wb");
        if (!fp) {
            perror(out);
            return 1;
        }
        fprintf(fp, "P6\n%d %d\n255\n", W, H);
        fwrite(image, 1, sizeof image, fp);
        fclose(fp);
    }
    sheaf_context_destroy(ctx);
    return 0;
}
