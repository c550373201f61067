/*
 * Any-hit filters through the C ABI: a cut-out filter on the single mesh and
 * on a scene geometry, every method bitwise its family's single ray with it,
 * the candidate's ids, force-opaque calls and opaque geometries skipping it,
 * bad input refused with nothing changed, and a filter calling back into
 * sheaf refused with SHEAF_STATUS_REENTRANT.
 */
#include "common.h"

/* What a filter saw. */
typedef struct seen {
    unsigned long calls;
    uint32_t geometries; /* bit per geometry id seen (ids < 32) */
    uint32_t instances;  /* bit per instance id seen, bit 31: SHEAF_INVALID_ID */
    /* Re-entry: a context to call into from inside the filter, and the
     * statuses those calls returned. */
    sheaf_context *reenter;
    sheaf_status inner[3];
} seen;

/* The cut-out: holes in a pattern of (u, v) cells shifted by the triangle
 * (the same for every instance, so scene hits check it without ids). */
static bool keep(float u, float v, uint32_t prim) {
    return ((uint32_t)(u * 8.0f) + (uint32_t)(v * 8.0f) + prim) % 3u != 0u;
}

static bool cutout(void *user, const sheaf_candidate *c) {
    seen *s = (seen *)user;
    if (s != NULL) {
        s->calls++;
        if (c->geometry < 32u) s->geometries |= 1u << c->geometry;
        s->instances |= c->instance == SHEAF_INVALID_ID ? 1u << 31 : 1u << (c->instance & 31u);
        if (s->reenter != NULL) {
            sheaf_ray r = make_ray(0.0f, 0.0f, 5.0f, 0.0f, 0.0f, -1.0f, 0.0f, INFINITY);
            sheaf_hit h;
            sheaf_stats st;
            s->inner[0] = sheaf_context_trace(s->reenter, SHEAF_METHOD_BVH_SINGLE, &r, &h, 1);
            s->inner[1] = sheaf_context_set_filter(s->reenter, NULL, NULL);
            s->inner[2] = sheaf_context_stats(s->reenter, &st);
        }
    }
    return keep(c->u, c->v, c->prim);
}

/* Ground, boxes of several heights: 62 triangles. */
static scene *boxes(void) {
    scene *s = scene_new();
    int i, j;
    scene_ground(s, 4.0f);
    for (i = 0; i < 3; ++i)
        for (j = 0; j < 2; ++j) {
            float x = -2.5f + 2.0f * (float)i, y = -1.5f + 2.0f * (float)j;
            scene_box(s, x, y, 0.0f, x + 1.2f, y + 1.2f, 0.5f + 0.4f * (float)(i + j));
        }
    return s;
}

/* 32 x 32 rays looking down at the boxes, in 8 x 8 packets' order (each
 * 64 consecutive rays one packet, quads of 2 x 2 in rows). */
#define SIDE 32
#define NRAYS (SIDE * SIDE)
static void camera(sheaf_ray *rays) {
    int k = 0, px, py, qx, qy, l;
    for (py = 0; py < SIDE; py += 8)
        for (px = 0; px < SIDE; px += 8)
            for (qy = 0; qy < 8; qy += 2)
                for (qx = 0; qx < 8; qx += 2)
                    for (l = 0; l < 4; ++l) {
                        int x = px + qx + (l & 1), y = py + qy + (l >> 1);
                        float dx = ((float)x + 0.5f) / SIDE - 0.5f, dy = ((float)y + 0.5f) / SIDE - 0.5f;
                        rays[k++] = make_ray(0.3f, 0.2f, 6.0f, 0.9f * dx, 0.9f * dy, -1.0f, 0.0f, INFINITY);
                    }
}

static sheaf_trace_params params(sheaf_method m) {
    sheaf_trace_params p;
    sheaf_trace_params_default(&p);
    p.method = (uint32_t)m;
    p.packet = 8;
    return p;
}

static bool same_hit(const sheaf_hit *a, const sheaf_hit *b) {
    return a->prim == b->prim && float_bits(a->t) == float_bits(b->t) &&
           float_bits(a->u) == float_bits(b->u) && float_bits(a->v) == float_bits(b->v);
}

static bool test_single_mesh_methods_with_a_filter(void) {
    static const sheaf_method single[3] = {SHEAF_METHOD_GRID_DDA, SHEAF_METHOD_BVH_SINGLE,
                                           SHEAF_METHOD_KD_SINGLE};
    static const sheaf_method packets[3][4] = {
        {SHEAF_METHOD_GRID_CGT, SHEAF_METHOD_GRID_CGT, SHEAF_METHOD_GRID_CGT, SHEAF_METHOD_GRID_CGT},
        {SHEAF_METHOD_BVH_SIMD, SHEAF_METHOD_BVH_MASKED, SHEAF_METHOD_BVH_RANGED, SHEAF_METHOD_BVH_FRUSTUM},
        {SHEAF_METHOD_KD_SIMD, SHEAF_METHOD_KD_PACKET, SHEAF_METHOD_KD_PACKET, SHEAF_METHOD_KD_PACKET}};
    scene *s = boxes();
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    static sheaf_ray rays[NRAYS];
    static sheaf_hit open[NRAYS], want[NRAYS], got[NRAYS];
    static uint8_t occ[NRAYS];
    seen sn;
    sheaf_trace_params p;
    int f, m, i, moved = 0;
    unsigned long before;
    memset(&sn, 0, sizeof sn);
    camera(rays);
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_context_build_grid(ctx, NULL));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_build_kd(ctx, NULL));
    p = params(SHEAF_METHOD_BVH_SINGLE);
    CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, open, NRAYS));
    CHECK_OK(sheaf_context_set_filter(ctx, cutout, &sn));
    for (f = 0; f < 3; ++f) {
        p = params(single[f]);
        CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, want, NRAYS));
        for (i = 0; i < NRAYS; ++i) {
            /* Every hit left is one the filter accepts. */
            CHECK(want[i].prim == SHEAF_INVALID_ID || keep(want[i].u, want[i].v, want[i].prim));
            moved += f == 1 && !same_hit(&want[i], &open[i]);
        }
        /* Occlusion: whether a filtered hit exists. */
        CHECK_OK(sheaf_context_occluded(ctx, single[f], rays, occ, NRAYS));
        for (i = 0; i < NRAYS; ++i) CHECK(occ[i] == (want[i].prim != SHEAF_INVALID_ID));
        for (m = 0; m < 4; ++m) {
            p = params(packets[f][m]);
            p.packet = m == 3 ? 16 : 8;
            CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, got, NRAYS));
            for (i = 0; i < NRAYS; ++i) CHECK(same_hit(&got[i], &want[i]));
        }
        /* Forced opacity: the unfiltered hits, no filter call. */
        before = sn.calls;
        p = params(packets[f][1]);
        p.force_opaque = 1;
        CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, got, NRAYS));
        for (i = 0; i < NRAYS; ++i) CHECK(float_bits(got[i].t) == float_bits(open[i].t));
        CHECK(sn.calls == before);
    }
    CHECK(moved > NRAYS / 20);
    CHECK(sn.calls > 0 && sn.geometries == 1u && sn.instances == 1u << 31);
    /* Removed: the unfiltered hits again. */
    CHECK_OK(sheaf_context_set_filter(ctx, NULL, NULL));
    p = params(SHEAF_METHOD_KD_PACKET);
    CHECK_OK(sheaf_context_trace_with(ctx, &p, rays, got, NRAYS));
    for (i = 0; i < NRAYS; ++i) CHECK(float_bits(got[i].t) == float_bits(open[i].t));
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

/* `s` as a sheaf_mesh (read during the call that takes it). */
static sheaf_mesh scene_mesh(const scene *s) {
    sheaf_mesh m;
    m.vertices = &s->v[0][0];
    m.vertex_stride_bytes = SCENE_STRIDE;
    m.vertex_count = s->nv;
    m.indices = s->idx;
    m.triangle_count = s->nt;
    return m;
}

static bool scene_ctx(sheaf_context **out, const scene *s) {
    sheaf_limits l;
    sheaf_mesh m;
    float x[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    CHECK_OK(sheaf_limits_default(16, &l));
    l.structures = SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_GRID;
    l.max_triangles = 4 * s->nt;
    l.max_geometries = 2;
    l.max_instances = 3;
    l.max_scene_triangles = 2 * s->nt;
    CHECK_OK(sheaf_context_create(&l, out));
    m = scene_mesh(s);
    CHECK_OK(sheaf_context_set_scene_geometry(*out, 0, &m, NULL));
    CHECK_OK(sheaf_context_set_scene_geometry(*out, 1, &m, NULL));
    CHECK_OK(sheaf_context_set_instance(*out, 0, 0, x, ~0u));
    x[3] = 0.25f;
    x[11] = 0.6f;
    CHECK_OK(sheaf_context_set_instance(*out, 1, 1, x, ~0u));
    x[3] = -0.4f;
    x[7] = 0.3f;
    x[11] = 1.2f;
    CHECK_OK(sheaf_context_set_instance(*out, 2, 0, x, ~0u));
    CHECK_OK(sheaf_context_commit_scene(*out, NULL));
    return true;
}

static bool test_scene_filters_ids_and_opacity(void) {
    scene *s = boxes();
    sheaf_context *ctx = NULL;
    static sheaf_ray rays[NRAYS];
    static sheaf_scene_hit open[NRAYS], want[NRAYS], got[NRAYS];
    sheaf_geometry_params gp;
    sheaf_mesh m;
    seen sn;
    sheaf_trace_params p;
    int i, moved = 0;
    unsigned long before;
    static const sheaf_method methods[4] = {SHEAF_METHOD_BVH_SIMD, SHEAF_METHOD_BVH_MASKED,
                                            SHEAF_METHOD_BVH_FRUSTUM, SHEAF_METHOD_GRID_CGT};
    memset(&sn, 0, sizeof sn);
    camera(rays);
    if (!scene_ctx(&ctx, s)) return false;
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, open, NRAYS, ~0u, 0));
    /* Geometry 0 (instances 0 and 2) cut out. */
    CHECK_OK(sheaf_context_set_scene_geometry_filter(ctx, 0, cutout, &sn));
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, want, NRAYS, ~0u, 0));
    for (i = 0; i < NRAYS; ++i) {
        CHECK(want[i].geometry != 0 || keep(want[i].u, want[i].v, want[i].prim));
        moved += float_bits(want[i].t) != float_bits(open[i].t);
    }
    CHECK(moved > NRAYS / 20);
    CHECK(sn.geometries == 1u && sn.instances == 5u);
    /* Every BVH method through the instances, and CGT on the flattened
     * scene against the 3DDDA there, bit for bit. */
    CHECK_OK(sheaf_context_build_scene_grid(ctx, NULL, ~0u));
    for (i = 0; i < 4; ++i) {
        int k;
        p = params(methods[i]);
        if (methods[i] == SHEAF_METHOD_GRID_CGT) {
            sheaf_trace_params dda = params(SHEAF_METHOD_GRID_DDA);
            CHECK_OK(sheaf_context_trace_scene(ctx, &dda, rays, want, NRAYS, ~0u, 0));
            for (k = 0; k < NRAYS; ++k)
                CHECK(want[k].geometry != 0 || keep(want[k].u, want[k].v, want[k].prim));
        }
        CHECK_OK(sheaf_context_trace_scene(ctx, &p, rays, got, NRAYS, ~0u, 0));
        for (k = 0; k < NRAYS; ++k) {
            CHECK(got[k].prim == want[k].prim && got[k].instance == want[k].instance);
            CHECK(float_bits(got[k].t) == float_bits(want[k].t));
        }
    }
    /* The ray flag forces opacity: no call, the unfiltered hits. */
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, want, NRAYS, ~0u, 0));
    before = sn.calls;
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, got, NRAYS, ~0u, SHEAF_RAY_FLAG_FORCE_OPAQUE));
    for (i = 0; i < NRAYS; ++i) CHECK(float_bits(got[i].t) == float_bits(open[i].t));
    CHECK(sn.calls == before);
    /* An opaque geometry skips the filter its params carry. */
    CHECK_OK(sheaf_geometry_params_default(&gp));
    gp.filter = cutout;
    gp.filter_user = &sn;
    gp.opaque = 1;
    m = scene_mesh(s);
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 0, &m, &gp));
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, got, NRAYS, ~0u, 0));
    for (i = 0; i < NRAYS; ++i) CHECK(float_bits(got[i].t) == float_bits(open[i].t));
    CHECK(sn.calls == before);
    /* Not opaque: the params' filter is the geometry's. */
    gp.opaque = 0;
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 0, &m, &gp));
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, got, NRAYS, ~0u, 0));
    for (i = 0; i < NRAYS; ++i) CHECK(float_bits(got[i].t) == float_bits(want[i].t));
    CHECK(sn.calls > before);
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_bad_filter_input_changes_nothing(void) {
    scene *s = boxes();
    sheaf_context *ctx = NULL;
    static sheaf_ray rays[NRAYS];
    static sheaf_scene_hit want[NRAYS], got[NRAYS];
    sheaf_geometry_params gp;
    sheaf_trace_params p;
    sheaf_mesh m;
    seen sn;
    unsigned long before;
    int dummy = 0, i;
    memset(&sn, 0, sizeof sn);
    camera(rays);
    if (!scene_ctx(&ctx, s)) return false;
    /* Geometry 1 removed (its instance first): its id is not set. */
    CHECK_OK(sheaf_context_remove_instance(ctx, 1));
    CHECK_OK(sheaf_context_remove_scene_geometry(ctx, 1));
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    CHECK_OK(sheaf_context_set_scene_geometry_filter(ctx, 0, cutout, &sn));
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, want, NRAYS, ~0u, 0));
    /* Ids not set, a pointer without a function, bad flags. */
    CHECK_STATUS(sheaf_context_set_scene_geometry_filter(ctx, 1u << 20, cutout, &sn),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_set_scene_geometry_filter(ctx, 1, cutout, &sn),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_set_scene_geometry_filter(ctx, 0, NULL, &dummy),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_set_filter(ctx, NULL, &dummy), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_set_filter(NULL, cutout, NULL), SHEAF_STATUS_NULL_POINTER);
    CHECK_OK(sheaf_geometry_params_default(&gp));
    gp.filter_user = &dummy;
    m = scene_mesh(s);
    CHECK_STATUS(sheaf_context_set_scene_geometry(ctx, 0, &m, &gp), SHEAF_STATUS_INVALID_ARGUMENT);
    gp.filter_user = NULL;
    gp.opaque = 2;
    CHECK_STATUS(sheaf_context_set_scene_geometry(ctx, 0, &m, &gp), SHEAF_STATUS_INVALID_ARGUMENT);
    p = params(SHEAF_METHOD_BVH_MASKED);
    p.force_opaque = 2;
    CHECK_STATUS(sheaf_context_trace_scene(ctx, &p, rays, got, NRAYS, ~0u, 0),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_trace_scene(ctx, NULL, rays, got, NRAYS, ~0u, 8u),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    /* Nothing changed: geometry 0 keeps its filter, the hits their bits. */
    before = sn.calls;
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, got, NRAYS, ~0u, 0));
    CHECK(sn.calls > before);
    for (i = 0; i < NRAYS; ++i) {
        CHECK(got[i].prim == want[i].prim && got[i].instance == want[i].instance);
        CHECK(float_bits(got[i].t) == float_bits(want[i].t));
    }
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

static bool test_a_filter_calling_sheaf_is_refused(void) {
    scene *s = boxes();
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    static sheaf_ray rays[NRAYS];
    static sheaf_hit want[NRAYS], got[NRAYS];
    seen sn;
    sheaf_stats st;
    int i;
    memset(&sn, 0, sizeof sn);
    camera(rays);
    CHECK_OK(sheaf_limits_default(s->nt, &l));
    CHECK_OK(sheaf_context_create(&l, &ctx));
    CHECK_OK(scene_set(ctx, s));
    CHECK_OK(sheaf_context_build_bvh(ctx, NULL));
    CHECK_OK(sheaf_context_set_filter(ctx, cutout, &sn));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, rays, want, NRAYS));
    sn.reenter = ctx;
    for (i = 0; i < 3; ++i) sn.inner[i] = SHEAF_STATUS_OK;
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_MASKED, rays, got, NRAYS));
    for (i = 0; i < 3; ++i) CHECK_STATUS(sn.inner[i], SHEAF_STATUS_REENTRANT);
    /* The refused calls changed nothing: the filter stays, the hits too. */
    for (i = 0; i < NRAYS; ++i) CHECK(float_bits(got[i].t) == float_bits(want[i].t));
    sn.reenter = NULL;
    CHECK_OK(sheaf_context_stats(ctx, &st));
    CHECK_OK(sheaf_context_trace(ctx, SHEAF_METHOD_BVH_SINGLE, rays, got, NRAYS));
    for (i = 0; i < NRAYS; ++i) CHECK(float_bits(got[i].t) == float_bits(want[i].t));
    sheaf_context_destroy(ctx);
    free(s);
    return true;
}

int main(void) {
    int passed = 0, failed = 0;
    run_test("test_single_mesh_methods_with_a_filter", test_single_mesh_methods_with_a_filter, &passed,
             &failed);
    run_test("test_scene_filters_ids_and_opacity", test_scene_filters_ids_and_opacity, &passed, &failed);
    run_test("test_bad_filter_input_changes_nothing", test_bad_filter_input_changes_nothing, &passed,
             &failed);
    run_test("test_a_filter_calling_sheaf_is_refused", test_a_filter_calling_sheaf_is_refused, &passed,
             &failed);
    return report(passed, failed);
}
