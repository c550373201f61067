/*
 * A capacity error in the middle of a frame sequence leaves the previous
 * frame's results intact (a scene larger than the pools gets a capacity
 * error and nothing is overwritten; sheaf_status 200-299: "the context
 * keeps its previous state").
 *
 * Each test builds a scene into every structure, keeps the results of
 * trace, occluded and render calls with several methods (grid, BVH, kd-tree)
 * and of a deferred frame, then makes calls that overflow a pool:
 *   - set_geometry with more triangles / vertices than the limits;
 *   - build_grid whose references or cells overflow;
 *   - build_bvh / build_kd / build_pgrid on indices edited in place to be out
 *     of range (their pools are sized per triangle and cannot overflow: the
 *     BVH has 2N nodes, the kd-tree makes leaves early when its node or
 *     reference pool runs out, which is checked too);
 *   - render_deferred whose perspective/light grid overflows its cells or pairs;
 * and checks after each: the documented status, the pool in the last error,
 * unchanged stats, untouched outputs, and every earlier result reproduced
 * bit for bit.
 */
#include "common.h"

#define W 32
#define H 24
#define STRIDE (W * 4 + 8)
#define LEN ((H - 1) * STRIDE + W * 4)
#define N_RAYS 64
#define SENTINEL 0xA7

/* Ground (2 triangles) and a unit box (12): 14 triangles, 12 vertices. */
static scene *small_scene(void) {
    scene *s = scene_new();
    scene_ground(s, 4.0f);
    scene_box(s, -0.5f, -0.5f, 0.0f, 0.5f, 0.5f, 1.0f);
    return s;
}

/* The small scene plus `boxes` more boxes. */
static scene *bigger_scene(int boxes) {
    scene *s = small_scene();
    int i;
    for (i = 0; i < boxes; ++i) {
        float x = -3.0f + 1.5f * (float)(i % 5), y = -3.0f + 1.5f * (float)(i / 5);
        scene_box(s, x, y, 0.0f, x + 0.6f, y + 0.6f, 0.4f + 0.1f * (float)i);
    }
    return s;
}

/* Rays from above and from the side over the whole scene, some misses. */
static void make_rays(sheaf_ray *rays) {
    int i;
    for (i = 0; i < N_RAYS; ++i) {
        float x = -3.5f + 7.0f * (float)(i % 8) / 7.0f, y = -3.5f + 7.0f * (float)(i / 8) / 7.0f;
        if (i % 3 == 0) {
            rays[i] = make_ray(x, y, 6.0f, 0.05f, -0.03f, -1.0f, 0.0f, INFINITY);
        } else if (i % 3 == 1) {
            rays[i] = make_ray(-6.0f, y, 0.3f + 0.01f * (float)i, 1.0f, 0.02f, -0.01f, 0.0f, INFINITY);
        } else {
            rays[i] = make_ray(x, y, 0.5f, 0.3f, 0.2f, 1.0f, 0.0f, INFINITY); /* mostly misses */
        }
    }
}

/* Field-wise: struct padding is not part of the contract. */
static bool stats_equal(const sheaf_stats *a, const sheaf_stats *b) {
#define SAME(f) if (a->f != b->f) { fprintf(stderr, "    stats.%s changed\n", #f); return false; }
    SAME(triangles_in) SAME(triangles) SAME(excluded_non_finite) SAME(excluded_zero_area)
    SAME(grid_res[0]) SAME(grid_res[1]) SAME(grid_res[2]) SAME(grid_refs) SAME(grid_cells)
    SAME(macrocell) SAME(lambda) SAME(test) SAME(build_ns) SAME(trace_ns)
    SAME(counters.rays) SAME(counters.packets) SAME(counters.tri_tests)
    SAME(bvh_nodes) SAME(bvh_leaves) SAME(bvh_depth) SAME(bvh_triangles) SAME(bvh_build_ns)
    SAME(kd_nodes) SAME(kd_leaves) SAME(kd_depth) SAME(kd_triangles) SAME(kd_refs) SAME(kd_build_ns)
    SAME(pgrid_triangles) SAME(camera_cells) SAME(camera_refs) SAME(light_cells) SAME(light_refs)
    SAME(primary_build_ns) SAME(shade_ns) SAME(shadow_rays) SAME(hits)
#undef SAME
    return true;
}

static bool last_error_names(const sheaf_context *ctx, const char *what) {
    char msg[SHEAF_ERROR_MESSAGE_MAX];
    size_t n = 0;
    if (sheaf_context_last_error(ctx, msg, sizeof msg, &n) != SHEAF_STATUS_OK) return false;
    if (strstr(msg, what) == NULL) {
        fprintf(stderr, "    last error \"%s\" does not name \"%s\"\n", msg, what);
        return false;
    }
    return true;
}

/* Everything a frame produced, to compare after a failed call. */
#define N_TRACES 7
static const sheaf_method trace_methods[N_TRACES] = {
    SHEAF_METHOD_GRID_DDA, SHEAF_METHOD_GRID_CGT, SHEAF_METHOD_BVH_SINGLE, SHEAF_METHOD_BVH_RANGED,
    SHEAF_METHOD_BVH_PARTITION, SHEAF_METHOD_KD_SINGLE, SHEAF_METHOD_KD_PACKET};

typedef struct results {
    sheaf_hit hits[N_TRACES][N_RAYS];
    uint8_t occluded[N_TRACES][N_RAYS];
    uint8_t grid_image[LEN];
    uint8_t bvh_image[LEN];
    uint8_t deferred_image[LEN];
    sheaf_hit pixel_hit[H][W];
    uint8_t pixel_bits[H][W];
    bool has_deferred;
} results;

static sheaf_trace_params params_for(sheaf_method m) {
    sheaf_trace_params p;
    (void)sheaf_trace_params_default(&p);
    p.method = m;
    p.packet = 4;
    return p;
}

static sheaf_deferred_job deferred_job(uint32_t w, uint32_t h, float eye_scale) {
    sheaf_deferred_job job;
    memset(&job, 0, sizeof job);
    job.frame = default_frame(w, h);
    job.frame.camera.eye[0] *= eye_scale;
    job.frame.camera.eye[1] *= eye_scale;
    job.frame.camera.eye[2] *= eye_scale;
    job.primary_pgrid = true;
    job.shadow_light_grid = true;
    return job;
}

/* Trace, occlude and render everything (results into *r). */
static bool run_frame(sheaf_context *ctx, const sheaf_ray *rays, results *r, bool deferred) {
    int k;
    uint32_t x, y;
    sheaf_frame f = default_frame(W, H);
    sheaf_trace_params bvh = params_for(SHEAF_METHOD_BVH_RANGED);
    for (k = 0; k < N_TRACES; ++k) {
        sheaf_trace_params p = params_for(trace_methods[k]);
        CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, r->hits[k], N_RAYS));
        CHECK_OK(sheaf_context_occluded(ctx, trace_methods[k], rays, r->occluded[k], N_RAYS));
    }
    memset(r->grid_image, 0, LEN);
    memset(r->bvh_image, 0, LEN);
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_GRID_CGT, &f, r->grid_image, STRIDE, LEN));
    CHECK_OK(sheaf_context_render_with(ctx, &bvh, &bvh, &f, r->bvh_image, STRIDE, LEN));
    r->has_deferred = deferred;
    if (deferred) {
        sheaf_deferred_job job = deferred_job(W, H, 1.0f);
        memset(r->deferred_image, 0, LEN);
        CHECK_OK(sheaf_context_render_deferred(ctx, &job, r->deferred_image, STRIDE, LEN));
        for (y = 0; y < H; ++y) {
            for (x = 0; x < W; ++x) {
                CHECK_OK(sheaf_context_deferred_pixel(ctx, x, y, &r->pixel_hit[y][x], &r->pixel_bits[y][x]));
            }
        }
    }
    return true;
}

/* The deferred pixels of the last frame are still those of `want` (the
 * shared-access queries only; no new frame is rendered). */
static bool pixels_kept(const sheaf_context *ctx, const results *want) {
    uint32_t x, y;
    for (y = 0; y < H; ++y) {
        for (x = 0; x < W; ++x) {
            sheaf_hit h;
            uint8_t bits;
            CHECK_OK(sheaf_context_deferred_pixel(ctx, x, y, &h, &bits));
            CHECK(h.prim == want->pixel_hit[y][x].prim && float_bits(h.t) == float_bits(want->pixel_hit[y][x].t));
            CHECK(bits == want->pixel_bits[y][x]);
        }
    }
    return true;
}

/* Every result of `want` again, bit for bit; first the stats, as `*stats`
 * (unless NULL; then updated to the stats after the new frame), and, when
 * `pixels_now`, the deferred pixels of the last frame. */
static bool results_kept_ext(sheaf_context *ctx, const sheaf_ray *rays, const results *want, sheaf_stats *stats,
                             bool pixels_now) {
    static results again;
    sheaf_stats st;
    int k;
    uint32_t y;
    CHECK_OK(sheaf_context_stats(ctx, &st));
    if (stats != NULL) CHECK(stats_equal(&st, stats));
    if (want->has_deferred && pixels_now) CHECK(pixels_kept(ctx, want));
    CHECK(run_frame(ctx, rays, &again, want->has_deferred));
    for (k = 0; k < N_TRACES; ++k) {
        if (memcmp(again.hits[k], want->hits[k], sizeof again.hits[k]) != 0) {
            fprintf(stderr, "    trace with method %d changed\n", (int)trace_methods[k]);
            return false;
        }
        if (memcmp(again.occluded[k], want->occluded[k], N_RAYS) != 0) {
            fprintf(stderr, "    occluded with method %d changed\n", (int)trace_methods[k]);
            return false;
        }
    }
    for (y = 0; y < H; ++y) {
        CHECK(memcmp(again.grid_image + y * STRIDE, want->grid_image + y * STRIDE, W * 4) == 0);
        CHECK(memcmp(again.bvh_image + y * STRIDE, want->bvh_image + y * STRIDE, W * 4) == 0);
        if (want->has_deferred) {
            CHECK(memcmp(again.deferred_image + y * STRIDE, want->deferred_image + y * STRIDE, W * 4) == 0);
        }
    }
    if (want->has_deferred) CHECK(pixels_kept(ctx, want));
    if (stats != NULL) CHECK_OK(sheaf_context_stats(ctx, stats));
    return true;
}

static bool results_kept(sheaf_context *ctx, const sheaf_ray *rays, const results *want, sheaf_stats *stats) {
    return results_kept_ext(ctx, rays, want, stats, true);
}

static sheaf_limits limits_for(uint32_t max_triangles) {
    sheaf_limits l;
    (void)sheaf_limits_default(max_triangles, &l);
    l.structures = SHEAF_STRUCTURE_GRID | SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_KD | SHEAF_STRUCTURE_PGRID;
    l.max_image_width = 64;
    l.max_image_height = 48;
    return l;
}

static bool build_all(sheaf_context *ctx) {
    CHECK_OK(sheaf_context_build_grid(ctx, NULL));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_build_kd(ctx, NULL));
    CHECK_OK(sheaf_context_build_pgrid(ctx, NULL));
    return true;
}

/* ---- set_geometry larger than the pools ------------------------------------ */

static bool test_set_geometry_over_the_limits_keeps_the_frame(void) {
    static results before;
    scene *s = small_scene();
    scene *big = bigger_scene(10);
    sheaf_limits l = limits_for(s->nt);
    sheaf_context *ctx = NULL;
    sheaf_ray rays[N_RAYS];
    sheaf_stats st;
    char msg[SHEAF_ERROR_MESSAGE_MAX];
    size_t n;
    l.max_vertices = s->nv + 2;
    make_rays(rays);
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(scene_set(ctx, s));
    CHECK(build_all(ctx));
    CHECK(run_frame(ctx, rays, &before, true));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK_OK(sheaf_context_last_error(ctx, msg, sizeof msg, &n));
    CHECK(strcmp(msg, "no error") == 0);

    /* More triangles than max_triangles. */
    CHECK_STATUS(scene_set(ctx, big), SHEAF_STATUS_CAPACITY_TRIANGLES);
    CHECK(last_error_names(ctx, "'triangles'"));
    CHECK(results_kept(ctx, rays, &before, &st));

    /* Few enough triangles, too many vertices (the big scene's first 14
       triangles use its first 12 vertices, but all are counted). */
    big->nt = s->nt;
    CHECK_STATUS(scene_set(ctx, big), SHEAF_STATUS_CAPACITY_VERTICES);
    CHECK(last_error_names(ctx, "'vertices'"));
    CHECK(results_kept(ctx, rays, &before, &st));

    /* The previous geometry is still set: every structure rebuilds from it
       to the same results. */
    CHECK(build_all(ctx));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.triangles_in == s->nt && st.bvh_triangles == s->nt && st.kd_triangles == s->nt);
    CHECK(results_kept(ctx, rays, &before, NULL)); /* new build times */
    sheaf_context_destroy(ctx);
    free(s);
    free(big);
    return true;
}

/* ---- builds that overflow ---------------------------------------------------- */

/* Grid references of `s` with default parameters (a probe context). */
static uint32_t grid_refs_of(const scene *s) {
    sheaf_limits l = limits_for(s->nt);
    sheaf_context *ctx = NULL;
    sheaf_stats st;
    if (sheaf_context_create(&l, &ctx) != SHEAF_STATUS_OK) return 0;
    if (scene_set(ctx, s) != SHEAF_STATUS_OK || sheaf_context_build_grid(ctx, NULL) != SHEAF_STATUS_OK ||
        sheaf_context_stats(ctx, &st) != SHEAF_STATUS_OK) {
        sheaf_context_destroy(ctx);
        return 0;
    }
    sheaf_context_destroy(ctx);
    return st.grid_refs;
}

static bool test_failed_builds_keep_every_structure(void) {
    static results before;
    scene *s = small_scene();
    scene *big = bigger_scene(12);
    uint32_t small_refs = grid_refs_of(s), big_refs = grid_refs_of(big);
    sheaf_limits l = limits_for(big->nt);
    sheaf_context *ctx = NULL;
    sheaf_ray rays[N_RAYS];
    sheaf_stats st;
    sheaf_grid_params gp;
    uint32_t saved;
    CHECK(small_refs > 0 && big_refs > small_refs);
    l.max_grid_refs = small_refs; /* the small scene's grid fits exactly, the big one's does not */
    make_rays(rays);
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(scene_set(ctx, s));
    CHECK(build_all(ctx));
    CHECK(run_frame(ctx, rays, &before, true));
    CHECK_OK(sheaf_context_stats(ctx, &st));

    /* The big scene fits the triangle pools: set_geometry succeeds and the
       built structures stay as they were (they keep their own copies). */
    CHECK_OK(scene_set(ctx, big));
    CHECK(results_kept(ctx, rays, &before, &st));

    /* Grid references overflow. */
    CHECK_STATUS(sheaf_context_build_grid(ctx, NULL), SHEAF_STATUS_CAPACITY_GRID_REFS);
    CHECK(last_error_names(ctx, "'grid_refs'"));
    CHECK(results_kept(ctx, rays, &before, &st));

    /* Grid cells overflow (lambda far above what max_grid_cells allows). */
    CHECK_OK(sheaf_grid_params_default(&gp));
    gp.lambda = 1000.0f;
    CHECK_STATUS(sheaf_context_build_grid(ctx, &gp), SHEAF_STATUS_CAPACITY_GRID_CELLS);
    CHECK(last_error_names(ctx, "'grid_cells'"));
    CHECK(results_kept(ctx, rays, &before, &st));

    /* An index edited in place to be out of range: every build refuses it
       and keeps its structure. */
    saved = big->idx[3 * (big->nt - 1) + 2];
    big->idx[3 * (big->nt - 1) + 2] = big->nv + 5;
    CHECK_STATUS(sheaf_context_build_grid(ctx, NULL), SHEAF_STATUS_INDEX_OUT_OF_RANGE);
    CHECK(results_kept(ctx, rays, &before, &st));
    CHECK_STATUS(sheaf_context_build_bvh(ctx, NULL), SHEAF_STATUS_INDEX_OUT_OF_RANGE);
    CHECK(last_error_names(ctx, "references vertex"));
    CHECK(results_kept(ctx, rays, &before, &st));
    CHECK_STATUS(sheaf_context_build_kd(ctx, NULL), SHEAF_STATUS_INDEX_OUT_OF_RANGE);
    CHECK(results_kept(ctx, rays, &before, &st));
    CHECK_STATUS(sheaf_context_build_pgrid(ctx, NULL), SHEAF_STATUS_INDEX_OUT_OF_RANGE);
    CHECK(results_kept(ctx, rays, &before, &st));
    big->idx[3 * (big->nt - 1) + 2] = saved;

    /* The BVH and kd-tree of the big scene build (their pools are per
       triangle); the grid still does not. */
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_build_kd(ctx, NULL));
    CHECK_STATUS(sheaf_context_build_grid(ctx, NULL), SHEAF_STATUS_CAPACITY_GRID_REFS);
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.triangles_in == s->nt && st.bvh_triangles == big->nt && st.kd_triangles == big->nt);
    {
        /* The grid still traces the small scene exactly as before. */
        sheaf_hit hits[N_RAYS];
        CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_GRID_DDA, rays, hits, N_RAYS));
        CHECK(memcmp(hits, before.hits[0], sizeof hits) == 0);
    }
    sheaf_context_destroy(ctx);
    free(s);
    free(big);
    return true;
}

/* kd pools too small for the tree: not an error, the build makes leaves
 * early (sheaf_limits.max_kd_nodes / max_kd_refs), and the tree traces
 * exactly like the BVH (same triangles, same test). */
static bool test_kd_pools_run_out_gracefully(void) {
    scene *big = bigger_scene(12);
    sheaf_limits l = limits_for(big->nt);
    sheaf_context *ctx = NULL;
    sheaf_ray rays[N_RAYS];
    sheaf_hit kd[N_RAYS], bvh[N_RAYS];
    sheaf_stats st;
    int i;
    l.max_kd_nodes = 3;
    l.max_kd_refs = big->nt + 1;
    make_rays(rays);
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(scene_set(ctx, big));
    CHECK_OK(sheaf_context_build_kd(ctx, NULL));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK(st.kd_nodes <= 3 && st.kd_refs <= big->nt + 1 && st.kd_triangles == big->nt);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_KD_SINGLE, rays, kd, N_RAYS));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, rays, bvh, N_RAYS));
    for (i = 0; i < N_RAYS; ++i) {
        CHECK(kd[i].prim == bvh[i].prim && float_bits(kd[i].t) == float_bits(bvh[i].t));
    }
    sheaf_context_destroy(ctx);
    free(big);
    return true;
}

/* Fewer kd references than triangles can never build (every triangle needs
 * a leaf reference): sheaf_context_create refuses such limits with
 * INVALID_ARGUMENT and writes no context. Found by fuzzing: the limits were
 * accepted and every kd build then failed with CAPACITY_TRIANGLES, naming a
 * pool that was large enough. 0 (the default) and exactly max_triangles
 * are accepted; without the kd-tree's pools the field is not read. */
static bool test_kd_refs_below_triangles_are_invalid(void) {
    sheaf_limits l = limits_for(14);
    sheaf_context *ctx = (sheaf_context *)&l; /* a sentinel: must stay */
    l.max_kd_refs = 1;
    CHECK(sheaf_context_create(&l, &ctx) == SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(ctx == (sheaf_context *)&l);
    l.max_kd_refs = 13;
    CHECK(sheaf_context_create(&l, &ctx) == SHEAF_STATUS_INVALID_ARGUMENT);
    l.max_kd_refs = 14;
    ctx = NULL;
    CHECK_OK(sheaf_context_create(&l, &ctx));
    sheaf_context_destroy(ctx);
    l.max_kd_refs = 1;
    l.structures = SHEAF_STRUCTURE_BVH;
    ctx = NULL;
    CHECK_OK(sheaf_context_create(&l, &ctx));
    sheaf_context_destroy(ctx);
    return true;
}

/* ---- deferred frames that overflow ------------------------------------------ */

/* camera_refs / light_refs / camera_cells of a deferred frame of `job`. */
static bool deferred_sizes(const scene *s, const sheaf_deferred_job *job, sheaf_stats *out) {
    sheaf_limits l = limits_for(s->nt);
    sheaf_context *ctx = NULL;
    static uint8_t img[64 * 48 * 4];
    bool ok;
    l.max_pgrid_refs = 1u << 20;
    if (sheaf_context_create(&l, &ctx) != SHEAF_STATUS_OK) return false;
    ok = scene_set(ctx, s) == SHEAF_STATUS_OK && sheaf_context_build_pgrid(ctx, NULL) == SHEAF_STATUS_OK &&
         sheaf_context_render_deferred(ctx, job, img, job->frame.width * 4, job->frame.width * job->frame.height * 4) ==
             SHEAF_STATUS_OK &&
         sheaf_context_stats(ctx, out) == SHEAF_STATUS_OK;
    sheaf_context_destroy(ctx);
    return ok;
}

static bool test_deferred_overflow_keeps_the_frame(void) {
    static results before;
    static uint8_t img[64 * 48 * 4];
    scene *s = small_scene();
    sheaf_deferred_job a = deferred_job(W, H, 1.0f);
    sheaf_deferred_job near = deferred_job(W, H, 0.35f); /* the box fills the view: more pairs */
    sheaf_deferred_job large = deferred_job(64, 48, 1.0f); /* more tiles: more cells */
    sheaf_stats sa, sn, sl, st;
    sheaf_limits l = limits_for(s->nt);
    sheaf_context *ctx = NULL;
    sheaf_ray rays[N_RAYS];
    uint32_t refs_a, refs_near, cells_a, i;
    CHECK(deferred_sizes(s, &a, &sa) && deferred_sizes(s, &near, &sn) && deferred_sizes(s, &large, &sl));
    refs_a = sa.camera_refs > sa.light_refs ? sa.camera_refs : sa.light_refs;
    refs_near = sn.camera_refs > sn.light_refs ? sn.camera_refs : sn.light_refs;
    CHECK(refs_near > refs_a);
    /* Cells for frames `a` and `near` (the light grid of `near` may need
       more than `a`'s): only the pairs of `near` overflow. */
    cells_a = sa.camera_cells > sa.light_cells ? sa.camera_cells : sa.light_cells;
    if (sn.camera_cells > cells_a) cells_a = sn.camera_cells;
    if (sn.light_cells > cells_a) cells_a = sn.light_cells;
    CHECK(sl.camera_cells > cells_a || sl.light_cells > cells_a);

    /* Pools that hold frame `a`: its pairs exactly. */
    l.max_pgrid_refs = refs_a;
    l.max_pgrid_cells = cells_a;
    make_rays(rays);
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(scene_set(ctx, s));
    CHECK(build_all(ctx));
    CHECK(run_frame(ctx, rays, &before, true));
    CHECK_OK(sheaf_context_stats(ctx, &st));

    /* (triangle, cell) pairs overflow: the documented status, the pool in
       the last error, the framebuffer and the stats untouched. The per-pixel
       results may be gone (NOT_BUILT), but never different. */
    memset(img, SENTINEL, sizeof img);
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &near, img, STRIDE, LEN), SHEAF_STATUS_CAPACITY_PGRID_REFS);
    CHECK(last_error_names(ctx, "pgrid_refs"));
    for (i = 0; i < sizeof img; ++i) CHECK(img[i] == SENTINEL);
    {
        sheaf_stats now;
        sheaf_hit h;
        uint8_t bits;
        sheaf_status ps = sheaf_context_deferred_pixel(ctx, 3, 4, &h, &bits);
        CHECK_OK(sheaf_context_stats(ctx, &now));
        CHECK(stats_equal(&now, &st));
        CHECK(ps == SHEAF_STATUS_NOT_BUILT ||
              (ps == SHEAF_STATUS_OK && h.prim == before.pixel_hit[4][3].prim && bits == before.pixel_bits[4][3]));
    }
    /* Grid, BVH and kd results and a new deferred frame `a`: as before
       (the pixels may have been gone until then: checked above). */
    CHECK(results_kept_ext(ctx, rays, &before, NULL, false));

    /* Cells overflow: a larger image has more tiles. */
    CHECK_OK(sheaf_context_stats(ctx, &st));
    memset(img, SENTINEL, sizeof img);
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &large, img, 64 * 4, sizeof img),
                 SHEAF_STATUS_CAPACITY_PGRID_CELLS);
    CHECK(last_error_names(ctx, "pgrid_cells"));
    for (i = 0; i < sizeof img; ++i) CHECK(img[i] == SENTINEL);
    {
        sheaf_stats now;
        CHECK_OK(sheaf_context_stats(ctx, &now));
        CHECK(stats_equal(&now, &st));
    }
    CHECK(results_kept_ext(ctx, rays, &before, NULL, false));
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

int main(void) {
    int passed = 0, failed = 0;
    run_test("test_set_geometry_over_the_limits_keeps_the_frame", test_set_geometry_over_the_limits_keeps_the_frame,
             &passed, &failed);
    run_test("test_failed_builds_keep_every_structure", test_failed_builds_keep_every_structure, &passed, &failed);
    run_test("test_kd_pools_run_out_gracefully", test_kd_pools_run_out_gracefully, &passed, &failed);
    run_test("test_kd_refs_below_triangles_are_invalid", test_kd_refs_below_triangles_are_invalid, &passed, &failed);
    run_test("test_deferred_overflow_keeps_the_frame", test_deferred_overflow_keeps_the_frame, &passed, &failed);
    return report(passed, failed);
}
