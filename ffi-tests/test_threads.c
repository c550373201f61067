/*
 * Thread safety as documented in sheaf.h: trace, occluded, stats and
 * last_error may run concurrently on one built context. Eight threads trace
 * and test occlusion of the same rays (and provoke errors, which record the
 * last error concurrently); every thread must get exactly the single-thread
 * results. Two threads with their own slots render bands of a frame and
 * trace CGT packets with mailboxes concurrently (the `_slot` / `_rows`
 * calls), and a slot shared by mistake gives SHEAF_STATUS_SLOT_BUSY, never
 * wrong results. Exclusive calls (builds, set_geometry, render, destroy)
 * racing traces on another thread get SHEAF_STATUS_CONTEXT_BUSY, as do the
 * traces racing them; the test runs until both sides have seen it, and no
 * trace that returns OK ever has a wrong hit.
 *
 * Runs under helgrind and DRD in tests/c_abi.rs (SHEAF_TEST_QUICK=1
 * shortens it).
 */
#define _POSIX_C_SOURCE 200112L
#include <pthread.h>
#include <time.h>

#include "common.h"

#define THREADS 8
#define NRAYS 2000
/* Rounds per test; SHEAF_TEST_QUICK=1 (the helgrind run) takes fewer. */
static int g_rounds = 20, g_slot_rounds = 12;
/* The head start of a helper that must wait before a build opens. */
static long g_head_ms = 50;

static sheaf_context *g_ctx;
static sheaf_ray g_rays[NRAYS];
static sheaf_hit g_want_hits[NRAYS];
static uint8_t g_want_occ[NRAYS];

static uint32_t lcg(uint32_t *state) {
    *state = *state * 1664525u + 1013904223u;
    return *state >> 8;
}

static float unit(uint32_t *state) {
    return (float)lcg(state) / (float)(1u << 24);
}

/* A field of boxes on a ground. */
static scene *box_field(void) {
    scene *s = scene_new();
    int i, j;
    scene_ground(s, 10.0f);
    for (i = -3; i <= 3; ++i) {
        for (j = -3; j <= 3; ++j) {
            float x = 2.5f * (float)i, y = 2.5f * (float)j, h = 0.5f + 0.25f * (float)((i + j + 6) % 5);
            scene_box(s, x - 0.6f, y - 0.6f, 0.0f, x + 0.6f, y + 0.6f, h);
        }
    }
    return s;
}

static void make_rays(void) {
    uint32_t st = 12345u;
    int i;
    for (i = 0; i < NRAYS; ++i) {
        float ox = -12.0f + 24.0f * unit(&st), oy = -12.0f + 24.0f * unit(&st), oz = 0.2f + 4.0f * unit(&st);
        float tx = -10.0f + 20.0f * unit(&st), ty = -10.0f + 20.0f * unit(&st), tz = 0.0f;
        g_rays[i] = make_ray(ox, oy, oz, tx - ox, ty - oy, tz - oz, 0.0f, (i % 2) ? 0.999f : INFINITY);
    }
}

static void *worker(void *arg) {
    static sheaf_hit hits[THREADS][NRAYS];
    static uint8_t occ[THREADS][NRAYS];
    size_t id = (size_t)arg;
    int round, i;
    char msg[SHEAF_ERROR_MESSAGE_MAX];
    size_t n;
    sheaf_stats st;
    for (round = 0; round < g_rounds; ++round) {
        if (sheaf_context_trace(g_ctx, SHEAF_METHOD_GRID_DDA, g_rays, hits[id], NRAYS) != SHEAF_STATUS_OK) return arg;
        if (sheaf_context_occluded(g_ctx, SHEAF_METHOD_GRID_DDA, g_rays, occ[id], NRAYS) != SHEAF_STATUS_OK) return arg;
        for (i = 0; i < NRAYS; ++i) {
            if (float_bits(hits[id][i].t) != float_bits(g_want_hits[i].t) || hits[id][i].prim != g_want_hits[i].prim ||
                float_bits(hits[id][i].u) != float_bits(g_want_hits[i].u) ||
                float_bits(hits[id][i].v) != float_bits(g_want_hits[i].v) || occ[id][i] != g_want_occ[i]) {
                fprintf(stderr, "    thread %u round %d ray %d differs\n", (unsigned)id, round, i);
                return arg;
            }
        }
        /* concurrent failures record the last error under a lock */
        if (sheaf_context_trace(g_ctx, SHEAF_METHOD_GRID_DDA, g_rays, NULL, NRAYS) != SHEAF_STATUS_NULL_POINTER) return arg;
        if (sheaf_context_last_error(g_ctx, msg, sizeof msg, &n) != SHEAF_STATUS_OK || n != strlen(msg)) return arg;
        if (sheaf_context_stats(g_ctx, &st) != SHEAF_STATUS_OK || st.triangles != 2 + 49 * 12) return arg;
    }
    return NULL;
}

static bool test_concurrent_trace_matches_single_thread(void) {
    scene *s = box_field();
    sheaf_limits l;
    pthread_t th[THREADS];
    size_t t;
    int hits = 0, i;
    char msg[SHEAF_ERROR_MESSAGE_MAX];
    size_t n;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    CHECK_OK(sheaf_context_create(&l, &g_ctx));
    CHECK_OK(scene_set(g_ctx, s));
    CHECK_OK(sheaf_context_build_grid(g_ctx, NULL));
    make_rays();
    CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_GRID_DDA, g_rays, g_want_hits, NRAYS));
    CHECK_OK(sheaf_context_occluded(g_ctx, SHEAF_METHOD_GRID_DDA, g_rays, g_want_occ, NRAYS));
    for (i = 0; i < NRAYS; ++i) hits += g_want_hits[i].prim != SHEAF_INVALID_ID;
    CHECK(hits > NRAYS / 4); /* the rays really hit things */
    for (t = 0; t < THREADS; ++t) CHECK(pthread_create(&th[t], NULL, worker, (void *)t) == 0);
    for (t = 0; t < THREADS; ++t) {
        void *ret = NULL;
        CHECK(pthread_join(th[t], &ret) == 0);
        CHECK(ret == NULL);
    }
    CHECK_OK(sheaf_context_last_error(g_ctx, msg, sizeof msg, &n));
    CHECK(strcmp(msg, "a required pointer is NULL") == 0);
    sheaf_context_destroy(g_ctx);
    free(s);
    return true;
}

/* Joined BVH builds: thread i of n calls sheaf_context_build_bvh_joined. */
typedef struct {
    sheaf_bvh_params p;
    uint32_t index, count;
    sheaf_status status;
} join_arg;

static void *joiner(void *arg) {
    join_arg *a = arg;
    a->status = sheaf_context_build_bvh_joined(g_ctx, &a->p, a->index, a->count);
    return NULL;
}

/* Run a joined build on `count` threads (this one leads); every status. */
static bool joined_build(const sheaf_bvh_params *p, uint32_t count, sheaf_status *status) {
    pthread_t th[8];
    join_arg a[8];
    uint32_t i;
    for (i = 0; i < count; ++i) {
        a[i].p = *p;
        a[i].index = i;
        a[i].count = count;
    }
    for (i = 1; i < count; ++i) CHECK(pthread_create(&th[i], NULL, joiner, &a[i]) == 0);
    joiner(&a[0]);
    for (i = 1; i < count; ++i) CHECK(pthread_join(th[i], NULL) == 0);
    for (i = 0; i < count; ++i) status[i] = a[i].status;
    return true;
}

/* Joined refits: thread i of n calls sheaf_context_refit_bvh_joined. */
typedef struct {
    uint32_t index, count;
    sheaf_refit_info info;
    sheaf_status status;
} refit_arg;

static void *refitter(void *arg) {
    refit_arg *a = arg;
    a->status = sheaf_context_refit_bvh_joined(g_ctx, NULL, &a->info, a->index, a->count);
    return NULL;
}

/* Run a joined refit on `count` threads (this one leads); every status and
   the leader's info. */
static bool joined_refit(uint32_t count, sheaf_status *status, sheaf_refit_info *info) {
    pthread_t th[8];
    refit_arg a[8];
    uint32_t i;
    memset(a, 0, sizeof a);
    for (i = 0; i < count; ++i) {
        a[i].index = i;
        a[i].count = count;
    }
    for (i = 1; i < count; ++i) CHECK(pthread_create(&th[i], NULL, refitter, &a[i]) == 0);
    refitter(&a[0]);
    for (i = 1; i < count; ++i) CHECK(pthread_join(th[i], NULL) == 0);
    for (i = 0; i < count; ++i) status[i] = a[i].status;
    *info = a[0].info;
    return true;
}

static bool test_joined_refits(void) {
    /* The caller's threads join one refit: on 1, 2 and 3 threads it gives
       the calling-thread refit's hits bit for bit and the same SAH figures,
       from the same tree (built before the vertices moved), with the 4-wide
       tree (bvh-wide) and without (width 2); every thread returns the
       leader's status, and bad thread arguments are refused at once. */
    scene *s = box_field();
    float orig[SCENE_MAX_V][4];
    sheaf_limits l;
    sheaf_bvh_params p;
    sheaf_refit_info want_info, info;
    sheaf_status st[8];
    sheaf_hit got[NRAYS];
    uint32_t count, i, width, hits;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    CHECK_OK(sheaf_context_create(&l, &g_ctx));
    CHECK_OK(scene_set(g_ctx, s));
    make_rays();
    memcpy(orig, s->v, sizeof orig);
    CHECK_OK(sheaf_bvh_params_default(&p));
    for (width = 2; width <= 4; width += 2) {
        sheaf_method m = width == 4 ? SHEAF_METHOD_BVH_WIDE : SHEAF_METHOD_BVH_SINGLE;
        p.width = width;
        for (count = 0; count <= 3; ++count) {
            /* count 0: the calling-thread refit, the reference. */
            memcpy(s->v, orig, sizeof orig);
            CHECK_OK(sheaf_context_build_bvh(g_ctx, &p));
            for (i = 0; i < s->nv; ++i) { /* every vertex moves */
                s->v[i][0] += 0.25f * s->v[i][1];
                s->v[i][2] -= 0.125f;
            }
            if (count == 0) {
                CHECK_OK(sheaf_context_refit_bvh(g_ctx, NULL, &want_info));
                CHECK_OK(sheaf_context_trace(g_ctx, m, g_rays, g_want_hits, NRAYS));
                for (i = 0, hits = 0; i < NRAYS; ++i) hits += g_want_hits[i].prim != SHEAF_INVALID_ID;
                CHECK(hits > NRAYS / 8); /* the moved boxes are still hit */
                continue;
            }
            CHECK(joined_refit(count, st, &info));
            for (i = 0; i < count; ++i) CHECK_OK(st[i]);
            CHECK(info.sah_before == want_info.sah_before && info.sah_after == want_info.sah_after);
            CHECK(info.rebuilt == 0 && info.newly_traceable == 0);
            CHECK_OK(sheaf_context_trace(g_ctx, m, g_rays, got, NRAYS));
            CHECK(memcmp(got, g_want_hits, sizeof got) == 0);
        }
    }
    CHECK_STATUS(sheaf_context_refit_bvh_joined(g_ctx, NULL, NULL, 0, 0), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_refit_bvh_joined(g_ctx, NULL, NULL, 3, 3), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_refit_bvh_joined(NULL, NULL, NULL, 0, 1), SHEAF_STATUS_NULL_POINTER);
    sheaf_context_destroy(g_ctx);
    free(s);
    return true;
}

/* Joined grid builds: thread i of n calls sheaf_context_build_grid_joined. */
typedef struct {
    uint32_t index, count;
    sheaf_status status;
} grid_arg;

static void *grid_joiner(void *arg) {
    grid_arg *a = arg;
    a->status = sheaf_context_build_grid_joined(g_ctx, NULL, a->index, a->count);
    return NULL;
}

static bool test_joined_grid_builds(void) {
    /* The caller's threads join one grid build: on 1, 2 and 3 threads the
       3DDDA and CGT packets give the calling-thread grid's hits bit for
       bit, every thread returns the leader's status, and bad thread
       arguments are refused at once. */
    scene *s = box_field();
    sheaf_limits l;
    sheaf_hit want_cgt[NRAYS], got[NRAYS];
    sheaf_trace_params tp;
    sheaf_grid_params coarse;
    sheaf_stats want_st, st;
    pthread_t th[8];
    grid_arg a[8];
    uint32_t count, i;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    CHECK_OK(sheaf_context_create(&l, &g_ctx));
    CHECK_OK(scene_set(g_ctx, s));
    make_rays();
    CHECK_OK(sheaf_trace_params_default(&tp));
    tp.method = SHEAF_METHOD_GRID_CGT;
    CHECK_OK(sheaf_grid_params_default(&coarse));
    coarse.lambda = 0.5f; /* another resolution, so each joined build must rewrite the grid */
    CHECK_OK(sheaf_context_build_grid(g_ctx, NULL));
    CHECK_OK(sheaf_context_stats(g_ctx, &want_st));
    CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_GRID_DDA, g_rays, g_want_hits, NRAYS));
    CHECK_OK(sheaf_context_trace_with(g_ctx, &tp, g_rays, want_cgt, NRAYS));
    for (count = 1; count <= 3; ++count) {
        CHECK_OK(sheaf_context_build_grid(g_ctx, &coarse));
        CHECK_OK(sheaf_context_stats(g_ctx, &st));
        CHECK(st.grid_cells != want_st.grid_cells);
        for (i = 0; i < count; ++i) {
            a[i].index = i;
            a[i].count = count;
        }
        for (i = 1; i < count; ++i) CHECK(pthread_create(&th[i], NULL, grid_joiner, &a[i]) == 0);
        grid_joiner(&a[0]);
        for (i = 1; i < count; ++i) CHECK(pthread_join(th[i], NULL) == 0);
        for (i = 0; i < count; ++i) CHECK_OK(a[i].status);
        CHECK_OK(sheaf_context_stats(g_ctx, &st));
        CHECK(st.grid_cells == want_st.grid_cells && st.grid_refs == want_st.grid_refs &&
              memcmp(st.grid_res, want_st.grid_res, sizeof st.grid_res) == 0);
        CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_GRID_DDA, g_rays, got, NRAYS));
        CHECK(memcmp(got, g_want_hits, sizeof got) == 0);
        CHECK_OK(sheaf_context_trace_with(g_ctx, &tp, g_rays, got, NRAYS));
        CHECK(memcmp(got, want_cgt, sizeof got) == 0);
    }
    CHECK_STATUS(sheaf_context_build_grid_joined(g_ctx, NULL, 0, 0), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_grid_joined(g_ctx, NULL, 1, 1), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_grid_joined(NULL, NULL, 0, 1), SHEAF_STATUS_NULL_POINTER);
    sheaf_context_destroy(g_ctx);
    free(s);
    return true;
}

/* Joined kd builds: thread i of n calls sheaf_context_build_kd_joined. */
static sheaf_kd_params g_kdp;

static void *kd_joiner(void *arg) {
    grid_arg *a = arg;
    a->status = sheaf_context_build_kd_joined(g_ctx, &g_kdp, a->index, a->count);
    return NULL;
}

static bool test_joined_kd_builds(void) {
    /* The caller's threads join one binned kd build (LOW and MEDIUM): on
       1, 2 and 3 threads the tree's counts and the kd single ray's and
       packets' hits are the calling-thread build's bit for bit; every
       thread returns the leader's status; bad parameters and thread
       arguments change nothing. */
    scene *s = box_field();
    sheaf_limits l;
    sheaf_hit want_pk[NRAYS], got[NRAYS];
    sheaf_trace_params tp;
    sheaf_kd_params exact, bad;
    sheaf_stats want_st, st;
    pthread_t th[8];
    grid_arg a[8];
    uint32_t count, i, q;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    l.structures = SHEAF_STRUCTURE_KD;
    CHECK_OK(sheaf_context_create(&l, &g_ctx));
    CHECK_OK(scene_set(g_ctx, s));
    make_rays();
    CHECK_OK(sheaf_trace_params_default(&tp));
    tp.method = SHEAF_METHOD_KD_PACKET;
    CHECK_OK(sheaf_kd_params_default(&exact));
    exact.quality = SHEAF_BUILD_QUALITY_HIGH;
    for (q = 0; q < 2; ++q) {
        CHECK_OK(sheaf_kd_params_default(&g_kdp));
        CHECK(g_kdp.quality == SHEAF_BUILD_QUALITY_LOW && g_kdp.bins == 32);
        g_kdp.quality = q == 0 ? SHEAF_BUILD_QUALITY_LOW : SHEAF_BUILD_QUALITY_MEDIUM;
        CHECK_OK(sheaf_context_build_kd(g_ctx, &g_kdp));
        CHECK_OK(sheaf_context_stats(g_ctx, &want_st));
        CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_KD_SINGLE, g_rays, g_want_hits, NRAYS));
        CHECK_OK(sheaf_context_trace_with(g_ctx, &tp, g_rays, want_pk, NRAYS));
        CHECK(memcmp(want_pk, g_want_hits, sizeof want_pk) == 0);
        for (count = 1; count <= 3; ++count) {
            /* The exact tree first, so each joined build must rewrite it. */
            CHECK_OK(sheaf_context_build_kd(g_ctx, &exact));
            CHECK_OK(sheaf_context_stats(g_ctx, &st));
            CHECK(st.kd_nodes != want_st.kd_nodes || st.kd_refs != want_st.kd_refs);
            for (i = 0; i < count; ++i) {
                a[i].index = i;
                a[i].count = count;
            }
            for (i = 1; i < count; ++i) CHECK(pthread_create(&th[i], NULL, kd_joiner, &a[i]) == 0);
            kd_joiner(&a[0]);
            for (i = 1; i < count; ++i) CHECK(pthread_join(th[i], NULL) == 0);
            for (i = 0; i < count; ++i) CHECK_OK(a[i].status);
            CHECK_OK(sheaf_context_stats(g_ctx, &st));
            CHECK(st.kd_nodes == want_st.kd_nodes && st.kd_refs == want_st.kd_refs &&
                  st.kd_leaves == want_st.kd_leaves && st.kd_depth == want_st.kd_depth);
            CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_KD_SINGLE, g_rays, got, NRAYS));
            CHECK(memcmp(got, g_want_hits, sizeof got) == 0);
            CHECK_OK(sheaf_context_trace_with(g_ctx, &tp, g_rays, got, NRAYS));
            CHECK(memcmp(got, want_pk, sizeof got) == 0);
        }
    }
    /* Bad input: refused, the tree unchanged. */
    bad = g_kdp;
    bad.bins = 1;
    CHECK_STATUS(sheaf_context_build_kd_joined(g_ctx, &bad, 0, 1), SHEAF_STATUS_INVALID_ARGUMENT);
    bad = g_kdp;
    bad.quality = 7;
    CHECK_STATUS(sheaf_context_build_kd_joined(g_ctx, &bad, 0, 1), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_kd_joined(g_ctx, NULL, 0, 0), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_kd_joined(g_ctx, NULL, 1, 1), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_kd_joined(g_ctx, NULL, 0, 17), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_kd_joined(NULL, NULL, 0, 1), SHEAF_STATUS_NULL_POINTER);
    CHECK_OK(sheaf_context_stats(g_ctx, &st));
    CHECK(st.kd_nodes == want_st.kd_nodes && st.kd_refs == want_st.kd_refs);
    CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_KD_SINGLE, g_rays, got, NRAYS));
    CHECK(memcmp(got, g_want_hits, sizeof got) == 0);
    sheaf_context_destroy(g_ctx);
    free(s);
    return true;
}

/* Joined deferred frames: thread i of n calls sheaf_context_render_deferred_joined. */
#define DW 67
#define DH 45
static sheaf_deferred_job g_djob;
static uint8_t g_dimg[4][DH][DW * 4];

typedef struct {
    uint32_t index, count;
    sheaf_status status;
} frame_arg;

static void *frame_joiner(void *arg) {
    frame_arg *a = arg;
    /* Helpers pass no framebuffer: only the leader's arguments are read. */
    a->status = sheaf_context_render_deferred_joined(g_ctx, a->index ? NULL : &g_djob,
                                                     a->index ? NULL : &g_dimg[a->count][0][0], DW * 4,
                                                     a->index ? 0 : sizeof g_dimg[0], a->index, a->count);
    return NULL;
}

static bool test_joined_deferred_frames(void) {
    /* The caller's threads join deferred frames (perspective grid, two
       lights through light grids, chunks of 16 rays): on 1, 2 and 3
       threads the image, every pixel's hit and shadow bits and the grids'
       and the reordering's statistics equal the calling-thread frame's,
       every thread returns the leader's status, and bad thread arguments
       are refused. The context has two thread slots: on 3 threads the third
       joins the build phases only. */
    static sheaf_hit want_hit[DH][DW];
    static uint8_t want_bits[DH][DW];
    scene *s = box_field();
    sheaf_limits l;
    sheaf_pgrid_params pp;
    sheaf_light lights[2];
    sheaf_stats want, st;
    sheaf_hit hit;
    uint8_t bits;
    pthread_t th[8];
    frame_arg a[8];
    uint32_t count, i, x, y, shadowed = 0;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    l.structures = SHEAF_STRUCTURE_PGRID;
    l.max_image_width = DW;
    l.max_image_height = DH;
    l.max_threads = 2;
    CHECK_OK(sheaf_context_create(&l, &g_ctx));
    CHECK_OK(scene_set(g_ctx, s));
    CHECK_OK(sheaf_pgrid_params_default(&pp));
    pp.chunk = 16;
    CHECK_OK(sheaf_context_build_pgrid(g_ctx, &pp));
    memset(&g_djob, 0, sizeof g_djob);
    g_djob.frame = default_frame(DW, DH);
    lights[0] = g_djob.frame.light;
    lights[1] = g_djob.frame.light;
    lights[1].position[0] = -5.0f;
    lights[1].spot_direction[0] = 5.0f;
    lights[1].spot_direction[1] = 3.0f;
    lights[1].spot_direction[2] = -8.0f;
    lights[1].spot_angle_deg = 35.0f;
    g_djob.lights = lights;
    g_djob.light_count = 2;
    g_djob.primary_pgrid = true;
    g_djob.shadow_light_grid = true;
    CHECK_OK(sheaf_context_render_deferred(g_ctx, &g_djob, &g_dimg[0][0][0], DW * 4, sizeof g_dimg[0]));
    CHECK_OK(sheaf_context_stats(g_ctx, &want));
    CHECK(want.shadow_rays > 0 && want.reorder_chunks > want.reorder_tiles_used);
    for (y = 0; y < DH; ++y) {
        for (x = 0; x < DW; ++x) {
            CHECK_OK(sheaf_context_deferred_pixel(g_ctx, x, y, &want_hit[y][x], &want_bits[y][x]));
            shadowed += want_bits[y][x] != 0;
        }
    }
    CHECK(shadowed > 0);
    for (count = 1; count <= 3; ++count) {
        for (i = 0; i < count; ++i) {
            a[i].index = i;
            a[i].count = count;
        }
        for (i = 1; i < count; ++i) CHECK(pthread_create(&th[i], NULL, frame_joiner, &a[i]) == 0);
        frame_joiner(&a[0]);
        for (i = 1; i < count; ++i) CHECK(pthread_join(th[i], NULL) == 0);
        for (i = 0; i < count; ++i) CHECK_OK(a[i].status);
        CHECK(memcmp(g_dimg[count], g_dimg[0], sizeof g_dimg[0]) == 0);
        CHECK_OK(sheaf_context_stats(g_ctx, &st));
        CHECK(st.camera_refs == want.camera_refs && st.camera_mapped == want.camera_mapped &&
              st.light_refs == want.light_refs && st.light_mapped == want.light_mapped &&
              memcmp(st.light_tiles, want.light_tiles, sizeof st.light_tiles) == 0 &&
              st.shadow_rays == want.shadow_rays && st.reorder_rays == want.reorder_rays &&
              st.reorder_chunks == want.reorder_chunks && st.reorder_tiles_used == want.reorder_tiles_used &&
              st.reorder_max_tile_rays == want.reorder_max_tile_rays && st.hits == want.hits);
        for (y = 0; y < DH; ++y) {
            for (x = 0; x < DW; ++x) {
                CHECK_OK(sheaf_context_deferred_pixel(g_ctx, x, y, &hit, &bits));
                CHECK(memcmp(&hit, &want_hit[y][x], sizeof hit) == 0 && bits == want_bits[y][x]);
            }
        }
    }
    CHECK_STATUS(sheaf_context_render_deferred_joined(g_ctx, &g_djob, &g_dimg[0][0][0], DW * 4, sizeof g_dimg[0], 0, 0),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_render_deferred_joined(g_ctx, &g_djob, &g_dimg[0][0][0], DW * 4, sizeof g_dimg[0], 1, 1),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_render_deferred_joined(NULL, &g_djob, &g_dimg[0][0][0], DW * 4, sizeof g_dimg[0], 0, 1),
                 SHEAF_STATUS_NULL_POINTER);
    sheaf_context_destroy(g_ctx);
    free(s);
    return true;
}

static bool test_joined_builds(void) {
    /* The caller's threads join one BVH build: LOW on 2 and 3 threads and
       MEDIUM on 2 give the single-thread build's hits bit for bit, every
       thread returns the leader's status (a bad parameter: all refused),
       and bad thread arguments are refused at once. */
    scene *s = box_field();
    sheaf_limits l;
    sheaf_bvh_params p;
    sheaf_status st[8];
    sheaf_hit got[NRAYS];
    uint32_t count, i, q;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    CHECK_OK(sheaf_context_create(&l, &g_ctx));
    CHECK_OK(scene_set(g_ctx, s));
    make_rays();
    CHECK_OK(sheaf_bvh_params_default(&p));
    CHECK_OK(sheaf_context_build_bvh(g_ctx, &p));
    CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_BVH_SINGLE, g_rays, g_want_hits, NRAYS));
    for (q = 0; q < 2; ++q) {
        p.quality = q == 0 ? SHEAF_BUILD_QUALITY_LOW : SHEAF_BUILD_QUALITY_MEDIUM;
        for (count = 1; count <= (q == 0 ? 3u : 2u); ++count) {
            int round;
            for (round = 0; round < g_slot_rounds; ++round) {
                CHECK(joined_build(&p, count, st));
                for (i = 0; i < count; ++i) CHECK_OK(st[i]);
                CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_BVH_RANGED, g_rays, got, NRAYS));
                for (i = 0; i < NRAYS; ++i) {
                    CHECK(got[i].prim == g_want_hits[i].prim &&
                          memcmp(&got[i].t, &g_want_hits[i].t, sizeof(float)) == 0);
                }
            }
        }
    }
    p.bins = 1; /* invalid: the leader refuses, its helper returns the same */
    p.quality = SHEAF_BUILD_QUALITY_MEDIUM;
    CHECK(joined_build(&p, 2, st));
    CHECK_STATUS(st[0], SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(st[1], SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_BVH_SINGLE, g_rays, got, NRAYS));
    CHECK(memcmp(got, g_want_hits, sizeof got) == 0);
    CHECK_OK(sheaf_bvh_params_default(&p));
    CHECK_STATUS(sheaf_context_build_bvh_joined(g_ctx, &p, 0, 0), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_bvh_joined(g_ctx, &p, 2, 2), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_bvh_joined(g_ctx, &p, 0, 17), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_build_bvh_joined(NULL, &p, 0, 1), SHEAF_STATUS_NULL_POINTER);
    sheaf_context_destroy(g_ctx);
    free(s);
    return true;
}

/* Misjoined builds: helpers with a duplicate index or another thread
   count. Each helper runs on its own thread and reports when it returns. */
typedef struct {
    int kd; /* 1: sheaf_context_build_kd_joined, 0: _bvh_joined */
    uint32_t index, count;
    sheaf_status status;
    int done;
} mis_arg;

static pthread_mutex_t g_mis_lock = PTHREAD_MUTEX_INITIALIZER;

static void *mis_joiner(void *arg) {
    mis_arg *a = arg;
    sheaf_status st = a->kd ? sheaf_context_build_kd_joined(g_ctx, NULL, a->index, a->count)
                            : sheaf_context_build_bvh_joined(g_ctx, NULL, a->index, a->count);
    pthread_mutex_lock(&g_mis_lock);
    a->status = st;
    a->done = 1;
    pthread_mutex_unlock(&g_mis_lock);
    return NULL;
}

static void sleep_ms(long ms) {
    struct timespec t;
    t.tv_sec = ms / 1000;
    t.tv_nsec = (ms % 1000) * 1000000L;
    nanosleep(&t, NULL);
}

/* Whether `a` returned within about `ms` milliseconds. */
static int returned_within(mis_arg *a, long ms) {
    long waited;
    for (waited = 0;; ++waited) {
        int d;
        pthread_mutex_lock(&g_mis_lock);
        d = a->done;
        pthread_mutex_unlock(&g_mis_lock);
        if (d || waited >= ms) return d;
        sleep_ms(1);
    }
}

static mis_arg mis(int kd, uint32_t index, uint32_t count) {
    mis_arg a;
    a.kd = kd;
    a.index = index;
    a.count = count;
    a.status = SHEAF_STATUS_PANIC;
    a.done = 0;
    return a;
}

static bool test_misjoined_builds_are_refused(void) {
    /* Two helpers passing one thread_index beside a leader, and a helper
       (2, 3) waiting beside a (0, 2) + (1, 2) group: the extra helper gets
       SHEAF_STATUS_INVALID_ARGUMENT, the build and its other helper OK,
       and the context stays usable (the same hits after). A helper
       waiting when the build opens is always looked at by it; one that
       arrives after its build ended waits for the next, so the test
       releases it with another build (never needed when the helpers were
       waiting, the head start), and counts the refusals it saw. */
    scene *s = box_field();
    sheaf_limits l;
    sheaf_hit got[NRAYS], want[2][NRAYS];
    int kd, round, refused = 0;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    CHECK_OK(sheaf_context_create(&l, &g_ctx));
    CHECK_OK(scene_set(g_ctx, s));
    make_rays();
    CHECK_OK(sheaf_context_build_bvh(g_ctx, NULL));
    CHECK_OK(sheaf_context_build_kd(g_ctx, NULL));
    CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_BVH_SINGLE, g_rays, want[0], NRAYS));
    CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_KD_SINGLE, g_rays, want[1], NRAYS));
    for (kd = 0; kd < 2; ++kd) {
        sheaf_method m = kd ? SHEAF_METHOD_KD_SINGLE : SHEAF_METHOD_BVH_SINGLE;
        for (round = 0; round < g_slot_rounds; ++round) {
            pthread_t th[3];
            mis_arg a[3], b[2];
            int i, ok = 0, bad = 0;
            /* A duplicate index. */
            a[0] = mis(kd, 1, 2), a[1] = mis(kd, 1, 2);
            for (i = 0; i < 2; ++i) CHECK(pthread_create(&th[i], NULL, mis_joiner, &a[i]) == 0);
            sleep_ms(g_head_ms);
            b[0] = mis(kd, 0, 2);
            mis_joiner(&b[0]);
            CHECK_OK(b[0].status);
            if (!(returned_within(&a[0], 2000) && returned_within(&a[1], 2000))) {
                b[1] = mis(kd, 0, 2); /* release a late duplicate */
                mis_joiner(&b[1]);
                CHECK_OK(b[1].status);
            }
            for (i = 0; i < 2; ++i) {
                CHECK(pthread_join(th[i], NULL) == 0);
                ok += a[i].status == SHEAF_STATUS_OK;
                bad += a[i].status == SHEAF_STATUS_INVALID_ARGUMENT;
            }
            CHECK(ok + bad == 2 && ok >= 1);
            refused += bad;
            CHECK_OK(sheaf_context_trace(g_ctx, m, g_rays, got, NRAYS));
            CHECK(memcmp(got, want[kd], sizeof got) == 0);
            /* A helper of another thread count waiting beside a group. */
            a[2] = mis(kd, 2, 3);
            CHECK(pthread_create(&th[2], NULL, mis_joiner, &a[2]) == 0);
            sleep_ms(g_head_ms);
            a[0] = mis(kd, 1, 2);
            CHECK(pthread_create(&th[0], NULL, mis_joiner, &a[0]) == 0);
            b[0] = mis(kd, 0, 2);
            mis_joiner(&b[0]);
            CHECK_OK(b[0].status);
            CHECK(pthread_join(th[0], NULL) == 0);
            CHECK_OK(a[0].status);
            if (!returned_within(&a[2], 2000)) {
                /* It missed the group (it was not waiting yet): a group of
                   three takes it. */
                a[1] = mis(kd, 1, 3);
                CHECK(pthread_create(&th[1], NULL, mis_joiner, &a[1]) == 0);
                b[1] = mis(kd, 0, 3);
                mis_joiner(&b[1]);
                CHECK(pthread_join(th[1], NULL) == 0);
                CHECK_OK(b[1].status);
            }
            CHECK(pthread_join(th[2], NULL) == 0);
            CHECK(a[2].status == SHEAF_STATUS_INVALID_ARGUMENT || a[2].status == SHEAF_STATUS_OK);
            refused += a[2].status == SHEAF_STATUS_INVALID_ARGUMENT;
            CHECK_OK(sheaf_context_trace(g_ctx, m, g_rays, got, NRAYS));
            CHECK(memcmp(got, want[kd], sizeof got) == 0);
        }
    }
    /* The head start puts the extra helpers at the door before the
       build opens: refusals are what the test sees, not the exception. */
    CHECK(refused >= 2 * g_slot_rounds);
    sheaf_context_destroy(g_ctx);
    free(s);
    return true;
}

/* Several contexts on several threads: independent. */
static void *own_context(void *arg) {
    scene *s = (scene *)arg;
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    static sheaf_hit hits[THREADS][NRAYS];
    static size_t next = 0;
    static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
    size_t id;
    pthread_mutex_lock(&lock);
    id = next++;
    pthread_mutex_unlock(&lock);
    if (sheaf_limits_default(s->nt, &l) != SHEAF_STATUS_OK) return arg;
    if (sheaf_context_create(&l, &ctx) != SHEAF_STATUS_OK) return arg;
    if (scene_set(ctx, s) != SHEAF_STATUS_OK || sheaf_context_build_grid(ctx, NULL) != SHEAF_STATUS_OK) return arg;
    if (sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, g_rays, hits[id], NRAYS) != SHEAF_STATUS_OK) return arg;
    sheaf_context_destroy(ctx);
    if (memcmp(hits[id], g_want_hits, sizeof g_want_hits) != 0) return arg;
    return NULL;
}

static bool test_independent_contexts_on_threads(void) {
    scene *s = box_field();
    pthread_t th[THREADS];
    size_t t;
    sheaf_context *ctx = NULL;
    sheaf_limits l;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_context_build_grid(ctx, NULL));
    make_rays();
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, g_rays, g_want_hits, NRAYS));
    sheaf_context_destroy(ctx);
    for (t = 0; t < THREADS; ++t) CHECK(pthread_create(&th[t], NULL, own_context, s) == 0);
    for (t = 0; t < THREADS; ++t) {
        void *ret = NULL;
        CHECK(pthread_join(th[t], &ret) == 0);
        CHECK(ret == NULL);
    }
    free(s);
    return true;
}

/* Two threads, one built context, per-thread slots. */
#define SLOT_W 96
#define SLOT_H 64
static sheaf_frame g_frame;
static sheaf_trace_params g_cgt, g_shadow;
static uint8_t g_want_img[SLOT_H][SLOT_W * 4];
static sheaf_ray g_cam[SLOT_W * SLOT_H];
static sheaf_hit g_want_cam[SLOT_W * SLOT_H];
static uint8_t g_want_cam_occ[SLOT_W * SLOT_H];
static uint8_t g_img[SLOT_H][SLOT_W * 4];

static void *slot_worker(void *arg) {
    static sheaf_hit hits[2][SLOT_W * SLOT_H];
    static uint8_t occ[2][SLOT_W * SLOT_H];
    uint32_t slot = (uint32_t)(size_t)arg, y0 = slot * (SLOT_H / 2), y, n = SLOT_W * SLOT_H;
    int round;
    for (round = 0; round < g_slot_rounds; ++round) {
        /* Bands of 5 rows (not a multiple of the 8x8 tiles) through this thread's half. */
        for (y = y0; y < y0 + SLOT_H / 2; y += 5) {
            uint32_t y1 = y + 5 < y0 + SLOT_H / 2 ? y + 5 : y0 + SLOT_H / 2;
            if (sheaf_context_render_rows(g_ctx, slot, &g_cgt, &g_shadow, &g_frame, y, y1, g_img[y], SLOT_W * 4,
                                          (size_t)(y1 - y) * SLOT_W * 4) != SHEAF_STATUS_OK)
                return arg;
        }
        if (sheaf_context_trace_slot(g_ctx, slot, &g_cgt, g_cam, hits[slot], n) != SHEAF_STATUS_OK) return arg;
        if (sheaf_context_occluded_slot(g_ctx, slot, &g_cgt, g_cam, occ[slot], n) != SHEAF_STATUS_OK) return arg;
        if (memcmp(hits[slot], g_want_cam, sizeof g_want_cam) != 0 ||
            memcmp(occ[slot], g_want_cam_occ, sizeof g_want_cam_occ) != 0) {
            fprintf(stderr, "    slot %u round %d: trace results differ\n", (unsigned)slot, round);
            return arg;
        }
    }
    return NULL;
}

/* Both threads on slot 0: every call either succeeds with the right hits or says the slot is busy. */
static int g_busy[2];
static void *shared_slot_worker(void *arg) {
    static sheaf_hit hits[2][SLOT_W * SLOT_H];
    size_t id = (size_t)arg;
    int round;
    for (round = 0; round < 4 * g_slot_rounds; ++round) {
        sheaf_status s = sheaf_context_trace_slot(g_ctx, 0, &g_cgt, g_cam, hits[id], SLOT_W * SLOT_H);
        if (s == SHEAF_STATUS_SLOT_BUSY) {
            ++g_busy[id];
            continue;
        }
        if (s != SHEAF_STATUS_OK || memcmp(hits[id], g_want_cam, sizeof g_want_cam) != 0) return arg;
    }
    return NULL;
}

static bool test_two_threads_with_slots(void) {
    scene *s = box_field();
    sheaf_limits l;
    pthread_t th[2];
    size_t t;
    uint32_t x, y;
    int hits = 0, i;
    sheaf_hit h;
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    l.max_threads = 2;
    CHECK_OK(sheaf_context_create(&l, &g_ctx));
    CHECK_OK(scene_set(g_ctx, s));
    CHECK_OK(sheaf_context_build_grid(g_ctx, NULL));
    g_frame = default_frame(SLOT_W, SLOT_H);
    g_frame.camera.eye[0] = 9.0f;
    g_frame.camera.eye[1] = -11.0f;
    g_frame.camera.eye[2] = 7.0f;
    CHECK_OK(sheaf_trace_params_default(&g_cgt));
    g_cgt.method = SHEAF_METHOD_GRID_CGT;
    g_cgt.packet = 8;
    g_cgt.mailbox = true;
    g_shadow = g_cgt;
    /* The single-thread answers: a whole-frame render and packets without slots. */
    CHECK_OK(sheaf_context_render_with(g_ctx, &g_cgt, &g_shadow, &g_frame, &g_want_img[0][0], SLOT_W * 4,
                                       sizeof g_want_img));
    for (y = 0; y < SLOT_H; ++y)
        for (x = 0; x < SLOT_W; ++x) CHECK_OK(sheaf_frame_camera_ray(&g_frame, x, y, &g_cam[y * SLOT_W + x]));
    CHECK_OK(sheaf_context_trace_with(g_ctx, &g_cgt, g_cam, g_want_cam, SLOT_W * SLOT_H));
    CHECK_OK(sheaf_context_occluded(g_ctx, SHEAF_METHOD_GRID_DDA, g_cam, g_want_cam_occ, SLOT_W * SLOT_H));
    for (i = 0; i < SLOT_W * SLOT_H; ++i) {
        CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_GRID_DDA, &g_cam[i], &h, 1));
        CHECK(h.prim == g_want_cam[i].prim && float_bits(h.t) == float_bits(g_want_cam[i].t));
        hits += h.prim != SHEAF_INVALID_ID;
    }
    CHECK(hits > SLOT_W * SLOT_H / 2); /* the camera sees the boxes */
    /* Two threads, slots 0 and 1, concurrently. */
    memset(g_img, 0, sizeof g_img);
    for (t = 0; t < 2; ++t) CHECK(pthread_create(&th[t], NULL, slot_worker, (void *)t) == 0);
    for (t = 0; t < 2; ++t) {
        void *ret = NULL;
        CHECK(pthread_join(th[t], &ret) == 0);
        CHECK(ret == NULL);
    }
    CHECK(memcmp(g_img, g_want_img, sizeof g_img) == 0);
    /* Slot 0 shared by mistake: busy or right, never wrong. */
    for (t = 0; t < 2; ++t) CHECK(pthread_create(&th[t], NULL, shared_slot_worker, (void *)t) == 0);
    for (t = 0; t < 2; ++t) {
        void *ret = NULL;
        CHECK(pthread_join(th[t], &ret) == 0);
        CHECK(ret == NULL);
    }
    printf("    slot 0 shared by two threads: %d + %d calls found it busy\n", g_busy[0], g_busy[1]);
    /* Both slots are free again once the calls return. */
    {
        static sheaf_hit again[SLOT_W * SLOT_H];
        CHECK_OK(sheaf_context_trace_slot(g_ctx, 0, &g_cgt, g_cam, again, SLOT_W * SLOT_H));
        CHECK_OK(sheaf_context_trace_slot(g_ctx, 1, &g_cgt, g_cam, again, SLOT_W * SLOT_H));
        CHECK(memcmp(again, g_want_cam, sizeof again) == 0);
    }
    /* Bad slots and rows change nothing. */
    memcpy(g_img, g_want_img, sizeof g_img);
    CHECK(sheaf_context_render_rows(g_ctx, 2, &g_cgt, &g_shadow, &g_frame, 0, 1, g_img[0], SLOT_W * 4, SLOT_W * 4) ==
          SHEAF_STATUS_CAPACITY_THREADS);
    CHECK(sheaf_context_render_rows(g_ctx, 0, &g_cgt, &g_shadow, &g_frame, 3, 3, g_img[3], SLOT_W * 4, SLOT_W * 4) ==
          SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(sheaf_context_render_rows(g_ctx, 0, &g_cgt, &g_shadow, &g_frame, 60, 65, g_img[60], SLOT_W * 4,
                                    5 * SLOT_W * 4) == SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(sheaf_context_render_rows(g_ctx, 0, &g_cgt, &g_shadow, &g_frame, 0, 2, g_img[0], SLOT_W * 4,
                                    SLOT_W * 4) == SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(sheaf_context_trace_slot(g_ctx, 7, &g_cgt, g_cam, (sheaf_hit *)g_img, 1) == SHEAF_STATUS_CAPACITY_THREADS);
    CHECK(memcmp(g_img, g_want_img, sizeof g_img) == 0);
    sheaf_context_destroy(g_ctx);
    free(s);
    return true;
}

/* One thread traces in a loop while the main thread rebuilds, resets the
 * geometry and renders: the state word must turn every overlap into
 * SHEAF_STATUS_CONTEXT_BUSY on one side. */
#define BUSY_RAYS 2000
static pthread_mutex_t g_stop_lock = PTHREAD_MUTEX_INITIALIZER;
static int g_stop;
static sheaf_trace_params g_bvh8;
static long g_trace_ok, g_trace_busy, g_trace_bad;

/* The tracer's counters and the stop flag, shared under g_stop_lock. */
static int stop_requested(long *busy) {
    int v;
    pthread_mutex_lock(&g_stop_lock);
    v = g_stop;
    if (busy) *busy = g_trace_busy;
    pthread_mutex_unlock(&g_stop_lock);
    return v;
}

static void *racing_tracer(void *arg) {
    static sheaf_hit hits[BUSY_RAYS];
    (void)arg;
    while (!stop_requested(NULL)) {
        sheaf_status st = sheaf_context_trace_slot(g_ctx, 0, &g_bvh8, g_rays, hits, BUSY_RAYS);
        struct timespec pause = {0, 20000}; /* leave gaps for the exclusive calls */
        if (st == SHEAF_STATUS_CONTEXT_BUSY) {
            pthread_mutex_lock(&g_stop_lock);
            ++g_trace_busy;
            pthread_mutex_unlock(&g_stop_lock);
        } else if (st != SHEAF_STATUS_OK) {
            fprintf(stderr, "    racing trace returned %d\n", (int)st);
            ++g_trace_bad;
        } else {
            int i;
            ++g_trace_ok;
            for (i = 0; i < BUSY_RAYS; ++i)
                if (hits[i].prim != g_want_hits[i].prim || float_bits(hits[i].t) != float_bits(g_want_hits[i].t)) {
                    fprintf(stderr, "    racing trace: ray %d wrong\n", i);
                    ++g_trace_bad;
                    break;
                }
        }
        nanosleep(&pause, NULL);
    }
    return NULL;
}

static bool test_exclusive_calls_racing_traces_get_busy(void) {
    scene *s = box_field();
    sheaf_limits l;
    pthread_t th;
    long build_ok = 0, build_busy = 0, other_busy = 0, rounds = 0, trace_busy = 0;
    time_t start;
    static uint8_t img[64][96 * 4];
    char msg[SHEAF_ERROR_MESSAGE_MAX];
    size_t n;
    sheaf_frame f = default_frame(96, 64);
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    l.max_threads = 2;
    CHECK_OK(sheaf_context_create(&l, &g_ctx));
    CHECK_OK(scene_set(g_ctx, s));
    CHECK_OK(sheaf_context_build_bvh(g_ctx, NULL));
    make_rays();
    CHECK_OK(sheaf_trace_params_default(&g_bvh8));
    /* Single rays: each call long enough (under valgrind, several of its
       scheduling quanta) for the other thread to run into it. */
    g_bvh8.method = SHEAF_METHOD_BVH_SINGLE;
    CHECK_OK(sheaf_context_trace(g_ctx, SHEAF_METHOD_BVH_SINGLE, g_rays, g_want_hits, BUSY_RAYS));
    g_stop = 0;
    CHECK(pthread_create(&th, NULL, racing_tracer, NULL) == 0);
    /* Until both sides have seen the other, each kind of exclusive call
       included (or 120 s, ample even under helgrind: then fail). */
    start = time(NULL);
    while (time(NULL) - start < 120 && (build_busy == 0 || trace_busy == 0 || other_busy == 0 || build_ok == 0)) {
        sheaf_status st;
        ++rounds;
        stop_requested(&trace_busy);
        switch (rounds % 4) {
        case 0: st = scene_set(g_ctx, s); break;
        case 1: st = sheaf_context_render(g_ctx, SHEAF_METHOD_BVH_SINGLE, &f, &img[0][0], 96 * 4, sizeof img); break;
        default: st = sheaf_context_build_bvh(g_ctx, NULL); break;
        }
        {
            struct timespec pause = {0, 5000}; /* leave gaps for the traces */
            nanosleep(&pause, NULL);
        }
        if (st == SHEAF_STATUS_CONTEXT_BUSY) {
            if (rounds % 4 >= 2) ++build_busy; else ++other_busy;
        } else if (st == SHEAF_STATUS_OK) {
            build_ok += rounds % 4 >= 2;
        } else {
            fprintf(stderr, "    exclusive call returned %d\n", (int)st);
            break;
        }
    }
    pthread_mutex_lock(&g_stop_lock);
    g_stop = 1;
    pthread_mutex_unlock(&g_stop_lock);
    CHECK(pthread_join(th, NULL) == 0);
    printf("    %ld exclusive calls: %ld builds OK, %ld builds + %ld others found the context busy; "
           "racing traces: %ld OK (all right), %ld busy\n",
           rounds, build_ok, build_busy, other_busy, g_trace_ok, g_trace_busy);
    CHECK(g_trace_bad == 0);
    CHECK(build_busy > 0 && other_busy > 0 && g_trace_busy > 0); /* contention really happened */
    CHECK(build_ok > 0 && g_trace_ok > 0);
    /* A busy refusal is not recorded as the last error. */
    CHECK_OK(sheaf_context_last_error(g_ctx, msg, sizeof msg, &n));
    CHECK(strcmp(msg, "no error") == 0);
    /* Nothing is left held: exclusive calls and destroy succeed again. */
    CHECK_OK(sheaf_context_build_bvh(g_ctx, NULL));
    sheaf_context_destroy(g_ctx);
    free(s);
    return true;
}

/* destroy while another thread traces (a create_in context, whose memory
 * stays valid afterwards, so the late calls are defined): destroy waits
 * for the trace inside, later calls are refused (INVALID_ARGUMENT: not a
 * live context), no trace is wrong. */
static sheaf_context *g_dying;
static long g_dying_ok, g_dying_busy, g_dying_gone, g_dying_bad;
/* Set (under the mutex) after the tracer's first successful call, so
 * destroy races calls in flight however busy the machine is. */
static pthread_mutex_t g_dying_mu = PTHREAD_MUTEX_INITIALIZER;
static int g_dying_started;

static void *tracer_until_gone(void *arg) {
    static sheaf_hit hits[BUSY_RAYS];
    (void)arg;
    for (;;) {
        sheaf_status st = sheaf_context_trace(g_dying, SHEAF_METHOD_BVH_SINGLE, g_rays, hits, BUSY_RAYS);
        if (st == SHEAF_STATUS_OK) {
            ++g_dying_ok;
            if (memcmp(hits, g_want_hits, sizeof hits) != 0) ++g_dying_bad;
            pthread_mutex_lock(&g_dying_mu);
            g_dying_started = 1;
            pthread_mutex_unlock(&g_dying_mu);
        } else if (st == SHEAF_STATUS_CONTEXT_BUSY) {
            ++g_dying_busy;
        } else if (st == SHEAF_STATUS_INVALID_ARGUMENT) {
            ++g_dying_gone;
            return NULL;
        } else {
            ++g_dying_bad;
            return NULL;
        }
    }
}

static bool test_destroy_waits_for_calls_inside(void) {
    scene *s = box_field();
    sheaf_limits l;
    size_t need = 0;
    void *raw;
    pthread_t th;
    struct timespec pause = {0, 2000000};
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    l.structures = SHEAF_STRUCTURE_BVH;
    CHECK_OK(sheaf_required_bytes(&l, &need));
    raw = malloc(need + SHEAF_CONTEXT_ALIGN);
    CHECK(raw != NULL);
    CHECK_OK(sheaf_context_create_in(align_up(raw, SHEAF_CONTEXT_ALIGN), need, &l, &g_dying));
    CHECK_OK(scene_set(g_dying, s));
    CHECK_OK(sheaf_context_build_bvh(g_dying, NULL));
    make_rays();
    CHECK_OK(sheaf_context_trace(g_dying, SHEAF_METHOD_BVH_SINGLE, g_rays, g_want_hits, BUSY_RAYS));
    CHECK(pthread_create(&th, NULL, tracer_until_gone, NULL) == 0);
    /* Wait for one finished call (a fixed sleep was not enough on a loaded
     * machine), then destroy while the tracer keeps calling. */
    for (;;) {
        int started;
        pthread_mutex_lock(&g_dying_mu);
        started = g_dying_started;
        pthread_mutex_unlock(&g_dying_mu);
        if (started) break;
        nanosleep(&pause, NULL);
    }
    sheaf_context_destroy(g_dying);
    CHECK(pthread_join(th, NULL) == 0);
    printf("    traces racing destroy: %ld OK (all right), then refused as destroyed\n", g_dying_ok);
    CHECK(g_dying_bad == 0 && g_dying_busy == 0 && g_dying_gone == 1 && g_dying_ok > 0);
    free(raw);
    free(s);
    return true;
}

int main(void) {
    int passed = 0, failed = 0;
    const char *quick = getenv("SHEAF_TEST_QUICK");
    if (quick && *quick == '1') {
        g_rounds = 2;
        g_slot_rounds = 2;
        g_head_ms = 500; /* threads start slowly under helgrind and DRD */
    }
    run_test("test_concurrent_trace_matches_single_thread", test_concurrent_trace_matches_single_thread, &passed,
             &failed);
    run_test("test_independent_contexts_on_threads", test_independent_contexts_on_threads, &passed, &failed);
    run_test("test_two_threads_with_slots", test_two_threads_with_slots, &passed, &failed);
    run_test("test_exclusive_calls_racing_traces_get_busy", test_exclusive_calls_racing_traces_get_busy, &passed,
             &failed);
    run_test("test_destroy_waits_for_calls_inside", test_destroy_waits_for_calls_inside, &passed, &failed);
    run_test("test_joined_builds", test_joined_builds, &passed, &failed);
    run_test("test_misjoined_builds_are_refused", test_misjoined_builds_are_refused, &passed, &failed);
    run_test("test_joined_refits", test_joined_refits, &passed, &failed);
    run_test("test_joined_grid_builds", test_joined_grid_builds, &passed, &failed);
    run_test("test_joined_kd_builds", test_joined_kd_builds, &passed, &failed);
    run_test("test_joined_deferred_frames", test_joined_deferred_frames, &passed, &failed);
    return report(passed, failed);
}
