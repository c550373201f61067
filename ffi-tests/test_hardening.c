/*
 * The C ABI under misuse: the geometry borrow ends at clear_geometry (run
 * under valgrind by tests/c_abi.rs: freed buffers are never read again),
 * one light check for every render call, boolean fields received as bytes
 * and checked, outputs that overlap inputs refused, render_rows touching
 * only its rows, and limits whose sizes overflow refused. Every refused
 * call changes nothing.
 */
#include "common.h"

#define W 48
#define H 32
#define STRIDE (W * 4 + 8)
#define LEN ((H - 1) * STRIDE + W * 4)

static scene *ground_and_box(void) {
    scene *s = scene_new();
    scene_ground(s, 6.0f);
    scene_box(s, -1.0f, -1.0f, 0.0f, 1.0f, 1.0f, 1.5f);
    return s;
}

static sheaf_context *context_for(const scene *s, uint32_t structures) {
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    if (sheaf_limits_default(s->nt, &l) != SHEAF_STATUS_OK) return NULL;
    l.structures = structures;
    l.max_image_width = 256;
    l.max_image_height = 256;
    if (sheaf_context_create(&l, &ctx) != SHEAF_STATUS_OK) return NULL;
    return ctx;
}

static bool test_clear_geometry_ends_the_borrow(void) {
    /* The caller's buffers come from malloc so valgrind sees any read after free. */
    scene *s = ground_and_box();
    float *verts = (float *)malloc(sizeof s->v);
    uint32_t *idx = (uint32_t *)malloc(sizeof s->idx), bad[3] = {0, 1, 99999};
    sheaf_context *ctx = context_for(s, SHEAF_STRUCTURE_GRID | SHEAF_STRUCTURE_BVH);
    sheaf_ray rays[64];
    sheaf_hit want[64], got[64];
    char msg[SHEAF_ERROR_MESSAGE_MAX];
    size_t n;
    int i, hits = 0;
    CHECK(ctx != NULL && verts != NULL && idx != NULL);
    memcpy(verts, s->v, sizeof s->v);
    memcpy(idx, s->idx, sizeof s->idx);
    CHECK_OK(sheaf_context_set_geometry(ctx, verts, SCENE_STRIDE, s->nv, idx, s->nt));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    for (i = 0; i < 64; ++i)
        rays[i] = make_ray(-3.0f + 0.1f * (float)i, -5.0f, 0.7f, 0.05f * (float)(i % 7), 1.0f, -0.1f, 0.0f, INFINITY);
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, rays, want, 64));
    for (i = 0; i < 64; ++i) hits += want[i].prim != SHEAF_INVALID_ID;
    CHECK(hits > 16);
    /* A failed set_geometry keeps the old buffers borrowed (documented) ... */
    CHECK_STATUS(sheaf_context_set_geometry(ctx, verts, SCENE_STRIDE, s->nv, bad, 1), SHEAF_STATUS_INDEX_OUT_OF_RANGE);
    CHECK_OK(sheaf_context_build_grid(ctx, NULL)); /* still reads them */
    /* ... until clear_geometry, after which they may be freed. */
    CHECK_OK(sheaf_context_clear_geometry(ctx));
    memset(verts, 0xFF, sizeof s->v); /* poison, then free: no later call may read them */
    free(verts);
    free(idx);
    CHECK_STATUS(sheaf_context_build_bvh(ctx, NULL), SHEAF_STATUS_NO_GEOMETRY);
    CHECK_STATUS(sheaf_context_build_grid(ctx, NULL), SHEAF_STATUS_NO_GEOMETRY);
    CHECK_STATUS(sheaf_context_build_kd(ctx, NULL), SHEAF_STATUS_NO_GEOMETRY);
    CHECK_STATUS(sheaf_context_build_pgrid(ctx, NULL), SHEAF_STATUS_NO_GEOMETRY);
    CHECK_OK(sheaf_context_last_error(ctx, msg, sizeof msg, &n));
    CHECK(strcmp(msg, "no geometry set") == 0);
    /* The built structures keep their own copy and trace as before. */
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, rays, got, 64));
    CHECK(memcmp(got, want, sizeof want) == 0);
    CHECK_OK(sheaf_context_clear_geometry(ctx)); /* clearing twice is fine */
    CHECK_STATUS(sheaf_context_clear_geometry(NULL), SHEAF_STATUS_NULL_POINTER);
    /* New geometry: builds work again. */
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, rays, got, 64));
    CHECK(memcmp(got, want, sizeof want) == 0);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_one_light_check_for_every_render(void) {
    scene *s = ground_and_box();
    sheaf_context *ctx = context_for(s, SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_PGRID);
    sheaf_trace_params p;
    sheaf_frame f = default_frame(W, H);
    sheaf_deferred_job job;
    static uint8_t img[LEN], before[LEN];
    int bad;
    CHECK(ctx != NULL);
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_build_pgrid(ctx, NULL));
    CHECK_OK(sheaf_trace_params_default(&p));
    p.method = SHEAF_METHOD_BVH_SINGLE;
    CHECK_OK(sheaf_context_render(ctx, SHEAF_METHOD_BVH_SINGLE, &f, img, STRIDE, LEN));
    memcpy(before, img, LEN);
    for (bad = 0; bad < 4; ++bad) {
        sheaf_frame g = f;
        if (bad == 0) g.light.position[0] = NAN;
        if (bad == 1) g.light.position[2] = INFINITY;
        if (bad == 2) g.light.spot_angle_deg = 200.0f;
        if (bad == 3) g.light.color[1] = NAN;
        CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_BVH_SINGLE, &g, img, STRIDE, LEN),
                     SHEAF_STATUS_INVALID_ARGUMENT);
        CHECK_STATUS(sheaf_context_render_with(ctx, &p, &p, &g, img, STRIDE, LEN), SHEAF_STATUS_INVALID_ARGUMENT);
        CHECK_STATUS(sheaf_context_render_rows(ctx, 0, &p, &p, &g, 0, 5, img, STRIDE, LEN),
                     SHEAF_STATUS_INVALID_ARGUMENT);
        CHECK_STATUS(sheaf_context_render_whitted(ctx, &p, &p, &p, NULL, &g, NULL, 0, NULL, 0, NULL, 0, img, STRIDE, LEN),
                     SHEAF_STATUS_INVALID_ARGUMENT);
        memset(&job, 0, sizeof job);
        job.frame = g;
        job.primary_pgrid = 1;
        job.shadow_light_grid = 1;
        CHECK_STATUS(sheaf_context_render_deferred(ctx, &job, img, STRIDE, LEN), SHEAF_STATUS_INVALID_ARGUMENT);
        CHECK(memcmp(img, before, LEN) == 0);
    }
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_boolean_bytes_are_checked(void) {
    scene *s = ground_and_box();
    sheaf_context *ctx = context_for(s, SHEAF_STRUCTURE_GRID | SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_PGRID);
    sheaf_trace_params p, q;
    sheaf_grid_params gp;
    sheaf_pgrid_params pp;
    sheaf_limits l;
    sheaf_deferred_job job;
    sheaf_frame f = default_frame(W, H), g;
    sheaf_ray r = make_ray(0.0f, -5.0f, 0.5f, 0.0f, 1.0f, 0.0f, 0.0f, INFINITY);
    sheaf_hit hit;
    uint8_t occ = 7;
    size_t need = 0;
    static uint8_t img[LEN], ok_img[LEN];
    int field;
    CHECK(ctx != NULL);
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_build_grid(ctx, NULL));
    CHECK_OK(sheaf_context_build_pgrid(ctx, NULL));
    CHECK_OK(sheaf_trace_params_default(&p));
    p.method = SHEAF_METHOD_BVH_RANGED;
    p.packet = 4;
    for (field = 0; field < 3; ++field) {
        q = p;
        if (field == 0) q.macrocells = 2;
        if (field == 1) q.mailbox = 2;
        if (field == 2) q.culling = 255;
        hit.prim = 12345;
        CHECK_STATUS(sheaf_context_trace_with(ctx, &q, &r, &hit, 1), SHEAF_STATUS_INVALID_ARGUMENT);
        CHECK_STATUS(sheaf_context_occluded_with(ctx, &q, &r, &occ, 1), SHEAF_STATUS_INVALID_ARGUMENT);
        CHECK(hit.prim == 12345 && occ == 7);
    }
    CHECK_OK(sheaf_grid_params_default(&gp));
    gp.fit = 2;
    CHECK_STATUS(sheaf_context_build_grid(ctx, &gp), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_OK(sheaf_pgrid_params_default(&pp));
    pp.cull_backfaces = 3;
    CHECK_STATUS(sheaf_context_build_pgrid(ctx, &pp), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_OK(sheaf_limits_default(100, &l));
    l.projection_test = 2;
    CHECK_STATUS(sheaf_required_bytes(&l, &need), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(need == 0);
    g = f;
    g.shading.shadows = 2;
    memset(img, 0x33, sizeof img);
    CHECK_STATUS(sheaf_context_render(ctx, SHEAF_METHOD_BVH_SINGLE, &g, img, STRIDE, LEN),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    memset(&job, 0, sizeof job);
    job.frame = f;
    job.primary_pgrid = 2;
    job.shadow_light_grid = 1;
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &job, img, STRIDE, LEN), SHEAF_STATUS_INVALID_ARGUMENT);
    job.primary_pgrid = 1;
    job.shadow_light_grid = 9;
    CHECK_STATUS(sheaf_context_render_deferred(ctx, &job, img, STRIDE, LEN), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(img[0] == 0x33 && img[LEN - 1] == 0x33);
    /* Fields documented as ignored are not checked: garbage in the unused
       trace params of a grid-only deferred frame is fine. */
    job.shadow_light_grid = 1;
    sheaf_trace_params garbage;
    memset(&garbage, 0xEE, sizeof garbage);
    job.primary = &garbage;
    job.shadow = &garbage;
    CHECK_OK(sheaf_context_render_deferred(ctx, &job, img, STRIDE, LEN));
    job.primary_pgrid = 0;
    job.shadow_light_grid = 0;
    job.primary = &p;
    job.shadow = &p;
    memset(ok_img, 0x33, sizeof ok_img); /* the same bytes between rows */
    CHECK_OK(sheaf_context_render_deferred(ctx, &job, ok_img, STRIDE, LEN));
    CHECK(memcmp(img, ok_img, LEN) == 0);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_overlapping_outputs_are_refused(void) {
    scene *s = ground_and_box();
    sheaf_context *ctx = context_for(s, SHEAF_STRUCTURE_BVH);
    sheaf_trace_params p;
    sheaf_frame f = default_frame(W, H);
    sheaf_material *mats;
    sheaf_material_range range = {0, 0};
    sheaf_limits l;
    size_t need = 0;
    void *raw;
    uint8_t *buf;
    sheaf_context *out_ctx = NULL;
    static uint8_t img[LEN + 4 * STRIDE], want[LEN];
    uint32_t y;
    CHECK(ctx != NULL);
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_trace_params_default(&p));
    p.method = SHEAF_METHOD_BVH_SINGLE;
    /* Whitted: a material array inside the framebuffer. */
    memset(img, 0, sizeof img);
    mats = (sheaf_material *)(void *)(img + 64);
    mats->diffuse[0] = mats->diffuse[1] = mats->diffuse[2] = 0.5f;
    mats->reflect = 0.5f;
    mats->transmit = 0.0f;
    mats->ior = 1.0f;
    CHECK_STATUS(sheaf_context_render_whitted(ctx, &p, &p, &p, NULL, &f, NULL, 0, mats, 1, &range, 1, img, STRIDE, LEN),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(mats->reflect == 0.5f && img[0] == 0);
    /* The lights array as the framebuffer's tail. */
    CHECK_STATUS(sheaf_context_render_whitted(ctx, &p, &p, &p, NULL, &f, (const sheaf_light *)(void *)(img + LEN - 8),
                                              1, NULL, 0, NULL, 0, img, STRIDE, LEN),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    /* create_in's output pointer inside its own buffer. */
    CHECK_OK(sheaf_limits_default(64, &l));
    l.structures = SHEAF_STRUCTURE_BVH;
    CHECK_OK(sheaf_required_bytes(&l, &need));
    raw = malloc(need + 2 * SHEAF_CONTEXT_ALIGN);
    CHECK(raw != NULL);
    buf = (uint8_t *)align_up(raw, SHEAF_CONTEXT_ALIGN);
    CHECK_STATUS(sheaf_context_create_in(buf, need, &l, (sheaf_context **)(void *)(buf + 128)),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_OK(sheaf_context_create_in(buf, need, &l, &out_ctx));
    sheaf_context_destroy(out_ctx);
    free(raw);
    /* render_rows with a generous length writes its own rows only. */
    CHECK_OK(sheaf_context_render_with(ctx, &p, &p, &f, want, STRIDE, LEN));
    memset(img, 0x77, sizeof img);
    CHECK_OK(sheaf_context_render_rows(ctx, 0, &p, &p, &f, 4, 9, img + 4 * STRIDE, STRIDE, sizeof img - 4 * STRIDE));
    for (y = 0; y < H; ++y) {
        uint32_t x;
        for (x = 0; x < W * 4; ++x) {
            uint8_t v = img[y * STRIDE + x];
            if (y >= 4 && y < 9) CHECK(v == want[y * STRIDE + x]);
            else CHECK(v == 0x77);
        }
    }
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_limits_that_overflow_are_refused(void) {
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    size_t need = 12345;
    static uint8_t small[4096 + SHEAF_CONTEXT_ALIGN];
    uint8_t *buf = (uint8_t *)align_up(small, SHEAF_CONTEXT_ALIGN);
    CHECK_OK(sheaf_limits_default(1000, &l));
    /* (2^32 - 16 + 16)^2 frame pixels used to wrap to 0: a 5 MB context. */
    l.max_image_width = 0xFFFFFFF0u;
    l.max_image_height = 0xFFFFFFF0u;
    l.max_tile = 16;
    l.structures = SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_PGRID;
    CHECK_STATUS(sheaf_required_bytes(&l, &need), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_create(&l, &ctx), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_create_in(buf, 4096, &l, &ctx), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(need == 12345 && ctx == NULL);
    /* Every pool at its u32 maximum: refused or honestly huge, never wrapped small. */
    CHECK_OK(sheaf_limits_default(0xFFFFFFFFu, &l));
    l.max_vertices = 0xFFFFFFFFu;
    l.max_threads = 1024;
    l.max_grid_cells = 0xFFFFFFFEu;
    l.max_grid_refs = 0xFFFFFFFFu;
    l.max_kd_nodes = 0xFFFFFFFFu;
    l.max_kd_refs = 0xFFFFFFFFu;
    l.projection_test = 1;
    /* (A BVH of more than 2^31 triangles is refused outright.) */
    l.structures = SHEAF_STRUCTURE_GRID | SHEAF_STRUCTURE_KD;
    need = 0;
    {
        sheaf_status st = sheaf_required_bytes(&l, &need);
        CHECK(st == SHEAF_STATUS_INVALID_ARGUMENT || (st == SHEAF_STATUS_OK && need > ((size_t)1 << 40)));
    }
    CHECK_STATUS(sheaf_context_create_in(buf, 4096, &l, &ctx), sizeof(size_t) == 8 ? SHEAF_STATUS_BUFFER_TOO_SMALL
                                                                                   : SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(ctx == NULL);
    return true;
}

/* The hits of rectangle `r` of a `w` x `h` image by `cam` with `p`, each
   sheaf_context_trace_with's hit of sheaf_frame_camera_ray's ray, into a
   buffer of exactly the rectangle's pixels (ASan and valgrind report a
   write past it). */
static bool camera_rect_is_exact(sheaf_context *ctx, const sheaf_trace_params *p, const sheaf_camera *cam,
                                 uint32_t w, uint32_t h, sheaf_pixel_rect r) {
    size_t row = r.x1 - r.x0, n = row * (r.y1 - r.y0);
    sheaf_hit *got = (sheaf_hit *)malloc(n * sizeof *got), want;
    sheaf_frame f;
    sheaf_ray ray;
    uint32_t x, y;
    bool ok = got != NULL;
    memset(&f, 0, sizeof f);
    f.camera = *cam, f.width = w, f.height = h;
    ok = ok && sheaf_context_trace_camera(ctx, p, cam, w, h, &r, got, row) == SHEAF_STATUS_OK;
    for (y = r.y0; ok && y < r.y1; ++y)
        for (x = r.x0; ok && x < r.x1; ++x) {
            const sheaf_hit *g = &got[(y - r.y0) * row + (x - r.x0)];
            ok = sheaf_frame_camera_ray(&f, x, y, &ray) == SHEAF_STATUS_OK &&
                 sheaf_context_trace_with(ctx, p, &ray, &want, 1) == SHEAF_STATUS_OK && g->prim == want.prim &&
                 memcmp(&g->t, &want.t, sizeof(float)) == 0;
        }
    free(got);
    return ok;
}

static bool test_camera_rectangles_at_the_u32_edge(void) {
    /* Rectangles inside UINT32_MAX x 2, 2 x UINT32_MAX and UINT32_MAX^2
       images at their far edges, for packet methods of every side (whose
       packets overhang the rectangle past 2^32) and single rays: accepted,
       exactly the rectangle's pixels written, each the single ray's hit. */
    scene *s = ground_and_box();
    sheaf_context *ctx = context_for(s, SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_GRID);
    sheaf_camera cam;
    sheaf_trace_params p;
    const uint32_t M = UINT32_MAX;
    uint32_t sides[5] = {2, 4, 8, 16, 32};
    sheaf_method methods[3] = {SHEAF_METHOD_BVH_FRUSTUM, SHEAF_METHOD_BVH_RANGED, SHEAF_METHOD_GRID_CGT};
    struct {
        uint32_t w, h;
        sheaf_pixel_rect r;
    } cases[5] = {{M, 2, {M - 5, 0, M, 2}},
                  {2, M, {0, M - 5, 2, M}},
                  {M, M, {M - 7, M - 3, M, M}},
                  {M, M, {M - 1, M - 1, M, M}},
                  {M, 3, {M - 33, 0, M, 3}}};
    int c, m, k;
    CHECK(ctx != NULL);
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_build_grid(ctx, NULL));
    memset(&cam, 0, sizeof cam);
    cam.eye[0] = 6.0f, cam.eye[1] = -8.0f, cam.eye[2] = 5.0f;
    cam.look_at[2] = 0.5f;
    cam.up[2] = 1.0f;
    cam.fov_y_deg = 40.0f;
    CHECK_OK(sheaf_trace_params_default(&p));
    for (c = 0; c < 5; ++c)
        for (m = 0; m < 3; ++m)
            for (k = 0; k < 5; ++k) {
                p.method = methods[m];
                p.packet = sides[k];
                CHECK(camera_rect_is_exact(ctx, &p, &cam, cases[c].w, cases[c].h, cases[c].r));
            }
    p.method = SHEAF_METHOD_BVH_SINGLE;
    CHECK(camera_rect_is_exact(ctx, &p, &cam, M, 2, cases[0].r));
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_cameras_of_any_scale(void) {
    /* A camera's vectors are normalised at any finite scale: up of 1e20
       or 1e-30, an eye 3e19 away give the unit camera's rays (distinct per
       pixel); only a degenerate basis is refused. */
    sheaf_frame f, g;
    sheaf_ray a, b;
    uint32_t x, y, k;
    memset(&f, 0, sizeof f);
    f.camera.eye[1] = -4.0f;
    f.camera.up[2] = 1.0f;
    f.camera.fov_y_deg = 50.0f;
    f.width = 64, f.height = 48;
    for (k = 0; k < 3; ++k) {
        g = f;
        if (k == 0) g.camera.up[2] = 1e20f;
        if (k == 1) g.camera.up[2] = 1e-30f;
        if (k == 2) g.camera.eye[1] = -3e19f;
        for (y = 0; y < 48; y += 47)
            for (x = 0; x < 64; x += 63) {
                float la, lb;
                int i;
                CHECK_OK(sheaf_frame_camera_ray(&f, x, y, &a));
                CHECK_OK(sheaf_frame_camera_ray(&g, x, y, &b));
                la = sqrtf(a.dir[0] * a.dir[0] + a.dir[1] * a.dir[1] + a.dir[2] * a.dir[2]);
                lb = sqrtf(b.dir[0] * b.dir[0] + b.dir[1] * b.dir[1] + b.dir[2] * b.dir[2]);
                for (i = 0; i < 3; ++i) CHECK(fabsf(a.dir[i] / la - b.dir[i] / lb) < 1e-5f);
            }
    }
    g = f;
    g.camera.up[2] = 0.0f;
    CHECK_STATUS(sheaf_frame_camera_ray(&g, 0, 0, &b), SHEAF_STATUS_INVALID_ARGUMENT);
    g.camera.up[1] = 1e25f; /* parallel to the view */
    CHECK_STATUS(sheaf_frame_camera_ray(&g, 0, 0, &b), SHEAF_STATUS_INVALID_ARGUMENT);
    return true;
}

static bool test_refused_bvh_builds_keep_the_tree(void) {
    /* A BVH build refused after its parameters passed (the projection
       test without its pool; capacity is refused earlier, at
       set_geometry) keeps the previous trees: the frustum walk gives the
       same hits and the stats the same tree. */
    scene *s = scene_new();
    sheaf_context *ctx;
    sheaf_trace_params p;
    sheaf_bvh_params bp;
    sheaf_stats before, after;
    sheaf_hit h0[64], h1[64];
    sheaf_ray rays[64];
    int i, j;
    /* A field of boxes: a tree deep enough that the 4-wide walk and the
       binary one count different node tests. */
    scene_ground(s, 10.0f);
    for (i = -4; i <= 4; ++i)
        for (j = -4; j <= 4; ++j)
            scene_box(s, 2.0f * (float)i - 0.5f, 2.0f * (float)j - 0.5f, 0.0f, 2.0f * (float)i + 0.5f,
                      2.0f * (float)j + 0.5f, 0.5f + 0.1f * (float)((i * 3 + j + 40) % 7));
    ctx = context_for(s, SHEAF_STRUCTURE_BVH);
    CHECK(ctx != NULL);
    for (i = 0; i < 64; ++i)
        rays[i] = make_ray(-7.5f + 0.23f * (float)i, -7.0f + 0.21f * (float)i, 5.0f, 0.01f, 0.02f, -1.0f, 0.0f,
                           INFINITY);
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_bvh_params_default(&bp));
    CHECK_OK(sheaf_trace_params_default(&p));
    p.method = SHEAF_METHOD_BVH_FRUSTUM;
    p.packet = 8;
    for (i = 0; i < 2; ++i) {
        bp.quality = i ? SHEAF_BUILD_QUALITY_LOW : SHEAF_BUILD_QUALITY_MEDIUM;
        CHECK_OK(sheaf_context_build_bvh(ctx, &bp));
        CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, h0, 64));
        CHECK_OK(sheaf_context_stats(ctx, &before));
        bp.test = SHEAF_TRI_TEST_PROJECTION; /* no projection pool */
        CHECK_STATUS(sheaf_context_build_bvh(ctx, &bp), SHEAF_STATUS_INVALID_ARGUMENT);
        bp.test = SHEAF_TRI_TEST_MOLLER_TRUMBORE;
        CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, h1, 64));
        CHECK_OK(sheaf_context_stats(ctx, &after));
        CHECK(memcmp(h0, h1, sizeof h0) == 0);
        /* The last build's figures stand (the wide tree itself is checked
           by the Rust test errors_leave_previous_build: C sees no counter
           of it). */
        CHECK(before.bvh_nodes == after.bvh_nodes && before.bvh_leaves == after.bvh_leaves &&
              before.bvh_triangles == after.bvh_triangles && before.bvh_nodes > 0);
    }
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_row_bands_at_the_u32_edge(void) {
    /* The last rows of a 2 x UINT32_MAX frame as a band, with packets of
       every side (tile origins stepped past 2^32 wrapped to row 0): OK,
       only the band's bytes written (a buffer of exactly its rows), the
       same pixels as the single-ray render of those rows. */
    scene *s = ground_and_box();
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    sheaf_frame f = default_frame(2, UINT32_MAX);
    sheaf_trace_params p, single;
    uint32_t sides[5] = {2, 4, 8, 16, 32}, k;
    uint8_t want[3 * 8], *got = (uint8_t *)malloc(3 * 8);
    CHECK(got != NULL);
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    l.structures = SHEAF_STRUCTURE_BVH;
    l.max_image_width = 2;
    l.max_image_height = UINT32_MAX;
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_trace_params_default(&single));
    single.method = SHEAF_METHOD_BVH_SINGLE;
    CHECK_OK(sheaf_context_render_rows(ctx, 0, &single, &single, &f, UINT32_MAX - 3, UINT32_MAX, want, 8, 24));
    p = single;
    p.method = SHEAF_METHOD_BVH_RANGED;
    for (k = 0; k < 5; ++k) {
        p.packet = sides[k];
        memset(got, 0, 24);
        CHECK_OK(sheaf_context_render_rows(ctx, 0, &p, &p, &f, UINT32_MAX - 3, UINT32_MAX, got, 8, 24));
        CHECK(memcmp(got, want, 24) == 0);
    }
    free(got);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

int main(void) {
    int passed = 0, failed = 0;
    run_test("test_clear_geometry_ends_the_borrow", test_clear_geometry_ends_the_borrow, &passed, &failed);
    run_test("test_one_light_check_for_every_render", test_one_light_check_for_every_render, &passed, &failed);
    run_test("test_boolean_bytes_are_checked", test_boolean_bytes_are_checked, &passed, &failed);
    run_test("test_overlapping_outputs_are_refused", test_overlapping_outputs_are_refused, &passed, &failed);
    run_test("test_limits_that_overflow_are_refused", test_limits_that_overflow_are_refused, &passed, &failed);
    run_test("test_camera_rectangles_at_the_u32_edge", test_camera_rectangles_at_the_u32_edge, &passed, &failed);
    run_test("test_cameras_of_any_scale", test_cameras_of_any_scale, &passed, &failed);
    run_test("test_refused_bvh_builds_keep_the_tree", test_refused_bvh_builds_keep_the_tree, &passed, &failed);
    run_test("test_row_bands_at_the_u32_edge", test_row_bands_at_the_u32_edge, &passed, &failed);
    return report(passed, failed);
}
