/*
 * The C ABI contract, call by call: lifecycle, every bad-input path (each
 * NULL pointer, zero and overflowing sizes, misaligned and too small
 * buffers, out-of-range indices, NaN vertices, capacity errors) and the
 * results of trace, occluded and render. Outputs must be written only on
 * SHEAF_STATUS_OK, and a failed call must leave the context as it was.
 */
#include "common.h"

/* Ground (tris 0, 1) and a unit box on it (tris 2..13): 14 triangles, 12 vertices. */
static scene *ground_and_box(void) {
    scene *s = scene_new();
    scene_ground(s, 4.0f);
    scene_box(s, -0.5f, -0.5f, 0.0f, 0.5f, 0.5f, 1.0f);
    return s;
}

/* A created, built context over `s` (kept alive by the caller). */
static sheaf_context *built_context(const scene *s, uint32_t max_triangles) {
    sheaf_limits limits;
    sheaf_context *ctx = NULL;
    if (sheaf_limits_default(max_triangles, &limits) != SHEAF_STATUS_OK) return NULL;
    if (sheaf_context_create(&limits, &ctx) != SHEAF_STATUS_OK) return NULL;
    if (scene_set(ctx, s) != SHEAF_STATUS_OK || sheaf_context_build_grid(ctx, NULL) != SHEAF_STATUS_OK) {
        sheaf_context_destroy(ctx);
        return NULL;
    }
    return ctx;
}

/* Rays over ground_and_box: ground, box top, miss, axis-parallel box side, ... */
#define N_PROBE 8
static void probe_rays(sheaf_ray rays[N_PROBE]) {
    rays[0] = make_ray(2.0f, -1.0f, 5.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY); /* ground tri 0, t = 5 */
    rays[1] = make_ray(-2.0f, 1.0f, 5.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY); /* ground tri 1, t = 5 */
    rays[2] = make_ray(0.1f, 0.2f, 5.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY);  /* box top, t = 4 */
    rays[3] = make_ray(2.0f, -1.0f, 1.0f, 0.0f, 0.0f, 1.0f, 0.0f, INFINITY);  /* up: miss */
    rays[4] = make_ray(-3.0f, 0.1f, 0.5f, 1.0f, 0.0f, 0.0f, 0.0f, INFINITY);  /* box side x = -0.5, t = 2.5 */
    rays[5] = make_ray(2.0f, -1.0f, 5.0f, 0.0f, 0.0f, -1.0f, 0.0f, 4.5f);     /* tmax before ground: miss */
    rays[6] = make_ray(NAN, 0.0f, 5.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY);   /* invalid: miss */
    rays[7] = make_ray(3.0f, 2.5f, 2.0f, -1.0f, -1.0f, -1.0f, 0.0f, INFINITY); /* diagonal onto the ground */
}

static bool hits_equal(const sheaf_hit *a, const sheaf_hit *b, size_t n) {
    size_t i;
    for (i = 0; i < n; ++i) {
        if (float_bits(a[i].t) != float_bits(b[i].t) || a[i].prim != b[i].prim ||
            float_bits(a[i].u) != float_bits(b[i].u) || float_bits(a[i].v) != float_bits(b[i].v)) {
            fprintf(stderr, "    hit %u differs: prim %u t %.9g vs prim %u t %.9g\n", (unsigned)i,
                    a[i].prim, a[i].t, b[i].prim, b[i].t);
            return false;
        }
    }
    return true;
}

static bool last_error_contains(const sheaf_context *ctx, const char *what) {
    char msg[SHEAF_ERROR_MESSAGE_MAX];
    size_t n = 0;
    if (sheaf_context_last_error(ctx, msg, sizeof msg, &n) != SHEAF_STATUS_OK) return false;
    if (strstr(msg, what) == NULL) {
        fprintf(stderr, "    last error \"%s\" does not contain \"%s\"\n", msg, what);
        return false;
    }
    return n == strlen(msg);
}

/* ---- status strings and version ------------------------------------------ */

static bool test_status_codes_and_strings(void) {
    static const struct {
        sheaf_status status;
        unsigned code;
    } all[] = {
        {SHEAF_STATUS_OK, 0},
        {SHEAF_STATUS_NULL_POINTER, 100},
        {SHEAF_STATUS_INVALID_ARGUMENT, 101},
        {SHEAF_STATUS_INDEX_OUT_OF_RANGE, 102},
        {SHEAF_STATUS_MISALIGNED, 103},
        {SHEAF_STATUS_BUFFER_TOO_SMALL, 104},
        {SHEAF_STATUS_CAPACITY_TRIANGLES, 200},
        {SHEAF_STATUS_CAPACITY_VERTICES, 201},
        {SHEAF_STATUS_CAPACITY_GRID_CELLS, 202},
        {SHEAF_STATUS_CAPACITY_GRID_REFS, 203},
        {SHEAF_STATUS_CAPACITY_IMAGE, 204},
        {SHEAF_STATUS_CAPACITY_THREADS, 205},
        {SHEAF_STATUS_CAPACITY_PGRID_CELLS, 206},
        {SHEAF_STATUS_CAPACITY_PGRID_REFS, 207},
        {SHEAF_STATUS_CAPACITY_PACKET_SIDE, 208},
        {SHEAF_STATUS_CAPACITY_BOUNCES, 209},
        {SHEAF_STATUS_OUT_OF_MEMORY, 299},
        {SHEAF_STATUS_NO_GEOMETRY, 300},
        {SHEAF_STATUS_NOT_BUILT, 301},
        {SHEAF_STATUS_PANIC, 900},
    };
    const size_t n = sizeof all / sizeof all[0];
    const char *unknown = sheaf_status_string((sheaf_status)12345);
    size_t i, j;
    CHECK(unknown != NULL && strlen(unknown) > 0);
    CHECK(sheaf_status_string((sheaf_status)1) != NULL);
    CHECK(sheaf_status_string((sheaf_status)99) != NULL);
    CHECK(sheaf_status_string((sheaf_status)0xFFFFFFFFu) != NULL);
    CHECK(strcmp(sheaf_status_string((sheaf_status)199), unknown) == 0);
    for (i = 0; i < n; ++i) {
        const char *s = sheaf_status_string(all[i].status);
        CHECK((unsigned)all[i].status == all[i].code); /* codes are never renumbered */
        CHECK(s != NULL && strlen(s) > 0);
        CHECK(strcmp(s, unknown) != 0);
        for (j = 0; j < i; ++j) CHECK(strcmp(s, sheaf_status_string(all[j].status)) != 0);
    }
    CHECK(strcmp(sheaf_status_string(SHEAF_STATUS_OK), "ok") == 0);
    return true;
}

static bool test_version(void) {
    char want[64];
    const char *v = sheaf_version_string();
    CHECK(v != NULL);
    sprintf(want, "%d.%d.%d", SHEAF_VERSION_MAJOR, SHEAF_VERSION_MINOR, SHEAF_VERSION_PATCH);
    CHECK(strcmp(v, want) == 0);
    return true;
}

/* ---- defaults and required bytes ------------------------------------------ */

static bool test_defaults(void) {
    sheaf_limits l;
    sheaf_grid_params p;
    sheaf_shading sh;
    CHECK_OK(sheaf_limits_default(100, &l));
    CHECK(l.max_triangles == 100 && l.max_vertices == 300 && l.max_threads == 8 && l.max_tile == 64);
    CHECK(l.max_image_width == 4096 && l.max_image_height == 4096);
    CHECK(l.max_grid_cells == 0 && l.max_grid_refs == 0);
    CHECK_STATUS((sheaf_limits_default)(1, NULL, sizeof(sheaf_limits)), SHEAF_STATUS_NULL_POINTER);
    CHECK_OK(sheaf_grid_params_default(&p));
    CHECK(p.lambda == 5.0f && p.macrocell == 6 && p.test == SHEAF_TRI_TEST_MOLLER_TRUMBORE && !p.fit);
    CHECK_STATUS((sheaf_grid_params_default)(NULL, sizeof(sheaf_grid_params)), SHEAF_STATUS_NULL_POINTER);
    CHECK_OK(sheaf_shading_default(&sh));
    CHECK(sh.shadows && sh.ambient > 0.0f);
    CHECK_STATUS(sheaf_shading_default(NULL), SHEAF_STATUS_NULL_POINTER);
    return true;
}

static bool test_required_bytes(void) {
    sheaf_limits l, bad;
    size_t a = 0, b = 0, untouched = 777;
    CHECK_OK(sheaf_limits_default(100, &l));
    CHECK_OK(sheaf_required_bytes(&l, &a));
    CHECK(a > 0 && a % SHEAF_CONTEXT_ALIGN == 0);
    l.max_triangles = 1000;
    CHECK_OK(sheaf_required_bytes(&l, &b));
    CHECK(b > a);
    CHECK_STATUS(sheaf_required_bytes(NULL, &untouched), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_required_bytes(&l, NULL), SHEAF_STATUS_NULL_POINTER);
    bad = l;
    bad.max_threads = 0; /* zero sizes are invalid */
    CHECK_STATUS(sheaf_required_bytes(&bad, &untouched), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = l;
    bad.max_tile = 0;
    CHECK_STATUS(sheaf_required_bytes(&bad, &untouched), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = l;
    bad.max_image_width = 0;
    CHECK_STATUS(sheaf_required_bytes(&bad, &untouched), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = l;
    bad.max_grid_refs = 0xFFFFFFFFu;
    bad.max_grid_cells = 0xFFFFFFFFu; /* above 2^32 - 1 entries */
    CHECK_STATUS(sheaf_required_bytes(&bad, &untouched), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(untouched == 777);
    {
        /* Slot scratch follows the packet side, bounces and renderers. */
        size_t all = 0, small = 0, ray_only = 0, a8 = 0;
        CHECK(l.max_packet_side == 32 && l.max_bounces == 8 &&
              l.renderers == (SHEAF_RENDERER_TILES | SHEAF_RENDERER_WHITTED | SHEAF_RENDERER_DEFERRED));
        CHECK_OK(sheaf_slot_scratch_bytes(&l, &all));
        bad = l;
        bad.max_packet_side = 8;
        CHECK_OK(sheaf_slot_scratch_bytes(&bad, &small));
        CHECK_OK(sheaf_required_bytes(&bad, &a8));
        CHECK(small * 8 < all && a8 < b);
        bad.renderers = 0;
        CHECK_OK(sheaf_slot_scratch_bytes(&bad, &ray_only));
        CHECK(ray_only < small);
        bad.max_packet_side = 12;
        CHECK_STATUS(sheaf_slot_scratch_bytes(&bad, &untouched), SHEAF_STATUS_INVALID_ARGUMENT);
        CHECK_STATUS(sheaf_required_bytes(&bad, &untouched), SHEAF_STATUS_INVALID_ARGUMENT);
        bad = l;
        bad.max_bounces = 9;
        CHECK_STATUS(sheaf_slot_scratch_bytes(&bad, &untouched), SHEAF_STATUS_INVALID_ARGUMENT);
        bad = l;
        bad.renderers = 8;
        CHECK_STATUS(sheaf_slot_scratch_bytes(&bad, &untouched), SHEAF_STATUS_INVALID_ARGUMENT);
        CHECK_STATUS(sheaf_slot_scratch_bytes(&l, NULL), SHEAF_STATUS_NULL_POINTER);
        CHECK(untouched == 777);
    }
    return true;
}

/* ---- lifecycle -------------------------------------------------------------- */

static bool test_create_destroy(void) {
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    sheaf_context *untouched = (sheaf_context *)&l;
    CHECK_OK(sheaf_limits_default(10, &l));
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK(ctx != NULL);
    sheaf_context_destroy(ctx);
    sheaf_context_destroy(NULL); /* accepted */
    CHECK_STATUS(sheaf_context_create(NULL, &untouched), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_create(&l, NULL), SHEAF_STATUS_NULL_POINTER);
    l.max_threads = 0;
    CHECK_STATUS(sheaf_context_create(&l, &untouched), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(untouched == (sheaf_context *)&l);
    return true;
}

/* create_in with exactly sheaf_required_bytes: everything lives inside the
 * buffer (guard bytes after it stay untouched through a whole frame). */
static bool test_create_in_exact_size(void) {
    enum { GUARD = 256 };
    scene *s = ground_and_box();
    sheaf_limits l;
    size_t need = 0, i;
    unsigned char *raw, *buf;
    sheaf_context *ctx = NULL, *ref;
    sheaf_ray rays[N_PROBE];
    sheaf_hit hits[N_PROBE], want[N_PROBE];
    sheaf_frame f = default_frame(32, 24);
    static uint8_t rgba[32 * 24 * 4];

    CHECK_OK(sheaf_limits_default(s->nt, &l));
    CHECK_OK(sheaf_required_bytes(&l, &need));
    raw = (unsigned char *)malloc(need + GUARD + SHEAF_CONTEXT_ALIGN);
    CHECK(raw != NULL);
    buf = (unsigned char *)align_up(raw, SHEAF_CONTEXT_ALIGN);
    memset(buf, 0xEE, need + GUARD);
    CHECK_OK(sheaf_context_create_in(buf, need, &l, &ctx));
    CHECK(ctx != NULL);
    CHECK((unsigned char *)ctx >= buf && (unsigned char *)ctx < buf + need); /* the handle is inside */
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_context_build_grid(ctx, NULL));
    probe_rays(rays);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, hits, N_PROBE));
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, rgba, 32 * 4, sizeof rgba));
    /* same results as an allocating context */
    ref = built_context(s, s->nt);
    CHECK(ref != NULL);
    CHECK_OK(sheaf_context_trace(ref, SHEAF_METHOD_GRID_DDA, rays, want, N_PROBE));
    CHECK(hits_equal(hits, want, N_PROBE));
    sheaf_context_destroy(ref);
    sheaf_context_destroy(ctx);
    for (i = 0; i < GUARD; ++i) CHECK(buf[need + i] == 0xEE);
    free(raw);
    free(s);
    return true;
}

static bool test_create_in_bad_buffers(void) {
    sheaf_limits l;
    size_t need = 0;
    unsigned char *raw, *buf;
    sheaf_context *untouched = (sheaf_context *)&l;
    CHECK_OK(sheaf_limits_default(50, &l));
    CHECK_OK(sheaf_required_bytes(&l, &need));
    raw = (unsigned char *)malloc(need + 2 * SHEAF_CONTEXT_ALIGN);
    CHECK(raw != NULL);
    buf = (unsigned char *)align_up(raw, SHEAF_CONTEXT_ALIGN);
    /* one byte too small, and zero bytes */
    CHECK_STATUS(sheaf_context_create_in(buf, need - 1, &l, &untouched), SHEAF_STATUS_BUFFER_TOO_SMALL);
    CHECK_STATUS(sheaf_context_create_in(buf, 0, &l, &untouched), SHEAF_STATUS_BUFFER_TOO_SMALL);
    /* misaligned, even with room to spare */
    CHECK_STATUS(sheaf_context_create_in(buf + 8, need + 8, &l, &untouched), SHEAF_STATUS_MISALIGNED);
    CHECK_STATUS(sheaf_context_create_in(buf + 1, need + 8, &l, &untouched), SHEAF_STATUS_MISALIGNED);
    /* NULL arguments */
    CHECK_STATUS(sheaf_context_create_in(NULL, need, &l, &untouched), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_create_in(buf, need, NULL, &untouched), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_create_in(buf, need, &l, NULL), SHEAF_STATUS_NULL_POINTER);
    /* invalid limits */
    l.max_tile = 3;
    CHECK_STATUS(sheaf_context_create_in(buf, need, &l, &untouched), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(untouched == (sheaf_context *)&l);
    free(raw);
    return true;
}

/* A create_in context's memory stays valid after destroy: a stale handle
 * is then detected instead of used. */
static bool test_create_in_stale_handle(void) {
    sheaf_limits l;
    size_t need = 0;
    unsigned char *raw, *buf;
    sheaf_context *ctx = NULL;
    sheaf_stats st;
    CHECK_OK(sheaf_limits_default(4, &l));
    CHECK_OK(sheaf_required_bytes(&l, &need));
    raw = (unsigned char *)malloc(need + SHEAF_CONTEXT_ALIGN);
    CHECK(raw != NULL);
    buf = (unsigned char *)align_up(raw, SHEAF_CONTEXT_ALIGN);
    CHECK_OK(sheaf_context_create_in(buf, need, &l, &ctx));
    sheaf_context_destroy(ctx);
    CHECK_STATUS(sheaf_context_stats(ctx, &st), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_grid(ctx, NULL), SHEAF_STATUS_INVALID_ARGUMENT);
    sheaf_context_destroy(ctx); /* second destroy: ignored */
    free(raw);
    return true;
}

/* ---- geometry ---------------------------------------------------------------- */

static bool test_set_geometry_bad_arguments(void) {
    scene *s = ground_and_box();
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    uint32_t *misaligned_storage;
    uint32_t *misaligned;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_STATUS(sheaf_context_set_geometry(NULL, &s->v[0][0], SCENE_STRIDE, s->nv, s->idx, s->nt),
                 SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_set_geometry(ctx, NULL, SCENE_STRIDE, s->nv, s->idx, s->nt),
                 SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_set_geometry(ctx, &s->v[0][0], SCENE_STRIDE, s->nv, NULL, s->nt),
                 SHEAF_STATUS_NULL_POINTER);
    /* strides: zero, below 12, not a multiple of 4, overflowing */
    CHECK_STATUS(sheaf_context_set_geometry(ctx, &s->v[0][0], 0, s->nv, s->idx, s->nt),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_set_geometry(ctx, &s->v[0][0], 8, s->nv, s->idx, s->nt),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_set_geometry(ctx, &s->v[0][0], 14, s->nv, s->idx, s->nt),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_set_geometry(ctx, &s->v[0][0], (size_t)-1 / 2, s->nv, s->idx, s->nt),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    /* indices not 4-byte aligned */
    misaligned_storage = (uint32_t *)malloc(sizeof(uint32_t) * (3 * s->nt + 1));
    CHECK(misaligned_storage != NULL);
    misaligned = (uint32_t *)(void *)((unsigned char *)misaligned_storage + 2);
    memcpy(misaligned, s->idx, sizeof(uint32_t) * 3 * s->nt);
    CHECK_STATUS(sheaf_context_set_geometry(ctx, &s->v[0][0], SCENE_STRIDE, s->nv, misaligned, s->nt),
                 SHEAF_STATUS_MISALIGNED);
    free(misaligned_storage);
    /* nothing was set */
    CHECK_STATUS(sheaf_context_build_grid(ctx, NULL), SHEAF_STATUS_NO_GEOMETRY);
    /* empty geometry with NULL pointers is fine, and builds an empty grid */
    CHECK_OK(sheaf_context_set_geometry(ctx, NULL, 12, 0, NULL, 0));
    CHECK_OK(sheaf_context_build_grid(ctx, NULL));
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_state_errors(void) {
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    sheaf_ray rays[N_PROBE];
    sheaf_hit hits[N_PROBE];
    uint8_t occ[N_PROBE];
    sheaf_frame f = default_frame(8, 8);
    uint8_t rgba[8 * 8 * 4];
    sheaf_stats st;
    probe_rays(rays);
    CHECK_OK(sheaf_limits_default(16, &l));
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK(last_error_contains(ctx, "no error"));
    CHECK_STATUS(sheaf_context_build_grid(ctx, NULL), SHEAF_STATUS_NO_GEOMETRY);
    CHECK(last_error_contains(ctx, "no geometry"));
    CHECK_STATUS(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, hits, N_PROBE), SHEAF_STATUS_NOT_BUILT);
    CHECK_STATUS(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_DDA, rays, occ, N_PROBE), SHEAF_STATUS_NOT_BUILT);
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, rgba, 32, sizeof rgba),
                 SHEAF_STATUS_NOT_BUILT);
    CHECK(last_error_contains(ctx, "no acceleration structure"));
    CHECK_OK(sheaf_context_stats(ctx, &st)); /* all zero before the first build */
    CHECK(st.triangles_in == 0 && st.grid_cells == 0 && st.counters.rays == 0);
    sheaf_context_destroy(ctx);
    return true;
}

/* An out-of-range index is rejected; the previous geometry and grid stay. */
static bool test_index_out_of_range_keeps_previous_geometry(void) {
    scene *s = ground_and_box();
    scene *bad = scene_new();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_ray rays[N_PROBE];
    sheaf_hit before[N_PROBE], after[N_PROBE], rebuilt[N_PROBE];
    CHECK(ctx != NULL);
    probe_rays(rays);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, before, N_PROBE));
    *bad = *s;
    bad->idx[3 * 5 + 1] = bad->nv; /* triangle 5 references vertex 12 of 12 */
    CHECK_STATUS(scene_set(ctx, bad), SHEAF_STATUS_INDEX_OUT_OF_RANGE);
    CHECK(last_error_contains(ctx, "triangle 5 references vertex 12"));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, after, N_PROBE));
    CHECK(hits_equal(before, after, N_PROBE));
    CHECK_OK(sheaf_context_build_grid(ctx, NULL)); /* rebuilds the previous (valid) geometry */
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, rebuilt, N_PROBE));
    CHECK(hits_equal(before, rebuilt, N_PROBE));
    sheaf_context_destroy(ctx);
    free(bad);
    free(s);
    return true;
}

/* NaN vertices and zero-area triangles are excluded and counted. */
static bool test_nan_and_degenerate_triangles_are_excluded(void) {
    scene *s = scene_new();
    sheaf_context *ctx;
    sheaf_stats st;
    sheaf_ray rays[N_PROBE];
    sheaf_hit hits[N_PROBE];
    uint32_t a, b, c;
    scene_ground(s, 4.0f);
    a = scene_vertex(s, 0.0f, 0.0f, 1.0f);
    b = scene_vertex(s, NAN, 0.0f, 1.0f);
    c = scene_vertex(s, 0.0f, 1.0f, 1.0f);
    scene_tri(s, a, b, c); /* NaN vertex */
    a = scene_vertex(s, 0.0f, 0.0f, 2.0f);
    b = scene_vertex(s, 1.0f, 1.0f, 2.0f);
    c = scene_vertex(s, 2.0f, 2.0f, 2.0f);
    scene_tri(s, a, b, c); /* collinear: zero area */
    a = scene_vertex(s, INFINITY, 0.0f, 3.0f);
    scene_tri(s, a, b, c); /* infinite vertex */
    ctx = built_context(s, s->nt);
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.triangles_in == 5);
    CHECK(st.triangles == 2);
    CHECK(st.excluded_non_finite == 2);
    CHECK(st.excluded_zero_area == 1);
    probe_rays(rays);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, hits, N_PROBE));
    CHECK(hits[0].prim == 0 && hits[1].prim == 1);
    CHECK(hits[2].prim == 0 || hits[2].prim == 1); /* no box here: the ground */
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

/* ---- capacity -------------------------------------------------------------- */

static bool test_capacity_triangles_and_vertices(void) {
    scene *s = ground_and_box();
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    CHECK_OK(sheaf_limits_default(2, &l)); /* the ground fits, the box does not */
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_STATUS(scene_set(ctx, s), SHEAF_STATUS_CAPACITY_TRIANGLES);
    CHECK(last_error_contains(ctx, "'triangles': needed 14, available 2"));
    sheaf_context_destroy(ctx);
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    l.max_vertices = 4;
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_STATUS(scene_set(ctx, s), SHEAF_STATUS_CAPACITY_VERTICES);
    CHECK(last_error_contains(ctx, "'vertices'"));
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

/* max_grid_refs fits the ground but not ground + box: the failed build
 * leaves the previous grid tracing identically. */
static bool test_capacity_grid_refs_keeps_previous_grid(void) {
    scene *small = scene_new();
    scene *big = ground_and_box();
    sheaf_context *probe;
    sheaf_stats st_small, st_big, st;
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    sheaf_ray rays[N_PROBE];
    sheaf_hit before[N_PROBE], after[N_PROBE];
    scene_ground(small, 4.0f);

    probe = built_context(small, big->nt);
    CHECK(probe != NULL);
    CHECK_OK(sheaf_context_stats(probe, &st_small));
    CHECK_OK(scene_set(probe, big));
    CHECK_OK(sheaf_context_build_grid(probe, NULL));
    CHECK_OK(sheaf_context_stats(probe, &st_big));
    sheaf_context_destroy(probe);
    CHECK(st_big.grid_refs > st_small.grid_refs);

    CHECK_OK(sheaf_limits_default(big->nt, &l));
    l.max_grid_refs = st_small.grid_refs;
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(scene_set(ctx, small));
    CHECK_OK(sheaf_context_build_grid(ctx, NULL));
    probe_rays(rays);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, before, N_PROBE));
    CHECK_OK(scene_set(ctx, big));
    CHECK_STATUS(sheaf_context_build_grid(ctx, NULL), SHEAF_STATUS_CAPACITY_GRID_REFS);
    CHECK(last_error_contains(ctx, "'grid_refs'"));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, after, N_PROBE));
    CHECK(hits_equal(before, after, N_PROBE));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.triangles_in == 2 && st.grid_refs == st_small.grid_refs); /* stats of the kept grid */
    sheaf_context_destroy(ctx);
    free(small);
    free(big);
    return true;
}

static bool test_capacity_grid_cells_and_fit(void) {
    scene *s = ground_and_box();
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    sheaf_grid_params p;
    sheaf_stats st;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    l.max_grid_cells = 8;
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(scene_set(ctx, s));
    CHECK_STATUS(sheaf_context_build_grid(ctx, NULL), SHEAF_STATUS_CAPACITY_GRID_CELLS);
    CHECK(last_error_contains(ctx, "'grid_cells'"));
    CHECK_OK(sheaf_grid_params_default(&p));
    p.fit = true;
    CHECK_OK(sheaf_context_build_grid(ctx, &p));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.grid_cells <= 8 && st.lambda < 5.0f && st.triangles == 14);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

/* ---- build parameters ------------------------------------------------------ */

static bool test_build_params(void) {
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_grid_params p, bad;
    sheaf_stats a, b;
    sheaf_ray rays[N_PROBE];
    sheaf_hit mt[N_PROBE], wt[N_PROBE];
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_context_stats(ctx, &a)); /* built with NULL params */
    CHECK_OK(sheaf_grid_params_default(&p));
    CHECK_OK(sheaf_context_build_grid(ctx, &p));
    CHECK_OK(sheaf_context_stats(ctx, &b));
    CHECK(a.grid_res[0] == b.grid_res[0] && a.grid_res[1] == b.grid_res[1] && a.grid_res[2] == b.grid_res[2]);
    CHECK(a.grid_refs == b.grid_refs && a.macrocell == b.macrocell && b.test == SHEAF_TRI_TEST_MOLLER_TRUMBORE);
    bad = p;
    bad.lambda = NAN;
    CHECK_STATUS(sheaf_context_build_grid(ctx, &bad), SHEAF_STATUS_INVALID_ARGUMENT);
    bad.lambda = 0.0f;
    CHECK_STATUS(sheaf_context_build_grid(ctx, &bad), SHEAF_STATUS_INVALID_ARGUMENT);
    bad.lambda = -1.0f;
    CHECK_STATUS(sheaf_context_build_grid(ctx, &bad), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = p;
    bad.macrocell = 1000;
    CHECK_STATUS(sheaf_context_build_grid(ctx, &bad), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = p;
    bad.test = (sheaf_tri_test)7;
    CHECK_STATUS(sheaf_context_build_grid(ctx, &bad), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(last_error_contains(ctx, "sheaf_tri_test"));
    CHECK_STATUS(sheaf_context_build_grid(NULL, &p), SHEAF_STATUS_NULL_POINTER);
    /* watertight: same nearest triangles on these rays */
    probe_rays(rays);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, mt, N_PROBE));
    p.test = SHEAF_TRI_TEST_WATERTIGHT;
    CHECK_OK(sheaf_context_build_grid(ctx, &p));
    CHECK_OK(sheaf_context_stats(ctx, &b));
    CHECK(b.test == SHEAF_TRI_TEST_WATERTIGHT);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, wt, N_PROBE));
    CHECK(mt[0].prim == wt[0].prim && mt[2].prim == wt[2].prim && mt[4].prim == wt[4].prim);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

/* ---- trace and occluded ---------------------------------------------------- */

static bool test_trace_results(void) {
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_ray rays[N_PROBE];
    sheaf_hit h[N_PROBE];
    CHECK(ctx != NULL);
    probe_rays(rays);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, h, N_PROBE));
    CHECK(h[0].prim == 0 && fabsf(h[0].t - 5.0f) < 1e-5f);
    CHECK(h[1].prim == 1 && fabsf(h[1].t - 5.0f) < 1e-5f);
    CHECK((h[2].prim == 4 || h[2].prim == 5) && fabsf(h[2].t - 4.0f) < 1e-5f); /* box top (+z) */
    CHECK(h[3].prim == SHEAF_INVALID_ID && isinf(h[3].t) && h[3].u == 0.0f && h[3].v == 0.0f);
    CHECK((h[4].prim == 10 || h[4].prim == 11) && fabsf(h[4].t - 2.5f) < 1e-5f); /* box side -x */
    CHECK(h[5].prim == SHEAF_INVALID_ID);
    CHECK(h[6].prim == SHEAF_INVALID_ID);
    CHECK(h[7].prim != SHEAF_INVALID_ID);
    CHECK(h[0].u >= 0.0f && h[0].v >= 0.0f && h[0].u + h[0].v <= 1.0f);
    {
        /* Coherent grid traversal returns the 3DDDA's hits bit for bit. */
        sheaf_hit c[N_PROBE];
        int i;
        CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_CGT, rays, c, N_PROBE));
        for (i = 0; i < N_PROBE; i++) {
            CHECK(c[i].prim == h[i].prim && memcmp(&c[i].t, &h[i].t, sizeof(float)) == 0);
        }
    }
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_trace_bad_arguments(void) {
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_ray rays[N_PROBE];
    sheaf_hit hits[N_PROBE], sentinel[N_PROBE];
    unsigned char raw[sizeof(sheaf_ray) * N_PROBE + 64];
    sheaf_ray *unaligned_rays = (sheaf_ray *)(void *)(raw + 1);
    sheaf_hit ok_hits[N_PROBE];
    CHECK(ctx != NULL);
    probe_rays(rays);
    memset(hits, 0xAB, sizeof hits);
    memcpy(sentinel, hits, sizeof hits);
    CHECK_STATUS(sheaf_context_trace(NULL, SHEAF_METHOD_GRID_DDA, rays, hits, N_PROBE), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, NULL, hits, N_PROBE), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, NULL, N_PROBE), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace(ctx, (sheaf_method)99, rays, hits, N_PROBE), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(last_error_contains(ctx, "unknown sheaf_method"));
    CHECK_STATUS(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, hits, (size_t)-1),
                 SHEAF_STATUS_INVALID_ARGUMENT); /* count * 32 overflows */
    CHECK_STATUS(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, (sheaf_hit *)(void *)rays, N_PROBE),
                 SHEAF_STATUS_INVALID_ARGUMENT); /* overlapping */
    CHECK(last_error_contains(ctx, "overlap"));
    CHECK(memcmp(hits, sentinel, sizeof hits) == 0); /* nothing written on error */
    /* count 0: any pointers, nothing written */
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, NULL, NULL, 0));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, hits, 0));
    CHECK(memcmp(hits, sentinel, sizeof hits) == 0);
    /* unaligned arrays are fine and give the same hits */
    memcpy(unaligned_rays, rays, sizeof rays);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, ok_hits, N_PROBE));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, unaligned_rays, hits, N_PROBE));
    CHECK(hits_equal(hits, ok_hits, N_PROBE));
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_occluded(void) {
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_ray rays[5];
    uint8_t occ[5], sentinel[5] = {7, 7, 7, 7, 7};
    CHECK(ctx != NULL);
    rays[0] = make_ray(-3.0f, 0.0f, 0.5f, 6.0f, 0.0f, 0.0f, 0.0f, 1.0f);  /* through the box */
    rays[1] = make_ray(-3.0f, 3.0f, 0.5f, 6.0f, 0.0f, 0.0f, 0.0f, 1.0f);  /* beside it */
    rays[2] = make_ray(-3.0f, 0.0f, 0.5f, 6.0f, 0.0f, 0.0f, 0.0f, 0.4f);  /* stops before it */
    rays[3] = make_ray(2.0f, -1.0f, 0.5f, 0.0f, 0.0f, -1.0f, 0.0f, 0.49f); /* ends above the ground */
    rays[4] = make_ray(2.0f, -1.0f, 0.5f, 0.0f, 0.0f, -1.0f, 0.0f, 0.6f); /* passes the ground */
    CHECK_OK(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_DDA, rays, occ, 5));
    CHECK(occ[0] == 1 && occ[1] == 0 && occ[2] == 0 && occ[3] == 0 && occ[4] == 1);
    memcpy(occ, sentinel, sizeof occ);
    CHECK_OK(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_CGT, rays, occ, 5));
    CHECK(occ[0] == 1 && occ[1] == 0 && occ[2] == 0 && occ[3] == 0 && occ[4] == 1);
    memcpy(occ, sentinel, sizeof occ);
    CHECK_STATUS(sheaf_context_occluded(NULL, SHEAF_METHOD_GRID_DDA, rays, occ, 5), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_DDA, NULL, occ, 5), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_DDA, rays, NULL, 5), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_occluded(ctx, (sheaf_method)77, rays, occ, 5), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_DDA, rays, occ, (size_t)-1 / 4),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_DDA, rays, (uint8_t *)rays + 3, 5),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(memcmp(occ, sentinel, sizeof occ) == 0);
    CHECK_OK(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_DDA, NULL, NULL, 0));
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

/* trace and occluded do not touch the stats (they may run concurrently). */
static bool test_trace_leaves_stats(void) {
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_stats a, b;
    sheaf_ray rays[N_PROBE];
    sheaf_hit hits[N_PROBE];
    uint8_t occ[N_PROBE];
    CHECK(ctx != NULL);
    probe_rays(rays);
    CHECK_OK(sheaf_context_stats(ctx, &a));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, hits, N_PROBE));
    CHECK_OK(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_DDA, rays, occ, N_PROBE));
    CHECK_OK(sheaf_context_stats(ctx, &b));
    CHECK(memcmp(&a, &b, sizeof a) == 0);
    CHECK(a.build_ns > 0 && a.triangles == 14 && a.grid_cells == (uint64_t)a.grid_res[0] * a.grid_res[1] * a.grid_res[2]);
    CHECK_STATUS(sheaf_context_stats(NULL, &a), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_stats(ctx, NULL), SHEAF_STATUS_NULL_POINTER);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

/* ---- render ------------------------------------------------------------------ */

#define RW 64
#define RH 48
#define RSTRIDE (RW * 4 + 12)
#define RLEN ((RH - 1) * RSTRIDE + RW * 4)

static bool test_trace_params(void) {
    /* Every packet side and switch of sheaf_trace_params gives the 3DDDA's
       hits bit for bit, its occlusion, and the same image; bad params are
       rejected and write nothing. */
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_ray rays[N_PROBE];
    sheaf_hit want[N_PROBE], got[N_PROBE];
    uint8_t occ_want[N_PROBE], occ_got[N_PROBE];
    sheaf_trace_params dda, cgt, bad;
    sheaf_frame f = default_frame(RW, RH);
    static uint8_t base[RLEN], img[RLEN];
    uint32_t sides[5] = {2, 4, 8, 16, 32};
    int i, k;
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_trace_params_default(&cgt));
    CHECK(cgt.method == SHEAF_METHOD_GRID_CGT && cgt.packet == 8 && cgt.mailbox && cgt.culling && cgt.macrocells);
    dda = cgt;
    dda.method = SHEAF_METHOD_GRID_DDA;
    probe_rays(rays);
    CHECK_OK(sheaf_context_trace_with(ctx, &dda, rays, want, N_PROBE));
    CHECK_OK(sheaf_context_render_with(ctx, &dda, &dda, &f, base, RSTRIDE, RLEN));
    CHECK_OK(sheaf_context_occluded(ctx, SHEAF_METHOD_GRID_DDA, rays, occ_want, N_PROBE));
    for (k = 0; k < 5; k++) {
        cgt.packet = sides[k];
        cgt.culling = (k % 2) == 0;
        CHECK_OK(sheaf_context_trace_with(ctx, &cgt, rays, got, N_PROBE));
        for (i = 0; i < N_PROBE; i++) {
            CHECK(got[i].prim == want[i].prim && memcmp(&got[i].t, &want[i].t, sizeof(float)) == 0);
        }
        memset(occ_got, 7, sizeof occ_got);
        CHECK_OK(sheaf_context_occluded_with(ctx, &cgt, rays, occ_got, N_PROBE));
        CHECK(memcmp(occ_got, occ_want, sizeof occ_want) == 0);
        memset(img, 0, sizeof img);
        CHECK_OK(sheaf_context_render_with(ctx, &cgt, &cgt, &f, img, RSTRIDE, RLEN));
        CHECK(memcmp(img, base, RLEN) == 0);
    }
    bad = cgt;
    bad.packet = 3;
    CHECK_STATUS(sheaf_context_trace_with(ctx, &bad, rays, got, N_PROBE), SHEAF_STATUS_INVALID_ARGUMENT);
    memset(occ_got, 7, sizeof occ_got);
    CHECK_STATUS(sheaf_context_occluded_with(ctx, &bad, rays, occ_got, N_PROBE), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_occluded_with(ctx, NULL, rays, occ_got, N_PROBE), SHEAF_STATUS_NULL_POINTER);
    for (i = 0; i < N_PROBE; i++) CHECK(occ_got[i] == 7);
    CHECK_STATUS(sheaf_context_render_with(ctx, &cgt, &bad, &f, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = cgt;
    bad.method = (sheaf_method)77;
    CHECK_STATUS(sheaf_context_trace_with(ctx, &bad, rays, got, N_PROBE), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_trace_with(ctx, NULL, rays, got, N_PROBE), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_render_with(ctx, &cgt, NULL, &f, img, RSTRIDE, RLEN), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS((sheaf_trace_params_default)(NULL, sizeof(sheaf_trace_params)), SHEAF_STATUS_NULL_POINTER);
    {
        /* 32 x 32 packets used some of each slot's scratch, never more. */
        sheaf_limits l;
        size_t used = 0, per_slot = 0;
        CHECK_OK(sheaf_limits_default(s->nt, &l));
        CHECK_OK(sheaf_context_scratch_high_water(ctx, &used));
        CHECK_OK(sheaf_slot_scratch_bytes(&l, &per_slot));
        CHECK(used > 0 && used <= per_slot);
        CHECK_STATUS(sheaf_context_scratch_high_water(ctx, NULL), SHEAF_STATUS_NULL_POINTER);
    }
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_bvh_methods(void) {
    /* The BVH next to the grid in one context: every BVH method and packet
       side gives the BVH single ray's hits bit for bit, the same occlusion
       and the same image; the BVH's image equals the grid's. */
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_ray rays[N_PROBE];
    sheaf_hit want[N_PROBE], got[N_PROBE];
    uint8_t occ_want[N_PROBE], occ_got[N_PROBE];
    sheaf_trace_params p, single;
    sheaf_bvh_params bp, bad_bp;
    sheaf_stats st;
    sheaf_frame f = default_frame(RW, RH);
    static uint8_t grid_img[RLEN], base[RLEN], img[RLEN];
    uint32_t sides[4] = {4, 8, 16, 32};
    sheaf_method methods[7] = {SHEAF_METHOD_BVH_SIMD,      SHEAF_METHOD_BVH_MASKED, SHEAF_METHOD_BVH_RANGED,
                               SHEAF_METHOD_BVH_PARTITION, SHEAF_METHOD_BVH_WIDE,   SHEAF_METHOD_BVH_WIDE_RANGED,
                               SHEAF_METHOD_BVH_FRUSTUM};
    int i, k, m;
    CHECK(ctx != NULL);
    probe_rays(rays);
    /* not built yet */
    CHECK_STATUS(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, rays, got, N_PROBE), SHEAF_STATUS_NOT_BUILT);
    CHECK_STATUS(sheaf_context_refit_bvh(ctx, NULL, NULL), SHEAF_STATUS_NOT_BUILT);
    CHECK_OK(sheaf_bvh_params_default(&bp));
    CHECK(bp.leaf_size == 4 && bp.bins == 16 && bp.test == SHEAF_TRI_TEST_MOLLER_TRUMBORE);
    bad_bp = bp;
    bad_bp.bins = 1;
    CHECK_STATUS(sheaf_context_build_bvh(ctx, &bad_bp), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_OK(sheaf_context_build_bvh(ctx, &bp));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.bvh_triangles == s->nt && st.bvh_nodes >= 1 && st.bvh_leaves >= 1 && st.bvh_build_ns > 0);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, rays, want, N_PROBE));
    CHECK_OK(sheaf_context_occluded(ctx, SHEAF_METHOD_BVH_SINGLE, rays, occ_want, N_PROBE));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, got, N_PROBE));
    CHECK(hits_equal(got, want, N_PROBE)); /* same triangle test: the grid's answers */
    {
        /* Refit to the same vertices: the same answers; bad params refused. */
        sheaf_refit_params rp;
        sheaf_refit_info ri;
        CHECK_OK(sheaf_refit_params_default(&rp));
        CHECK(rp.rebuild_above == 0.0f);
        CHECK_OK(sheaf_context_refit_bvh(ctx, &rp, &ri));
        CHECK(ri.rebuilt == 0 && ri.sah_after > 0.0f && ri.newly_traceable == 0);
        CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, rays, got, N_PROBE));
        CHECK(hits_equal(got, want, N_PROBE));
        rp.rebuild_above = 0.5f;
        CHECK_STATUS(sheaf_context_refit_bvh(ctx, &rp, &ri), SHEAF_STATUS_INVALID_ARGUMENT);
        CHECK_OK(sheaf_context_refit_bvh(ctx, NULL, NULL));
        CHECK_STATUS(sheaf_context_refit_bvh(NULL, NULL, NULL), SHEAF_STATUS_NULL_POINTER);
        CHECK_STATUS((sheaf_refit_params_default)(NULL, sizeof(sheaf_refit_params)), SHEAF_STATUS_NULL_POINTER);
    }
    CHECK_OK(sheaf_trace_params_default(&single));
    single.method = SHEAF_METHOD_BVH_SINGLE;
    CHECK_OK(sheaf_context_render_with(ctx, &single, &single, &f, base, RSTRIDE, RLEN));
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, grid_img, RSTRIDE, RLEN));
    CHECK(memcmp(grid_img, base, RLEN) == 0);
    for (m = 0; m < 7; m++) {
        for (k = 0; k < 4; k++) {
            p = single;
            p.method = methods[m];
            p.packet = sides[k];
            p.culling = (k % 2) == 0;
            p.ray_kind = SHEAF_RAY_KIND_AUTO;
            CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, got, N_PROBE));
            for (i = 0; i < N_PROBE; i++) {
                CHECK(got[i].prim == want[i].prim && memcmp(&got[i].t, &want[i].t, sizeof(float)) == 0);
            }
            CHECK_OK(sheaf_context_occluded(ctx, methods[m], rays, occ_got, N_PROBE));
            CHECK(memcmp(occ_got, occ_want, N_PROBE) == 0);
            memset(img, 0, sizeof img);
            CHECK_OK(sheaf_context_render_with(ctx, &p, &p, &f, img, RSTRIDE, RLEN));
            CHECK(memcmp(img, base, RLEN) == 0);
        }
    }
    p.ray_kind = 9;
    CHECK_STATUS(sheaf_context_trace_with(ctx, &p, rays, got, N_PROBE), SHEAF_STATUS_INVALID_ARGUMENT);
    /* The fast (LOW, Morton) build: another tree, the same answers from
       every method; an unknown quality is refused and keeps the tree. */
    CHECK(bp.quality == SHEAF_BUILD_QUALITY_MEDIUM);
    bad_bp = bp;
    bad_bp.quality = 7;
    CHECK_STATUS(sheaf_context_build_bvh(ctx, &bad_bp), SHEAF_STATUS_INVALID_ARGUMENT);
    bp.quality = SHEAF_BUILD_QUALITY_LOW;
    /* presplit: 0 (default) or 1 (this context has no reserve to split
       into, so the tree is the same); anything else is refused. */
    CHECK(bp.presplit == 0);
    bad_bp = bp;
    bad_bp.presplit = 2;
    CHECK_STATUS(sheaf_context_build_bvh(ctx, &bad_bp), SHEAF_STATUS_INVALID_ARGUMENT);
    bp.presplit = 1;
    CHECK_OK(sheaf_context_build_bvh(ctx, &bp));
    for (m = 0; m < 7; m++) {
        p = single;
        p.method = methods[m];
        p.packet = sides[m % 4];
        CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, got, N_PROBE));
        CHECK(hits_equal(got, want, N_PROBE));
        CHECK_OK(sheaf_context_occluded(ctx, methods[m], rays, occ_got, N_PROBE));
        CHECK(memcmp(occ_got, occ_want, N_PROBE) == 0);
    }
    /* Width: 4 (the default) or 2 (no wide tree: BVH_WIDE walks the binary
       one, with the same answers); anything else is refused. */
    CHECK(bp.width == 4);
    bad_bp = bp;
    bad_bp.width = 8;
    CHECK_STATUS(sheaf_context_build_bvh(ctx, &bad_bp), SHEAF_STATUS_INVALID_ARGUMENT);
    bad_bp.width = 0; /* zero-filled: the default */
    CHECK_OK(sheaf_context_build_bvh(ctx, &bad_bp));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_WIDE, rays, got, N_PROBE));
    CHECK(hits_equal(got, want, N_PROBE));
    bp.width = 2;
    CHECK_OK(sheaf_context_build_bvh(ctx, &bp));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_WIDE, rays, got, N_PROBE));
    CHECK(hits_equal(got, want, N_PROBE));
    CHECK_OK(sheaf_context_occluded(ctx, SHEAF_METHOD_BVH_WIDE, rays, occ_got, N_PROBE));
    CHECK(memcmp(occ_got, occ_want, N_PROBE) == 0);
    CHECK_STATUS((sheaf_bvh_params_default)(NULL, sizeof(sheaf_bvh_params)), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_build_bvh(NULL, &bp), SHEAF_STATUS_NULL_POINTER);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

/* ---- ray streams ----------------------------------------------------------- */

#define N_STREAM 37 /* ends inside a quad and inside a 4x4 packet */

/* One ray per element of an array of structs: the interleaved layout. */
typedef struct {
    float ox, oy, oz, dx, dy, dz, tmin, tmax;
} aos_ray;
typedef struct {
    float t, u, v;
    uint32_t prim;
} aos_hit;

static bool test_streams(void) {
    /* Rays as structures of arrays, packed (stride 4) and interleaved
       (stride 32), give sheaf_context_trace_with's hits and
       sheaf_context_occluded_with's answers bit for bit; every bad input
       is refused and writes nothing. */
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_ray probe[N_PROBE], rays[N_STREAM];
    sheaf_hit want[N_STREAM];
    uint8_t occ_want[N_STREAM], occ[N_STREAM];
    static float col[8][N_STREAM];
    static aos_ray ar[N_STREAM];
    static aos_hit ah[N_STREAM];
    float t[N_STREAM], u[N_STREAM], v[N_STREAM];
    uint32_t prim[N_STREAM], geom[N_STREAM];
    sheaf_ray_stream rs, ri, bad;
    sheaf_hit_stream hs, hi, badh;
    sheaf_trace_params p;
    sheaf_method methods[4] = {SHEAF_METHOD_GRID_CGT, SHEAF_METHOD_BVH_SINGLE, SHEAF_METHOD_BVH_RANGED,
                               SHEAF_METHOD_BVH_FRUSTUM};
    static float raw[N_STREAM + 2]; /* 4-byte aligned: raw + 1 or 2 bytes is not */
    int i, m;
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    probe_rays(probe);
    for (i = 0; i < N_STREAM; ++i) {
        rays[i] = probe[i % N_PROBE];
        rays[i].org[0] += 0.01f * (float)(i / N_PROBE);
        col[0][i] = rays[i].org[0];
        col[1][i] = rays[i].org[1];
        col[2][i] = rays[i].org[2];
        col[3][i] = rays[i].dir[0];
        col[4][i] = rays[i].dir[1];
        col[5][i] = rays[i].dir[2];
        col[6][i] = rays[i].tmin;
        col[7][i] = rays[i].tmax;
        ar[i].ox = col[0][i];
        ar[i].oy = col[1][i];
        ar[i].oz = col[2][i];
        ar[i].dx = col[3][i];
        ar[i].dy = col[4][i];
        ar[i].dz = col[5][i];
        ar[i].tmin = col[6][i];
        ar[i].tmax = col[7][i];
    }
    rs.org_x = col[0], rs.org_y = col[1], rs.org_z = col[2];
    rs.dir_x = col[3], rs.dir_y = col[4], rs.dir_z = col[5];
    rs.tmin = col[6], rs.tmax = col[7], rs.stride = sizeof(float);
    ri.org_x = &ar[0].ox, ri.org_y = &ar[0].oy, ri.org_z = &ar[0].oz;
    ri.dir_x = &ar[0].dx, ri.dir_y = &ar[0].dy, ri.dir_z = &ar[0].dz;
    ri.tmin = &ar[0].tmin, ri.tmax = &ar[0].tmax, ri.stride = sizeof(aos_ray);
    hs.t = t, hs.u = u, hs.v = v, hs.prim = prim, hs.geometry = NULL, hs.instance = NULL;
    hs.stride = sizeof(float);
    hi.t = &ah[0].t, hi.u = &ah[0].u, hi.v = &ah[0].v, hi.prim = &ah[0].prim;
    hi.geometry = NULL, hi.instance = NULL, hi.stride = sizeof(aos_hit);
    CHECK_OK(sheaf_trace_params_default(&p));
    for (m = 0; m < 4; ++m) {
        p.method = methods[m];
        p.packet = 4;
        CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, want, N_STREAM));
        CHECK_OK(sheaf_context_occluded_with(ctx, &p, rays, occ_want, N_STREAM));
        CHECK_OK(sheaf_context_trace_stream(ctx, &p, &rs, &hs, N_STREAM));
        CHECK_OK(sheaf_context_trace_stream(ctx, &p, &ri, &hi, N_STREAM));
        for (i = 0; i < N_STREAM; ++i) {
            CHECK(float_bits(t[i]) == float_bits(want[i].t) && prim[i] == want[i].prim);
            CHECK(float_bits(u[i]) == float_bits(want[i].u) && float_bits(v[i]) == float_bits(want[i].v));
            CHECK(float_bits(ah[i].t) == float_bits(want[i].t) && ah[i].prim == want[i].prim);
            CHECK(float_bits(ah[i].u) == float_bits(want[i].u) && float_bits(ah[i].v) == float_bits(want[i].v));
        }
        memset(occ, 7, sizeof occ);
        CHECK_OK(sheaf_context_occluded_stream(ctx, &p, &rs, occ, N_STREAM));
        CHECK(memcmp(occ, occ_want, sizeof occ) == 0);
        memset(occ, 7, sizeof occ);
        CHECK_OK(sheaf_context_occluded_stream(ctx, &p, &ri, occ, N_STREAM));
        CHECK(memcmp(occ, occ_want, sizeof occ) == 0);
    }
    CHECK(want[2].prim != SHEAF_INVALID_ID && want[3].prim == SHEAF_INVALID_ID);
    /* count 0: NULL arrays allowed, nothing written */
    bad = rs;
    bad.org_x = NULL;
    CHECK_OK(sheaf_context_trace_stream(ctx, &p, &bad, &hs, 0));
    /* bad input: a clear status, nothing written */
    memset(t, 0xAB, sizeof t);
    memset(occ, 7, sizeof occ);
    CHECK_STATUS(sheaf_context_trace_stream(NULL, &p, &rs, &hs, N_STREAM), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace_stream(ctx, NULL, &rs, &hs, N_STREAM), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, NULL, &hs, N_STREAM), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &rs, NULL, N_STREAM), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_occluded_stream(ctx, &p, &rs, NULL, N_STREAM), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &bad, &hs, N_STREAM), SHEAF_STATUS_NULL_POINTER);
    badh = hs;
    badh.prim = NULL;
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &rs, &badh, N_STREAM), SHEAF_STATUS_NULL_POINTER);
    bad = rs;
    bad.tmax = (const float *)(void *)((char *)raw + 1); /* misaligned */
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &bad, &hs, N_STREAM), SHEAF_STATUS_MISALIGNED);
    badh = hs;
    badh.u = (float *)(void *)((char *)raw + 2);
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &rs, &badh, N_STREAM), SHEAF_STATUS_MISALIGNED);
    for (i = 0; i < 3; ++i) {
        size_t strides[3] = {0, 2, 6};
        bad = rs;
        bad.stride = strides[i];
        CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &bad, &hs, N_STREAM), SHEAF_STATUS_INVALID_ARGUMENT);
        CHECK_STATUS(sheaf_context_occluded_stream(ctx, &p, &bad, occ, N_STREAM), SHEAF_STATUS_INVALID_ARGUMENT);
        badh = hs;
        badh.stride = strides[i];
        CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &rs, &badh, N_STREAM), SHEAF_STATUS_INVALID_ARGUMENT);
    }
    bad = rs;
    bad.stride = (SIZE_MAX / 2) & ~(size_t)3; /* a valid stride, but past the address space */
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &bad, &hs, N_STREAM), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &rs, &hs, SIZE_MAX), SHEAF_STATUS_INVALID_ARGUMENT);
    badh = hs;
    badh.t = col[3]; /* an output over an input */
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &rs, &badh, N_STREAM), SHEAF_STATUS_INVALID_ARGUMENT);
    badh = hs;
    badh.v = u; /* two outputs on one array */
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &rs, &badh, N_STREAM), SHEAF_STATUS_INVALID_ARGUMENT);
    badh = hi;
    badh.v = &ah[1].t; /* interleaved, but on another field's elements */
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &rs, &badh, N_STREAM), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_occluded_stream(ctx, &p, &rs, (uint8_t *)col[5], N_STREAM),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    badh = hs;
    badh.geometry = geom; /* a scene hit's field in a single-mesh call */
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &rs, &badh, N_STREAM), SHEAF_STATUS_INVALID_ARGUMENT);
    p.packet = 0;
    CHECK_STATUS(sheaf_context_trace_stream(ctx, &p, &rs, &hs, N_STREAM), SHEAF_STATUS_INVALID_ARGUMENT);
    for (i = 0; i < N_STREAM; ++i) CHECK(float_bits(t[i]) == 0xABABABABu && occ[i] == 7);
    /* the scene calls without a two-level scene */
    p.packet = 4;
    CHECK_STATUS(sheaf_context_trace_scene_stream(ctx, &p, &rs, &hs, N_STREAM, ~0u, 0),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

/* ---- camera packets made in the kernel -------------------------------------- */

#define CAM_W 23
#define CAM_H 19

static bool test_camera(void) {
    /* The camera rays of a pixel rectangle, made by the kernel as packets,
       give sheaf_context_trace_with's hits for sheaf_frame_camera_ray's
       rays bit for bit, per pixel, rows hits_per_row apart with the gaps
       left alone; every bad input is refused and writes nothing. */
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_frame f;
    sheaf_pixel_rect r = {2, 3, 2 + 17, 3 + 13}, bad;
    enum { ROW = 20, LEN = 12 * ROW + 17 };
    static sheaf_ray rays[CAM_W * CAM_H];
    static sheaf_hit want[CAM_W * CAM_H], got[LEN];
    sheaf_trace_params p;
    sheaf_camera cam;
    sheaf_method methods[4] = {SHEAF_METHOD_GRID_CGT, SHEAF_METHOD_BVH_SINGLE, SHEAF_METHOD_BVH_RANGED,
                               SHEAF_METHOD_BVH_FRUSTUM};
    uint32_t sides[3] = {2, 8, 32}, x, y;
    int i, m, k, seen = 0;
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    memset(&f, 0, sizeof f);
    f.camera.eye[0] = 2.5f, f.camera.eye[1] = -3.0f, f.camera.eye[2] = 2.0f;
    f.camera.look_at[2] = 0.4f;
    f.camera.up[2] = 1.0f;
    f.camera.fov_y_deg = 50.0f;
    f.width = CAM_W, f.height = CAM_H;
    cam = f.camera;
    for (y = 0; y < CAM_H; ++y)
        for (x = 0; x < CAM_W; ++x) CHECK_OK(sheaf_frame_camera_ray(&f, x, y, &rays[y * CAM_W + x]));
    CHECK_OK(sheaf_trace_params_default(&p));
    for (m = 0; m < 4; ++m)
        for (k = 0; k < 3; ++k) {
            p.method = methods[m];
            p.packet = sides[k];
            CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, want, CAM_W * CAM_H));
            memset(got, 0xAB, sizeof got);
            CHECK_OK(sheaf_context_trace_camera(ctx, &p, &cam, CAM_W, CAM_H, &r, got, ROW));
            for (y = r.y0; y < r.y1; ++y)
                for (x = r.x0; x < r.x1; ++x) {
                    const sheaf_hit *g = &got[(y - r.y0) * ROW + (x - r.x0)];
                    CHECK(hits_equal(g, &want[y * CAM_W + x], 1));
                    seen += g->prim != SHEAF_INVALID_ID;
                }
            for (y = 0; y + 1 < r.y1 - r.y0; ++y)
                for (x = r.x1 - r.x0; x < ROW; ++x) CHECK(got[y * ROW + x].prim == 0xABABABABu);
        }
    CHECK(seen > 0);
    /* bad input: a clear status, nothing written */
    memset(got, 0xAB, sizeof got);
    CHECK_STATUS(sheaf_context_trace_camera(NULL, &p, &cam, CAM_W, CAM_H, &r, got, ROW),
                 SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace_camera(ctx, NULL, &cam, CAM_W, CAM_H, &r, got, ROW),
                 SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, NULL, CAM_W, CAM_H, &r, got, ROW),
                 SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, &cam, CAM_W, CAM_H, NULL, got, ROW),
                 SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, &cam, CAM_W, CAM_H, &r, NULL, ROW),
                 SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, &cam, CAM_W, CAM_H, &r, got, 16),
                 SHEAF_STATUS_INVALID_ARGUMENT); /* rows narrower than the rectangle */
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, &cam, CAM_W, CAM_H, &r, got, SIZE_MAX / 4),
                 SHEAF_STATUS_INVALID_ARGUMENT); /* a buffer past the address space */
    bad = r, bad.x1 = CAM_W + 1; /* outside the image */
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, &cam, CAM_W, CAM_H, &bad, got, ROW),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    bad = r, bad.y1 = bad.y0; /* empty */
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, &cam, CAM_W, CAM_H, &bad, got, ROW),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, &cam, 0, 0, &r, got, ROW), SHEAF_STATUS_INVALID_ARGUMENT);
    cam.fov_y_deg = NAN;
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, &cam, CAM_W, CAM_H, &r, got, ROW),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    cam = f.camera;
    memcpy(cam.look_at, cam.eye, sizeof cam.eye); /* degenerate: no view direction */
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, &cam, CAM_W, CAM_H, &r, got, ROW),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    cam = f.camera;
    p.packet = 6;
    CHECK_STATUS(sheaf_context_trace_camera(ctx, &p, &cam, CAM_W, CAM_H, &r, got, ROW),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    p.packet = 8;
    CHECK_STATUS(sheaf_context_trace_scene_camera(ctx, &p, &cam, CAM_W, CAM_H, &r, NULL, ROW, ~0u, 0),
                 SHEAF_STATUS_NULL_POINTER);
    for (i = 0; i < LEN; ++i) CHECK(got[i].prim == 0xABABABABu);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_kd_methods(void) {
    /* The kd-tree next to the grid and the BVH: kd SIMD and kd packets of
       every side, from the root and from MLRTA and AEPSA entry points, give
       the kd single ray's hits bit for bit and its occlusion; so do BVH
       packets from entry points; bad kd parameters and entry values are
       rejected. */
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_ray rays[N_PROBE];
    sheaf_hit want[N_PROBE], got[N_PROBE];
    uint8_t occ_want[N_PROBE], occ_got[N_PROBE];
    sheaf_trace_params p;
    sheaf_kd_params kp, bad_kp;
    sheaf_stats st;
    uint32_t sides[4] = {4, 8, 16, 32};
    sheaf_entry_search entries[3] = {SHEAF_ENTRY_SEARCH_NONE, SHEAF_ENTRY_SEARCH_MLRTA, SHEAF_ENTRY_SEARCH_AEPSA};
    int i, k, e;
    CHECK(ctx != NULL);
    probe_rays(rays);
    CHECK_STATUS(sheaf_context_trace(ctx, SHEAF_METHOD_KD_SINGLE, rays, got, N_PROBE), SHEAF_STATUS_NOT_BUILT);
    CHECK_OK(sheaf_kd_params_default(&kp));
    CHECK(kp.max_depth == 0 && kp.test == SHEAF_TRI_TEST_MOLLER_TRUMBORE);
    bad_kp = kp;
    bad_kp.empty_bonus = 1.0f;
    CHECK_STATUS(sheaf_context_build_kd(ctx, &bad_kp), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_OK(sheaf_context_build_kd(ctx, &kp));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.kd_triangles == s->nt && st.kd_leaves >= 1 && st.kd_nodes == 2 * st.kd_leaves - 1 && st.kd_build_ns > 0);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_KD_SINGLE, rays, want, N_PROBE));
    CHECK_OK(sheaf_context_occluded(ctx, SHEAF_METHOD_KD_SINGLE, rays, occ_want, N_PROBE));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_KD_SIMD, rays, got, N_PROBE));
    CHECK(hits_equal(got, want, N_PROBE));
    for (e = 0; e < 3; e++) {
        for (k = 0; k < 4; k++) {
            CHECK_OK(sheaf_trace_params_default(&p));
            p.method = (k == 3 && e > 0) ? SHEAF_METHOD_BVH_RANGED : SHEAF_METHOD_KD_PACKET;
            p.packet = sides[k];
            p.entry = entries[e];
            p.culling = (k % 2) == 0;
            CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, got, N_PROBE));
            for (i = 0; i < N_PROBE; i++) {
                CHECK(got[i].prim == want[i].prim && memcmp(&got[i].t, &want[i].t, sizeof(float)) == 0);
            }
            CHECK_OK(sheaf_context_occluded(ctx, p.method, rays, occ_got, N_PROBE));
            CHECK(memcmp(occ_got, occ_want, N_PROBE) == 0);
        }
    }
    p.entry = 3;
    CHECK_STATUS(sheaf_context_trace_with(ctx, &p, rays, got, N_PROBE), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS((sheaf_kd_params_default)(NULL, sizeof(sheaf_kd_params)), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_build_kd(NULL, &kp), SHEAF_STATUS_NULL_POINTER);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_whitted(void) {
    /* A mirror ground and a glass box: the Whitted image is the same for the
       grid's single ray, CGT packets, and every BVH method; bad materials
       and bounce limits are rejected and leave the framebuffer alone. */
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_trace_params single, p, sec;
    sheaf_whitted_params wp;
    sheaf_material mats[2] = {{{0.6f, 0.6f, 0.6f}, 0.5f, 0.0f, 1.0f}, {{0.9f, 0.8f, 0.7f}, 0.1f, 0.7f, 1.5f}};
    sheaf_material_range ranges[2] = {{0, 0}, {2, 1}}; /* ground: triangles 0-1 */
    sheaf_light lights[2];
    sheaf_frame f = default_frame(RW, RH);
    static uint8_t base[RLEN], img[RLEN], plain[RLEN];
    sheaf_method methods[8] = {SHEAF_METHOD_GRID_CGT,      SHEAF_METHOD_BVH_SIMD, SHEAF_METHOD_BVH_MASKED,
                               SHEAF_METHOD_BVH_RANGED,    SHEAF_METHOD_BVH_PARTITION,
                               SHEAF_METHOD_BVH_WIDE,      SHEAF_METHOD_BVH_WIDE_RANGED,
                               SHEAF_METHOD_BVH_FRUSTUM};
    int m;
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_whitted_params_default(&wp));
    CHECK(wp.max_reflect == 2 && wp.max_refract == 2);
    lights[0] = f.light;
    lights[1] = f.light;
    lights[1].position[0] += 3.0f;
    lights[1].color[1] = 0.5f;
    CHECK_OK(sheaf_trace_params_default(&single));
    single.method = SHEAF_METHOD_GRID_DDA;
    CHECK_OK(sheaf_context_render_whitted(ctx, &single, &single, &single, &wp, &f, lights, 2, mats, 2, ranges, 2, base,
                                          RSTRIDE, RLEN));
    /* no secondary materials and one light: the plain image */
    CHECK_OK(sheaf_context_render_whitted(ctx, &single, &single, &single, NULL, &f, NULL, 0, NULL, 0, NULL, 0, img,
                                          RSTRIDE, RLEN));
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, plain, RSTRIDE, RLEN));
    CHECK(memcmp(img, plain, RLEN) == 0);
    CHECK(memcmp(base, plain, RLEN) != 0);
    for (m = 0; m < 8; m++) {
        p = single;
        p.method = methods[m];
        p.packet = 16;
        p.ray_kind = SHEAF_RAY_KIND_AUTO;
        sec = p;
        if (methods[m] == SHEAF_METHOD_BVH_RANGED) sec.method = SHEAF_METHOD_BVH_PARTITION;
        memset(img, 0, sizeof img);
        CHECK_OK(sheaf_context_render_whitted(ctx, &p, &p, &sec, &wp, &f, lights, 2, mats, 2, ranges, 2, img, RSTRIDE,
                                              RLEN));
        CHECK(memcmp(img, base, RLEN) == 0);
    }
    memset(img, 0xAB, sizeof img);
    mats[1].reflect = 0.5f; /* reflect + transmit > 1 */
    CHECK_STATUS(sheaf_context_render_whitted(ctx, &p, &p, &p, &wp, &f, lights, 2, mats, 2, ranges, 2, img, RSTRIDE,
                                              RLEN),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    mats[1].reflect = 0.1f;
    ranges[1].material = 7; /* no such material */
    CHECK_STATUS(sheaf_context_render_whitted(ctx, &p, &p, &p, &wp, &f, lights, 2, mats, 2, ranges, 2, img, RSTRIDE,
                                              RLEN),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    ranges[1].material = 1;
    wp.max_reflect = 9;
    CHECK_STATUS(sheaf_context_render_whitted(ctx, &p, &p, &p, &wp, &f, lights, 2, mats, 2, ranges, 2, img, RSTRIDE,
                                              RLEN),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_render_whitted(ctx, &p, &p, &p, NULL, &f, NULL, 2, mats, 2, ranges, 2, img, RSTRIDE, RLEN),
                 SHEAF_STATUS_NULL_POINTER);
    CHECK(img[0] == 0xAB && img[RLEN - 1] == 0xAB);
    CHECK_STATUS((sheaf_whitted_params_default)(NULL, sizeof(sheaf_whitted_params)), SHEAF_STATUS_NULL_POINTER);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_render(void) {
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_frame f = default_frame(RW, RH), sky = f, flat = f;
    static uint8_t img[RLEN], again[RLEN], sky_img[RLEN], flat_img[RLEN];
    sheaf_stats st;
    uint32_t x, y, bg = 0, geo = 0;
    CHECK(ctx != NULL);
    memset(img, 0xCD, sizeof img);
    memset(again, 0xCD, sizeof again);
    memset(sky_img, 0xCD, sizeof sky_img);
    memset(flat_img, 0xCD, sizeof flat_img);
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, img, RSTRIDE, RLEN));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.counters.rays >= (uint64_t)RW * RH && st.trace_ns > 0 && st.counters.tri_tests > 0);
    /* deterministic */
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, again, RSTRIDE, RLEN));
    CHECK(memcmp(img, again, RLEN) == 0);
    /* coherent grid traversal renders the same image (and padding stays untouched) */
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_GRID_CGT, &f, again, RSTRIDE, RLEN));
    CHECK(memcmp(img, again, RLEN) == 0);
    for (y = 0; y < RH; ++y) {
        for (x = 0; x < RW; ++x) CHECK(img[y * RSTRIDE + 4 * x + 3] == 255); /* opaque */
        if (y + 1 < RH) {
            for (x = RW * 4; x < RSTRIDE; ++x) CHECK(img[y * RSTRIDE + x] == 0xCD); /* padding untouched */
        }
    }
    /* a camera looking up sees only background: every pixel has its colour */
    sky.camera.look_at[0] = sky.camera.eye[0];
    sky.camera.look_at[1] = sky.camera.eye[1] + 1.0f;
    sky.camera.look_at[2] = sky.camera.eye[2] + 10.0f;
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &sky, sky_img, RSTRIDE, RLEN));
    for (y = 0; y < RH; ++y)
        for (x = 0; x < RW; ++x) CHECK(memcmp(&sky_img[y * RSTRIDE + 4 * x], sky_img, 4) == 0);
    for (y = 0; y < RH; ++y) {
        for (x = 0; x < RW; ++x) {
            if (memcmp(&img[y * RSTRIDE + 4 * x], sky_img, 4) == 0) ++bg; else ++geo;
        }
    }
    CHECK(bg > 0 && geo > RW * RH / 4); /* the scene fills a good part of the view */
    /* shadows off changes the image (the box shadows the ground) */
    flat.shading.shadows = false;
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &flat, flat_img, RSTRIDE, RLEN));
    CHECK(memcmp(img, flat_img, RLEN) != 0); /* same padding: a pixel differs */
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_render_bad_arguments(void) {
    scene *s = ground_and_box();
    sheaf_context *ctx = built_context(s, s->nt);
    sheaf_frame f = default_frame(RW, RH), bad;
    static uint8_t img[RLEN], copy[RLEN];
    CHECK(ctx != NULL);
    memset(img, 0x3C, sizeof img);
    memcpy(copy, img, sizeof img);
    CHECK_STATUS(sheaf_context_render(NULL, SHEAF_METHOD_GRID_DDA, &f, img, RSTRIDE, RLEN), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, NULL, img, RSTRIDE, RLEN), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, NULL, RSTRIDE, RLEN), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_render(ctx, (sheaf_method)77, &f, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    /* buffer one byte short, zero length, stride too small, stride overflowing */
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, img, RSTRIDE, RLEN - 1),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, img, RSTRIDE, 0), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, img, RW * 4 - 1, RLEN),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &f, img, (size_t)-1 / 2, RLEN),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    /* zero-sized image */
    bad = f;
    bad.width = 0;
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &bad, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = f;
    bad.height = 0;
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &bad, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    /* larger than the limits */
    bad = f;
    bad.width = 5000;
    bad.height = 1;
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &bad, img, 5000 * 4, RLEN), SHEAF_STATUS_CAPACITY_IMAGE);
    CHECK(last_error_contains(ctx, "'image'"));
    /* cameras: eye == look_at, NaN, fov out of range, up parallel to the view */
    bad = f;
    memcpy(bad.camera.look_at, bad.camera.eye, sizeof bad.camera.eye);
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &bad, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = f;
    bad.camera.eye[1] = NAN;
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &bad, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = f;
    bad.camera.fov_y_deg = 180.0f;
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &bad, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = f;
    bad.camera.up[0] = bad.camera.look_at[0] - bad.camera.eye[0];
    bad.camera.up[1] = bad.camera.look_at[1] - bad.camera.eye[1];
    bad.camera.up[2] = bad.camera.look_at[2] - bad.camera.eye[2];
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &bad, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(last_error_contains(ctx, "camera"));
    CHECK(memcmp(img, copy, sizeof img) == 0); /* nothing written on error */
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

/* ---- perspective and light grids, deferred frames ------------------------------- */

/* A context over `s` with pools for `structures` and images up to RW x RH
   (the perspective grid's pools scale with the image), geometry set. */
static sheaf_context *pgrid_context(const scene *s, uint32_t structures, uint32_t max_pgrid_cells,
                                    uint32_t max_pgrid_refs) {
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    if (sheaf_limits_default(s->nt, &l) != SHEAF_STATUS_OK) return NULL;
    l.max_image_width = RW;
    l.max_image_height = RH;
    l.structures = structures;
    l.max_pgrid_cells = max_pgrid_cells;
    l.max_pgrid_refs = max_pgrid_refs;
    if (sheaf_context_create(&l, &ctx) != SHEAF_STATUS_OK) return NULL;
    if (scene_set(ctx, s) != SHEAF_STATUS_OK) {
        sheaf_context_destroy(ctx);
        return NULL;
    }
    return ctx;
}

/* The pixels (not the padding) of two RW x RH images are equal. */
static bool same_pixels(const uint8_t *a, const uint8_t *b) {
    uint32_t y;
    for (y = 0; y < RH; ++y) {
        if (memcmp(a + y * RSTRIDE, b + y * RSTRIDE, RW * 4) != 0) return false;
    }
    return true;
}

/* Every pixel of the last deferred frame against single rays through the
   BVH: the camera ray's hit (sheaf_frame_camera_ray, sheaf_context_trace)
   bit for bit, and each light's shadow bit against its shadow ray
   (sheaf_context_deferred_shadow_ray, sheaf_context_occluded). Counts hit
   pixels and shadowed (pixel, light) pairs. */
static bool deferred_pixels_match(const sheaf_context *ctx, const sheaf_frame *f, const sheaf_light *lights,
                                  size_t n_lights, uint32_t *hits, uint32_t *shadowed) {
    uint32_t x, y;
    size_t l;
    *hits = 0;
    *shadowed = 0;
    for (y = 0; y < f->height; ++y) {
        for (x = 0; x < f->width; ++x) {
            sheaf_ray ray, sray;
            sheaf_hit want, got;
            uint8_t bits = 0xEE, occ = 0;
            CHECK_OK(sheaf_frame_camera_ray(f, x, y, &ray));
            CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, &ray, &want, 1));
            CHECK_OK(sheaf_context_deferred_pixel(ctx, x, y, &got, &bits));
            CHECK(got.prim == want.prim && float_bits(got.t) == float_bits(want.t));
            CHECK(got.u == 0.0f && got.v == 0.0f);
            if (got.prim == SHEAF_INVALID_ID) {
                CHECK(bits == 0 && isinf(got.t));
                continue;
            }
            ++*hits;
            CHECK((bits >> n_lights) == 0);
            for (l = 0; l < n_lights; ++l) {
                bool has = false;
                CHECK_OK(sheaf_context_deferred_shadow_ray(ctx, x, y, &lights[l], &sray, &has));
                if (!has) {
                    CHECK(((bits >> l) & 1) == 0);
                    continue;
                }
                CHECK(sray.tmax == 1.0f && memcmp(sray.org, lights[l].position, sizeof sray.org) == 0);
                CHECK_OK(sheaf_context_occluded(ctx, SHEAF_METHOD_BVH_SINGLE, &sray, &occ, 1));
                CHECK(occ == ((bits >> l) & 1));
                *shadowed += occ;
            }
        }
    }
    return true;
}

static bool test_pgrid(void) {
    /* Deferred frames with the perspective grid and light grids: with one
       point light the image equals sheaf_context_render's with BVH single
       rays byte for byte; every pixel's hit and shadow bits equal single
       rays'; the stats hold the phase times and consistent reordering
       counts; two lights (one a spot) give the same image through the grids
       and through traced passes. */
    scene *s = ground_and_box();
    sheaf_context *ctx = pgrid_context(s, SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_PGRID, 0, 0);
    sheaf_pgrid_params pp;
    sheaf_deferred_job job, traced;
    sheaf_trace_params single;
    sheaf_stats st;
    sheaf_light lights[2];
    sheaf_frame f = default_frame(RW, RH);
    static uint8_t base[RLEN], img[RLEN], two[RLEN], two_traced[RLEN];
    uint32_t hits = 0, shadowed = 0;
    uint64_t one_light_rays;
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_pgrid_params_default(&pp));
    CHECK(pp.tile == 8 && pp.group == 2 && pp.slices == 32 && pp.light_tiles == 64 && pp.light_slices == 32);
    CHECK(pp.chunk == 256 && !pp.cull_backfaces && pp.test == SHEAF_TRI_TEST_MOLLER_TRUMBORE);
    CHECK_OK(sheaf_context_build_pgrid(ctx, &pp));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.pgrid_triangles == s->nt && st.pgrid_excluded == 0 && st.pgrid_test == SHEAF_TRI_TEST_MOLLER_TRUMBORE);
    CHECK(st.primary_build_ns == 0 && st.shade_ns == 0 && st.camera_cells == 0); /* no deferred frame yet */

    /* One point light (frame.light): the forward renderer's image. */
    memset(&job, 0, sizeof job);
    job.frame = f;
    job.primary_pgrid = true;
    job.shadow_light_grid = true;
    memset(img, 0x5A, sizeof img);
    CHECK_OK(sheaf_context_render_deferred(ctx, &job, img, RSTRIDE, RLEN));
    CHECK(img[RW * 4] == 0x5A); /* padding untouched */
    CHECK_OK(sheaf_context_stats(ctx, &st)); /* before render_with replaces counters and trace_ns */
    CHECK_OK(sheaf_trace_params_default(&single));
    single.method = SHEAF_METHOD_BVH_SINGLE;
    CHECK_OK(sheaf_context_render_with(ctx, &single, &single, &f, base, RSTRIDE, RLEN));
    CHECK(same_pixels(img, base));
    CHECK(deferred_pixels_match(ctx, &f, &f.light, 1, &hits, &shadowed));
    CHECK(hits > RW * RH / 4 && shadowed > 0 && shadowed < hits); /* the box shadows part of the ground */

    /* Stats: Figure 10's phases, the grids, the reordering. */
    CHECK(st.primary_build_ns > 0 && st.primary_trace_ns > 0 && st.rearrange_ns > 0 && st.shadow_build_ns > 0 &&
          st.shadow_trace_ns > 0 && st.shade_ns > 0);
    CHECK(st.trace_ns == st.primary_build_ns + st.primary_trace_ns + st.rearrange_ns + st.shadow_build_ns +
                             st.shadow_trace_ns + st.shade_ns);
    CHECK(st.hits == hits && st.shadow_rays > 0 && st.shadow_rays <= st.hits);
    CHECK(st.camera_tiles[0] == RW / 8 && st.camera_tiles[1] == RH / 8 && st.camera_slices == 32);
    CHECK(st.camera_cells == st.camera_tiles[0] * st.camera_tiles[1] * st.camera_slices);
    CHECK(st.camera_mapped > 0 && st.camera_mapped <= s->nt && st.camera_refs >= st.camera_mapped);
    CHECK(st.camera_backfaces == 0);
    CHECK(st.light_tiles[0] >= 1 && st.light_tiles[0] <= 64 && st.light_slices == 32);
    CHECK(st.light_cells == st.light_tiles[0] * st.light_tiles[1] * st.light_slices);
    CHECK(st.light_mapped > 0 && st.light_refs >= st.light_mapped);
    CHECK(st.reorder_rays == st.shadow_rays); /* one light */
    CHECK(st.reorder_tiles_used >= 1 && st.reorder_tiles_used <= st.light_tiles[0] * st.light_tiles[1]);
    CHECK(st.reorder_chunks >= st.reorder_tiles_used &&
          st.reorder_chunks <= st.reorder_tiles_used + st.reorder_rays / pp.chunk);
    CHECK(st.reorder_max_tile_rays >= (st.reorder_rays + st.reorder_tiles_used - 1) / st.reorder_tiles_used &&
          st.reorder_max_tile_rays <= st.reorder_rays);
    CHECK(st.counters.rays > 0);
    one_light_rays = st.shadow_rays;

    /* Small chunks: more chunks, the same image. */
    pp.chunk = 16;
    CHECK_OK(sheaf_context_build_pgrid(ctx, &pp));
    CHECK_OK(sheaf_context_render_deferred(ctx, &job, img, RSTRIDE, RLEN));
    CHECK(same_pixels(img, base));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.reorder_chunks >= (st.reorder_rays + 15) / 16 &&
          st.reorder_chunks <= st.reorder_tiles_used + st.reorder_rays / 16);

    /* Two lights, the second a soft-edged spot: grids and traced passes agree. */
    lights[0] = f.light;
    memset(&lights[1], 0, sizeof lights[1]);
    lights[1].position[0] = -3.0f;
    lights[1].position[1] = -2.0f;
    lights[1].position[2] = 6.0f;
    lights[1].color[0] = 0.6f;
    lights[1].color[1] = 0.5f;
    lights[1].color[2] = 0.3f;
    lights[1].spot_direction[0] = 3.0f;
    lights[1].spot_direction[1] = 2.0f;
    lights[1].spot_direction[2] = -6.0f;
    lights[1].spot_angle_deg = 25.0f;
    lights[1].spot_soft_deg = 5.0f;
    job.lights = lights;
    job.light_count = 2;
    CHECK_OK(sheaf_context_render_deferred(ctx, &job, two, RSTRIDE, RLEN));
    CHECK(!same_pixels(two, base)); /* the spot adds light */
    CHECK(deferred_pixels_match(ctx, &f, lights, 2, &hits, &shadowed));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.reorder_rays == st.shadow_rays && st.shadow_rays > one_light_rays); /* the spot adds shadow rays */
    traced = job;
    traced.primary_pgrid = false;
    traced.shadow_light_grid = false;
    sheaf_trace_params traced_shadow = single;
    traced_shadow.method = SHEAF_METHOD_BVH_PARTITION;
    traced_shadow.packet = 8;
    traced.primary = &single;
    traced.shadow = &traced_shadow;
    CHECK_OK(sheaf_context_render_deferred(ctx, &traced, two_traced, RSTRIDE, RLEN));
    CHECK(same_pixels(two, two_traced));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.primary_build_ns == 0 && st.shadow_build_ns == 0 && st.camera_cells == 0 && st.light_cells == 0 &&
          st.reorder_rays == 0 && st.shade_ns > 0);
    /* and the Whitted renderer without materials: the same two lights */
    memset(two_traced, 0, sizeof two_traced);
    CHECK_OK(sheaf_context_render_whitted(ctx, &single, &single, &single, NULL, &f, lights, 2, NULL, 0, NULL, 0,
                                          two_traced, RSTRIDE, RLEN));
    CHECK(same_pixels(two, two_traced));
    /* the camera ray through the grid and traced: mixed passes too */
    traced.primary_pgrid = true;
    CHECK_OK(sheaf_context_render_deferred(ctx, &traced, img, RSTRIDE, RLEN));
    CHECK(same_pixels(img, two));
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_pgrid_bad_arguments(void) {
    /* Every error leaves the framebuffer, the stats and the last frame's
       pixels as they were. */
    scene *s = ground_and_box();
    sheaf_context *ctx = pgrid_context(s, SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_PGRID, 0, 0);
    sheaf_context *plain = built_context(s, s->nt); /* default limits: no SHEAF_STRUCTURE_PGRID */
    sheaf_pgrid_params pp, bad;
    sheaf_deferred_job job, j;
    sheaf_stats st, st2;
    sheaf_light lights[SHEAF_DEFERRED_MAX_LIGHTS + 1];
    sheaf_frame f = default_frame(RW, RH);
    sheaf_hit hit, hit2;
    sheaf_ray ray;
    uint8_t bits = 0, bits2 = 0;
    bool has = true;
    static uint8_t img[RLEN], copy[RLEN];
    size_t i;
    CHECK(ctx != NULL && plain != NULL);
    memset(&job, 0, sizeof job);
    job.frame = f;
    job.primary_pgrid = true;
    job.shadow_light_grid = true;
    for (i = 0; i < SHEAF_DEFERRED_MAX_LIGHTS + 1; ++i) {
        lights[i] = f.light;
        lights[i].position[0] += (float)i;
    }
    memset(img, 0xAB, sizeof img);
    memcpy(copy, img, sizeof img);

    /* Before sheaf_context_build_pgrid: nothing to render or read. */
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &job, img, RSTRIDE, RLEN), SHEAF_STATUS_NOT_BUILT);
    CHECK_STATUS(sheaf_context_deferred_pixel(ctx, 0, 0, &hit, &bits), SHEAF_STATUS_NOT_BUILT);
    CHECK_STATUS(sheaf_context_deferred_shadow_ray(ctx, 0, 0, &f.light, &ray, &has), SHEAF_STATUS_NOT_BUILT);
    /* a traced pass needs its structure */
    j = job;
    j.primary_pgrid = false;
    j.shadow_light_grid = false;
    sheaf_trace_params jp;
    CHECK_OK(sheaf_trace_params_default(&jp));
    jp.method = SHEAF_METHOD_BVH_SINGLE;
    j.primary = &jp;
    j.shadow = &jp;
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_NOT_BUILT);
    CHECK(memcmp(img, copy, sizeof img) == 0);

    /* Parameters. */
    CHECK_STATUS((sheaf_pgrid_params_default)(NULL, sizeof(sheaf_pgrid_params)), SHEAF_STATUS_NULL_POINTER);
    CHECK_OK(sheaf_pgrid_params_default(&pp));
    bad = pp;
    bad.tile = 6;
    CHECK_STATUS(sheaf_context_build_pgrid(ctx, &bad), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = pp;
    bad.chunk = 8;
    CHECK_STATUS(sheaf_context_build_pgrid(ctx, &bad), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = pp;
    bad.light_tiles = 257;
    CHECK_STATUS(sheaf_context_build_pgrid(ctx, &bad), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = pp;
    bad.test = (sheaf_tri_test)9;
    CHECK_STATUS(sheaf_context_build_pgrid(ctx, &bad), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = pp;
    bad.test = SHEAF_TRI_TEST_PROJECTION; /* no projection_test in the limits */
    CHECK_STATUS(sheaf_context_build_pgrid(ctx, &bad), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_pgrid(NULL, &pp), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &job, img, RSTRIDE, RLEN), SHEAF_STATUS_NOT_BUILT);

    /* No pools: a context without SHEAF_STRUCTURE_PGRID. */
    CHECK_STATUS(sheaf_context_build_pgrid(plain, NULL), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(last_error_contains(plain, "PGRID"));
    jp.method = SHEAF_METHOD_GRID_DDA; /* built in `plain` */
    CHECK_STATUS(sheaf_context_render_deferred(plain, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(last_error_contains(plain, "PGRID"));

    /* A good frame, then errors that must not change it. */
    CHECK_OK(sheaf_context_build_pgrid(ctx, NULL)); /* NULL: the defaults */
    CHECK_OK(sheaf_context_render_deferred(ctx, &job, img, RSTRIDE, RLEN));
    memcpy(copy, img, sizeof img);
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK_OK(sheaf_context_deferred_pixel(ctx, RW / 2, RH / 2, &hit, &bits));
    CHECK(hit.prim != SHEAF_INVALID_ID);
    CHECK_STATUS(sheaf_context_render_deferred(ctx, NULL, img, RSTRIDE, RLEN), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_render_deferred(NULL, &job, img, RSTRIDE, RLEN), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &job, NULL, RSTRIDE, RLEN), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &job, img, RSTRIDE, RLEN - 1), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &job, img, RW * 4 - 1, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    j = job;
    j.lights = lights;
    j.light_count = SHEAF_DEFERRED_MAX_LIGHTS + 1; /* 9 lights */
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(last_error_contains(ctx, "8 lights"));
    j.light_count = (size_t)-1;
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    j.lights = NULL;
    j.light_count = 2;
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_NULL_POINTER);
    j.lights = lights;
    lights[1].spot_angle_deg = 95.0f; /* a spot's cone is below 90 degrees */
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    lights[1].spot_angle_deg = 20.0f;
    lights[1].spot_soft_deg = 30.0f; /* soft edge wider than the cone */
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    lights[1].spot_soft_deg = 0.0f;
    lights[1].position[2] = NAN;
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    lights[1].position[2] = f.light.position[2];
    j = job;
    j.primary_pgrid = false;
    jp.method = (sheaf_method)77; /* checked once used */
    j.primary = &jp;
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    j = job;
    j.frame.width = RW + 1; /* beyond the limits */
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_CAPACITY_IMAGE);
    j = job;
    memcpy(j.frame.camera.look_at, j.frame.camera.eye, sizeof j.frame.camera.eye);
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(memcmp(img, copy, sizeof img) == 0); /* nothing written on error */
    CHECK_OK(sheaf_context_stats(ctx, &st2));
    CHECK(memcmp(&st, &st2, sizeof st) == 0); /* stats unchanged */
    CHECK_OK(sheaf_context_deferred_pixel(ctx, RW / 2, RH / 2, &hit2, &bits2));
    CHECK(memcmp(&hit, &hit2, sizeof hit) == 0 && bits == bits2); /* the frame's pixels too */

    /* Pixel queries. */
    hit2.prim = 4242;
    CHECK_STATUS(sheaf_context_deferred_pixel(ctx, RW, 0, &hit2, &bits2), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_deferred_pixel(ctx, 0, RH, &hit2, &bits2), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_deferred_pixel(ctx, 0, 0, NULL, &bits2), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_deferred_pixel(ctx, 0, 0, &hit2, NULL), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_deferred_pixel(NULL, 0, 0, &hit2, &bits2), SHEAF_STATUS_NULL_POINTER);
    CHECK(hit2.prim == 4242);
    CHECK_STATUS(sheaf_context_deferred_shadow_ray(ctx, RW, 0, &f.light, &ray, &has), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_deferred_shadow_ray(ctx, 0, 0, NULL, &ray, &has), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_deferred_shadow_ray(ctx, 0, 0, &f.light, NULL, &has), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_deferred_shadow_ray(ctx, 0, 0, &f.light, &ray, NULL), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_frame_camera_ray(&f, RW, 0, &ray), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_frame_camera_ray(NULL, 0, 0, &ray), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_frame_camera_ray(&f, 0, 0, NULL), SHEAF_STATUS_NULL_POINTER);

    /* A failed frame (after the arguments were checked) leaves no pixels. */
    j = job;
    j.primary_pgrid = false;
    jp.method = SHEAF_METHOD_KD_SINGLE; /* no kd-tree */
    jp.packet = 8;
    j.primary = &jp;
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &j, img, RSTRIDE, RLEN), SHEAF_STATUS_NOT_BUILT);
    CHECK(memcmp(img, copy, sizeof img) == 0);
    sheaf_context_destroy(ctx);
    sheaf_context_destroy(plain);
    free(s);
    return true;
}

static bool test_pgrid_capacity(void) {
    /* Too few perspective grid cells or (triangle, cell) pairs: the
       capacity statuses, with the pool named in the last error. */
    scene *s = ground_and_box();
    sheaf_context *cells = pgrid_context(s, SHEAF_STRUCTURE_PGRID, 100, 0);
    sheaf_context *refs = pgrid_context(s, SHEAF_STRUCTURE_PGRID, 0, 16);
    sheaf_deferred_job job;
    static uint8_t img[RLEN];
    CHECK(cells != NULL && refs != NULL);
    memset(&job, 0, sizeof job);
    job.frame = default_frame(RW, RH);
    job.primary_pgrid = true;
    job.shadow_light_grid = true;
    CHECK_OK(sheaf_context_build_pgrid(cells, NULL));
    CHECK_OK(sheaf_context_build_pgrid(refs, NULL));
    CHECK_STATUS(sheaf_context_render_deferred(cells, &job, img, RSTRIDE, RLEN), SHEAF_STATUS_CAPACITY_PGRID_CELLS);
    CHECK(last_error_contains(cells, "pgrid_cells"));
    CHECK_STATUS(sheaf_context_render_deferred(refs, &job, img, RSTRIDE, RLEN), SHEAF_STATUS_CAPACITY_PGRID_REFS);
    CHECK(last_error_contains(refs, "pgrid_refs"));
    sheaf_context_destroy(cells);
    sheaf_context_destroy(refs);
    free(s);
    return true;
}

/* ---- last error ---------------------------------------------------------------- */

static bool test_last_error_buffer_rules(void) {
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    char buf[SHEAF_ERROR_MESSAGE_MAX], small[5];
    size_t n = 99, full;
    CHECK_OK(sheaf_limits_default(4, &l));
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(sheaf_context_last_error(ctx, buf, sizeof buf, &n));
    CHECK(strcmp(buf, "no error") == 0 && n == 8);
    CHECK_STATUS(sheaf_context_build_grid(ctx, NULL), SHEAF_STATUS_NO_GEOMETRY);
    CHECK_OK(sheaf_context_last_error(ctx, buf, sizeof buf, &full));
    CHECK(strcmp(buf, "no geometry set") == 0 && full == strlen(buf));
    /* truncation: len - 1 bytes and a NUL */
    memset(small, 'x', sizeof small);
    CHECK_OK(sheaf_context_last_error(ctx, small, sizeof small, &n));
    CHECK(n == 4 && small[4] == '\0' && strncmp(small, "no g", 4) == 0);
    CHECK_OK(sheaf_context_last_error(ctx, small, 1, &n));
    CHECK(n == 0 && small[0] == '\0');
    /* bad arguments: statuses, and the recorded error is not replaced */
    n = 42;
    CHECK_STATUS(sheaf_context_last_error(ctx, buf, 0, &n), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_last_error(ctx, NULL, sizeof buf, &n), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_last_error(ctx, buf, sizeof buf, NULL), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_last_error(NULL, buf, sizeof buf, &n), SHEAF_STATUS_NULL_POINTER);
    CHECK(n == 42);
    CHECK(last_error_contains(ctx, "no geometry set"));
    /* a success does not clear it; the next failure replaces it */
    CHECK_OK(sheaf_context_set_geometry(ctx, NULL, 12, 0, NULL, 0));
    CHECK(last_error_contains(ctx, "no geometry set"));
    CHECK_STATUS(sheaf_context_set_geometry(ctx, NULL, 12, 3, NULL, 0), SHEAF_STATUS_NULL_POINTER);
    CHECK(last_error_contains(ctx, "NULL"));
    sheaf_context_destroy(ctx);
    return true;
}

int main(void) {
    int passed = 0, failed = 0;
    run_test("test_status_codes_and_strings", test_status_codes_and_strings, &passed, &failed);
    run_test("test_version", test_version, &passed, &failed);
    run_test("test_defaults", test_defaults, &passed, &failed);
    run_test("test_required_bytes", test_required_bytes, &passed, &failed);
    run_test("test_create_destroy", test_create_destroy, &passed, &failed);
    run_test("test_create_in_exact_size", test_create_in_exact_size, &passed, &failed);
    run_test("test_create_in_bad_buffers", test_create_in_bad_buffers, &passed, &failed);
    run_test("test_create_in_stale_handle", test_create_in_stale_handle, &passed, &failed);
    run_test("test_set_geometry_bad_arguments", test_set_geometry_bad_arguments, &passed, &failed);
    run_test("test_state_errors", test_state_errors, &passed, &failed);
    run_test("test_index_out_of_range_keeps_previous_geometry", test_index_out_of_range_keeps_previous_geometry,
             &passed, &failed);
    run_test("test_nan_and_degenerate_triangles_are_excluded", test_nan_and_degenerate_triangles_are_excluded,
             &passed, &failed);
    run_test("test_capacity_triangles_and_vertices", test_capacity_triangles_and_vertices, &passed, &failed);
    run_test("test_capacity_grid_refs_keeps_previous_grid", test_capacity_grid_refs_keeps_previous_grid, &passed,
             &failed);
    run_test("test_capacity_grid_cells_and_fit", test_capacity_grid_cells_and_fit, &passed, &failed);
    run_test("test_build_params", test_build_params, &passed, &failed);
    run_test("test_trace_results", test_trace_results, &passed, &failed);
    run_test("test_trace_bad_arguments", test_trace_bad_arguments, &passed, &failed);
    run_test("test_occluded", test_occluded, &passed, &failed);
    run_test("test_trace_leaves_stats", test_trace_leaves_stats, &passed, &failed);
    run_test("test_render", test_render, &passed, &failed);
    run_test("test_bvh_methods", test_bvh_methods, &passed, &failed);
    run_test("test_streams", test_streams, &passed, &failed);
    run_test("test_camera", test_camera, &passed, &failed);
    run_test("test_kd_methods", test_kd_methods, &passed, &failed);
    run_test("test_whitted", test_whitted, &passed, &failed);
    run_test("test_pgrid", test_pgrid, &passed, &failed);
    run_test("test_pgrid_bad_arguments", test_pgrid_bad_arguments, &passed, &failed);
    run_test("test_pgrid_capacity", test_pgrid_capacity, &passed, &failed);
    run_test("test_trace_params", test_trace_params, &passed, &failed);
    run_test("test_render_bad_arguments", test_render_bad_arguments, &passed, &failed);
    run_test("test_last_error_buffer_rules", test_last_error_buffer_rules, &passed, &failed);
    return report(passed, failed);
}
