/*
 * "Hits through the C ABI equal the Rust API's": this program builds a fixed
 * scene and fixed rays (all written here, in C), traces them through the C
 * ABI with two grid configurations, and prints everything as exact bit
 * patterns on lines starting with '@':
 *
 *   @limits <14 x u32>                     sheaf_limits used (projection_test as 0/1, structures, kd and pgrid pools)
 *   @vertex <i> <x> <y> <z>                float bits (hex)
 *   @tri <i> <a> <b> <c>
 *   @ray <i> <org x y z> <tmin> <dir x y z> <tmax>   float bits (hex)
 *   @build <k> <test> <lambda bits> <macrocell> <fit>
 *   @stats <k> <triangles_in> <triangles> <non_finite> <zero_area> <res x y z> <refs>
 *   @hit <k> <i> <prim> <t> <u> <v>        float bits (hex)
 *   @occ <k> <i> <0|1>
 *   @frame <k> <width> <height> <stride> <camera 10> <light 6> <albedo 3> <ambient> <background 3> <shadows>
 *   @image <k> <FNV-1a 64 of the pixel bytes, row by row, without padding>
 *
 * tests/c_abi.rs parses these lines, computes the same through the Rust API
 * (sheaf::OwnedContext) and compares bit for bit. The tests below check
 * what C alone can: create and create_in agree, results are deterministic.
 */
#include "common.h"

#define GRID_N 20
#define CAM_W 48
#define CAM_H 36
#define N_RANDOM 600
#define N_AXIS 180
#define N_SPECIAL 6
#define MAX_RAYS (CAM_W * CAM_H + N_RANDOM + N_AXIS + N_SPECIAL)
#define IMG_W 40
#define IMG_H 30
#define IMG_STRIDE (IMG_W * 4 + 8)

static scene *g_scene;
static sheaf_ray g_rays[MAX_RAYS];
static size_t g_nrays;

static uint32_t lcg(uint32_t *state) {
    *state = *state * 1664525u + 1013904223u;
    return *state >> 8;
}

static float unit(uint32_t *state) {
    return (float)lcg(state) / (float)(1u << 24);
}

/* Rolling terrain, four boxes, one NaN and one zero-area triangle. */
static void make_scene(void) {
    scene *s = scene_new();
    int i, j;
    uint32_t a, b, c;
    for (j = 0; j < GRID_N; ++j) {
        for (i = 0; i < GRID_N; ++i) {
            float x = -6.0f + 12.0f * (float)i / (GRID_N - 1), y = -6.0f + 12.0f * (float)j / (GRID_N - 1);
            scene_vertex(s, x, y, 0.6f * sinf(0.9f * x) * cosf(0.7f * y));
        }
    }
    for (j = 0; j + 1 < GRID_N; ++j) {
        for (i = 0; i + 1 < GRID_N; ++i) {
            uint32_t v = (uint32_t)(j * GRID_N + i);
            scene_tri(s, v, v + 1, v + GRID_N + 1);
            scene_tri(s, v, v + GRID_N + 1, v + GRID_N);
        }
    }
    scene_box(s, -1.0f, -1.0f, 0.0f, 1.0f, 1.0f, 2.0f);
    scene_box(s, 2.0f, -3.0f, -0.5f, 3.0f, -2.0f, 1.5f);
    scene_box(s, -4.0f, 2.0f, 0.2f, -2.5f, 3.5f, 0.9f);
    scene_box(s, 3.0f, 3.0f, 1.0f, 3.5f, 3.5f, 4.0f);
    a = scene_vertex(s, 0.0f, 0.0f, 3.0f);
    b = scene_vertex(s, NAN, 1.0f, 3.0f);
    c = scene_vertex(s, 1.0f, 0.0f, 3.0f);
    scene_tri(s, a, b, c);
    b = scene_vertex(s, 2.0f, 0.0f, 3.0f);
    scene_tri(s, a, c, b); /* collinear */
    g_scene = s;
}

static void add_ray(sheaf_ray r) {
    g_rays[g_nrays++] = r;
}

static void make_rays(void) {
    uint32_t st = 2024u;
    int x, y, i;
    /* pinhole camera rays */
    const float eye[3] = {9.0f, -11.0f, 6.0f};
    for (y = 0; y < CAM_H; ++y) {
        for (x = 0; x < CAM_W; ++x) {
            float u = ((float)x + 0.5f) / CAM_W - 0.5f, v = ((float)y + 0.5f) / CAM_H - 0.5f;
            float d[3];
            d[0] = -9.0f + 8.0f * u + 3.0f * v;
            d[1] = 11.0f + 6.0f * u - 2.0f * v;
            d[2] = -6.0f - 5.0f * v;
            add_ray(make_ray(eye[0], eye[1], eye[2], d[0], d[1], d[2], 0.0f, INFINITY));
        }
    }
    /* random rays, some with zero direction components, some with finite tmax */
    for (i = 0; i < N_RANDOM; ++i) {
        float o[3], d[3];
        int k;
        for (k = 0; k < 3; ++k) o[k] = -8.0f + 16.0f * unit(&st);
        o[2] = 0.1f + 5.0f * unit(&st);
        for (k = 0; k < 3; ++k) d[k] = -1.0f + 2.0f * unit(&st);
        if (i % 7 == 0) d[i % 3] = 0.0f;
        add_ray(make_ray(o[0], o[1], o[2], d[0], d[1], d[2], (i % 5 == 0) ? 0.5f : 0.0f,
                         (i % 3 == 0) ? 2.0f + 10.0f * unit(&st) : INFINITY));
    }
    /* axis-parallel rays along all six directions */
    for (i = 0; i < N_AXIS; ++i) {
        float o[3], d[3] = {0.0f, 0.0f, 0.0f};
        o[0] = -7.0f + 14.0f * unit(&st);
        o[1] = -7.0f + 14.0f * unit(&st);
        o[2] = -0.5f + 4.0f * unit(&st);
        d[(i / 2) % 3] = (i % 2) ? 1.0f : -1.0f;
        add_ray(make_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY));
    }
    /* invalid rays: misses */
    add_ray(make_ray(0.0f, 0.0f, 5.0f, 0.0f, 0.0f, 0.0f, 0.0f, INFINITY));
    add_ray(make_ray(NAN, 0.0f, 5.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY));
    add_ray(make_ray(0.0f, 0.0f, 5.0f, 0.0f, INFINITY, -1.0f, 0.0f, INFINITY));
    add_ray(make_ray(0.0f, 0.0f, 5.0f, 0.0f, 0.0f, -1.0f, 3.0f, 2.0f));
    add_ray(make_ray(0.0f, 0.0f, 5.0f, 0.0f, 0.0f, -1.0f, -1.0f, INFINITY));
    add_ray(make_ray(0.0f, 0.0f, 5.0f, 0.0f, 0.0f, -1.0f, 0.0f, NAN));
}

/* The two grid configurations compared. */
static sheaf_grid_params build_params(int k) {
    sheaf_grid_params p;
    (void)sheaf_grid_params_default(&p);
    if (k == 1) {
        p.test = SHEAF_TRI_TEST_WATERTIGHT;
        p.lambda = 3.0f;
        p.macrocell = 4;
    }
    return p;
}

static sheaf_frame build_frame(int k) {
    sheaf_frame f = default_frame(IMG_W, IMG_H);
    f.camera.eye[0] = 9.0f;
    f.camera.eye[1] = -11.0f;
    f.camera.eye[2] = 6.0f;
    if (k == 1) {
        f.shading.ambient = 0.3f;
        f.light.position[0] = -5.0f;
    }
    return f;
}

static uint64_t fnv1a(const uint8_t *img, size_t w, size_t h, size_t stride) {
    uint64_t x = 1469598103934665603ull;
    size_t r, i;
    for (r = 0; r < h; ++r) {
        for (i = 0; i < 4 * w; ++i) {
            x ^= img[r * stride + i];
            x *= 1099511628211ull;
        }
    }
    return x;
}

static sheaf_context *make_context(int k, sheaf_limits *limits) {
    sheaf_grid_params p = build_params(k);
    sheaf_context *ctx = NULL;
    if (sheaf_limits_default(g_scene->nt, limits) != SHEAF_STATUS_OK) return NULL;
    if (sheaf_context_create(limits, &ctx) != SHEAF_STATUS_OK) return NULL;
    if (scene_set(ctx, g_scene) != SHEAF_STATUS_OK || sheaf_context_build_grid(ctx, &p) != SHEAF_STATUS_OK) {
        sheaf_context_destroy(ctx);
        return NULL;
    }
    return ctx;
}

static bool test_create_and_create_in_agree(void) {
    static sheaf_hit a[MAX_RAYS], b[MAX_RAYS];
    sheaf_limits l;
    sheaf_context *ctx = make_context(0, &l), *in = NULL;
    sheaf_grid_params p = build_params(0);
    size_t need = 0;
    unsigned char *raw, *buf;
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_required_bytes(&l, &need));
    raw = (unsigned char *)malloc(need + SHEAF_CONTEXT_ALIGN);
    CHECK(raw != NULL);
    buf = (unsigned char *)align_up(raw, SHEAF_CONTEXT_ALIGN);
    CHECK_OK(sheaf_context_create_in(buf, need, &l, &in));
    CHECK_OK(scene_set(in, g_scene));
    CHECK_OK(sheaf_context_build_grid(in, &p));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, g_rays, a, g_nrays));
    CHECK_OK(sheaf_context_trace(in, SHEAF_METHOD_GRID_DDA, g_rays, b, g_nrays));
    CHECK(memcmp(a, b, g_nrays * sizeof a[0]) == 0);
    /* rebuilding gives the same grid and the same hits */
    CHECK_OK(sheaf_context_build_grid(in, &p));
    CHECK_OK(sheaf_context_trace(in, SHEAF_METHOD_GRID_DDA, g_rays, b, g_nrays));
    CHECK(memcmp(a, b, g_nrays * sizeof a[0]) == 0);
    sheaf_context_destroy(in);
    sheaf_context_destroy(ctx);
    free(raw);
    return true;
}

/* Trace, occlusion, stats and a render for configuration k, printed. */
static bool emit(int k) {
    static sheaf_hit hits[MAX_RAYS];
    static uint8_t occ[MAX_RAYS];
    static uint8_t img[(IMG_H - 1) * IMG_STRIDE + IMG_W * 4];
    sheaf_limits l;
    sheaf_context *ctx = make_context(k, &l);
    sheaf_grid_params p = build_params(k);
    sheaf_frame f = build_frame(k);
    sheaf_stats st;
    size_t i, n_hit = 0;
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, g_rays, hits, g_nrays));
    CHECK_OK(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_DDA, g_rays, occ, g_nrays));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, img, IMG_STRIDE, sizeof img));
    printf("@build %d %u %08x %u %d\n", k, (unsigned)p.test, float_bits(p.lambda), p.macrocell, p.fit ? 1 : 0);
    printf("@stats %d %u %u %u %u %u %u %u %u\n", k, st.triangles_in, st.triangles, st.excluded_non_finite,
           st.excluded_zero_area, st.grid_res[0], st.grid_res[1], st.grid_res[2], st.grid_refs);
    for (i = 0; i < g_nrays; ++i) {
        printf("@hit %d %u %u %08x %08x %08x\n", k, (unsigned)i, hits[i].prim, float_bits(hits[i].t),
               float_bits(hits[i].u), float_bits(hits[i].v));
        n_hit += hits[i].prim != SHEAF_INVALID_ID;
    }
    for (i = 0; i < g_nrays; ++i) printf("@occ %d %u %u\n", k, (unsigned)i, (unsigned)occ[i]);
    printf("@frame %d %u %u %u", k, f.width, f.height, (unsigned)IMG_STRIDE);
    for (i = 0; i < 3; ++i) printf(" %08x", float_bits(f.camera.eye[i]));
    for (i = 0; i < 3; ++i) printf(" %08x", float_bits(f.camera.look_at[i]));
    for (i = 0; i < 3; ++i) printf(" %08x", float_bits(f.camera.up[i]));
    printf(" %08x", float_bits(f.camera.fov_y_deg));
    for (i = 0; i < 3; ++i) printf(" %08x", float_bits(f.light.position[i]));
    for (i = 0; i < 3; ++i) printf(" %08x", float_bits(f.light.color[i]));
    for (i = 0; i < 3; ++i) printf(" %08x", float_bits(f.shading.albedo[i]));
    printf(" %08x", float_bits(f.shading.ambient));
    for (i = 0; i < 3; ++i) printf(" %08x", float_bits(f.shading.background[i]));
    printf(" %d\n", f.shading.shadows ? 1 : 0);
    printf("@image %d %016llx\n", k, (unsigned long long)fnv1a(img, IMG_W, IMG_H, IMG_STRIDE));
    CHECK(n_hit > g_nrays / 3); /* a meaningful comparison: many rays hit */
    CHECK(st.excluded_non_finite == 1 && st.excluded_zero_area == 1);
    sheaf_context_destroy(ctx);
    return true;
}

static bool test_emit_scene_and_rays(void) {
    sheaf_limits l;
    uint32_t i;
    CHECK_OK(sheaf_limits_default(g_scene->nt, &l));
    printf("@limits %u %u %u %u %u %u %u %u %u %u %u %u %u %u\n", l.max_triangles, l.max_vertices, l.max_image_width,
           l.max_image_height, l.max_tile, l.max_threads, l.max_grid_cells, l.max_grid_refs,
           (unsigned)l.projection_test, l.structures, l.max_kd_nodes, l.max_kd_refs, l.max_pgrid_cells,
           l.max_pgrid_refs);
    for (i = 0; i < g_scene->nv; ++i)
        printf("@vertex %u %08x %08x %08x\n", i, float_bits(g_scene->v[i][0]), float_bits(g_scene->v[i][1]),
               float_bits(g_scene->v[i][2]));
    for (i = 0; i < g_scene->nt; ++i)
        printf("@tri %u %u %u %u\n", i, g_scene->idx[3 * i], g_scene->idx[3 * i + 1], g_scene->idx[3 * i + 2]);
    for (i = 0; i < g_nrays; ++i) {
        const sheaf_ray *r = &g_rays[i];
        printf("@ray %u %08x %08x %08x %08x %08x %08x %08x %08x\n", i, float_bits(r->org[0]), float_bits(r->org[1]),
               float_bits(r->org[2]), float_bits(r->tmin), float_bits(r->dir[0]), float_bits(r->dir[1]),
               float_bits(r->dir[2]), float_bits(r->tmax));
    }
    return true;
}

static bool test_emit_moller_trumbore(void) {
    return emit(0);
}

static bool test_emit_watertight(void) {
    return emit(1);
}

int main(void) {
    int passed = 0, failed = 0;
    make_scene();
    make_rays();
    run_test("test_create_and_create_in_agree", test_create_and_create_in_agree, &passed, &failed);
    run_test("test_emit_scene_and_rays", test_emit_scene_and_rays, &passed, &failed);
    run_test("test_emit_moller_trumbore", test_emit_moller_trumbore, &passed, &failed);
    run_test("test_emit_watertight", test_emit_watertight, &passed, &failed);
    free(g_scene);
    return report(passed, failed);
}
