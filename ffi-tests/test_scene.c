/*
 * The two-level scene through the C ABI: geometries set, updated (refit and
 * rebuild) and removed, instances placing them, commits, traces with ids and
 * masks, and every bad input refused with its status and nothing changed.
 */
#include "common.h"

/* A unit square (two triangles) in the plane z = 0, x and y in [0, 1]. */
static const float SQUARE_V[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
static const uint32_t SQUARE_I[6] = {0, 1, 2, 0, 2, 3};

static sheaf_mesh square(void) {
    sheaf_mesh m;
    m.vertices = &SQUARE_V[0][0];
    m.vertex_stride_bytes = 12;
    m.vertex_count = 4;
    m.indices = SQUARE_I;
    m.triangle_count = 2;
    return m;
}

/* A pyramid of 6 triangles (a square base at y = 0, apex at y = 1.5). */
static const float PYR_V[5][3] = {{-1, 0, -1}, {1, 0, -1}, {1, 0, 1}, {-1, 0, 1}, {0, 1.5f, 0}};
static const uint32_t PYR_I[18] = {0, 1, 4, 1, 2, 4, 2, 3, 4, 3, 0, 4, 0, 2, 1, 0, 3, 2};

static sheaf_mesh pyramid(void) {
    sheaf_mesh m;
    m.vertices = &PYR_V[0][0];
    m.vertex_stride_bytes = 12;
    m.vertex_count = 5;
    m.indices = PYR_I;
    m.triangle_count = 6;
    return m;
}

/* The camera ray of pixel (x, y) of an n x n image looking down -z from
 * (0, 0.8, 6) at the pyramids. */
static sheaf_ray eye_ray(int x, int y, int n) {
    sheaf_ray r;
    float c = 0.5f * (float)(n - 1);
    r.org[0] = 0.0f;
    r.org[1] = 0.8f;
    r.org[2] = 6.0f;
    r.dir[0] = ((float)x - c) / (float)n * 0.8f;
    r.dir[1] = ((float)y - c) / (float)n * 0.6f - 0.1f;
    r.dir[2] = -1.0f;
    r.tmin = 0.0f;
    r.tmax = INFINITY;
    return r;
}

static sheaf_context *scene_context(uint32_t geometries, uint32_t instances, uint32_t budget) {
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    if (sheaf_limits_default(16, &l) != SHEAF_STATUS_OK)
        return NULL;
    l.structures = SHEAF_STRUCTURE_BVH;
    l.max_geometries = geometries;
    l.max_instances = instances;
    l.max_scene_triangles = budget;
    if (sheaf_context_create(&l, &ctx) != SHEAF_STATUS_OK)
        return NULL;
    return ctx;
}

/* Row-major 3x4: a translation by (x, y, z), scaled by s. */
static void placed(float m[12], float s, float x, float y, float z) {
    int i;
    for (i = 0; i < 12; ++i)
        m[i] = 0.0f;
    m[0] = m[5] = m[10] = s;
    m[3] = x;
    m[7] = y;
    m[11] = z;
}

static sheaf_ray down_at(float x, float y) {
    sheaf_ray r;
    r.org[0] = x;
    r.org[1] = y;
    r.org[2] = 10.0f;
    r.dir[0] = 0.0f;
    r.dir[1] = 0.0f;
    r.dir[2] = -1.0f;
    r.tmin = 0.0f;
    r.tmax = INFINITY;
    return r;
}

static bool test_instances_ids_and_masks(void) {
    sheaf_context *ctx = scene_context(2, 4, 64);
    sheaf_mesh m = square();
    sheaf_geometry_params p;
    sheaf_scene_info info;
    sheaf_ray rays[4];
    sheaf_scene_hit hits[4];
    uint8_t occ[4];
    float xf[12];
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_geometry_params_default(&p));
    CHECK(p.mode == SHEAF_UPDATE_MODE_STATIC && p.mask == ~0u);
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 0, &m, &p));
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 1, &m, NULL));
    /* Instance 0: geometry 0 at z = 1; instance 1: geometry 1 at z = 2,
     * twice as large, shifted to x in [2, 4]; instance 2: geometry 0 at z = 3
     * over instance 0, mask 2 only. */
    placed(xf, 1.0f, 0.0f, 0.0f, 1.0f);
    CHECK_OK(sheaf_context_set_instance(ctx, 0, 0, xf, 1));
    placed(xf, 2.0f, 2.0f, 0.0f, 2.0f);
    CHECK_OK(sheaf_context_set_instance(ctx, 1, 1, xf, 1));
    placed(xf, 1.0f, 0.0f, 0.0f, 3.0f);
    CHECK_OK(sheaf_context_set_instance(ctx, 2, 0, xf, 2));
    rays[0] = down_at(0.25f, 0.5f);
    rays[1] = down_at(3.0f, 1.5f);
    rays[2] = down_at(1.5f, 0.5f); /* between the instances: a miss */
    rays[3] = down_at(0.75f, 0.25f);
    CHECK_STATUS(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, ~0u, 0), SHEAF_STATUS_NOT_BUILT);
    CHECK_OK(sheaf_context_commit_scene(ctx, &info));
    CHECK(info.geometries == 2 && info.instances == 3 && info.instanced_triangles == 6);
    CHECK(info.free_triangles == 60 && info.largest_free_run == 60 && info.compactions == 0);
    CHECK(info.bounds_min[0] <= 0.0f && info.bounds_max[0] >= 4.0f && info.bounds_max[2] >= 3.0f);
    /* Mask 1: instances 0 and 1. */
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, 1, 0));
    CHECK(hits[0].instance == 0 && hits[0].geometry == 0 && hits[0].t == 9.0f);
    CHECK(hits[1].instance == 1 && hits[1].geometry == 1 && hits[1].t == 8.0f);
    CHECK(hits[2].prim == SHEAF_INVALID_ID && hits[2].instance == SHEAF_INVALID_ID && hits[2].t == INFINITY);
    CHECK(hits[3].instance == 0 && hits[3].prim == 0); /* below the diagonal: triangle 0 */
    CHECK(hits[0].prim == 1);
    /* Every mask: instance 2 (z = 3) is nearer over instance 0. */
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, ~0u, 0));
    CHECK(hits[0].instance == 2 && hits[0].t == 7.0f && hits[1].instance == 1);
    CHECK_OK(sheaf_context_occluded_scene(ctx, NULL, rays, occ, 4, 2, 0));
    CHECK(occ[0] == 1 && occ[1] == 0 && occ[2] == 0 && occ[3] == 1);
    /* No instance answers mask 4. */
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, 4, 0));
    CHECK(hits[0].prim == SHEAF_INVALID_ID && hits[1].prim == SHEAF_INVALID_ID);
    /* A geometry mask hides every instance of the geometry from rays
     * that share no bit with it. */
    p.mask = 2;
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 1, &m, &p));
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, 1, 0));
    CHECK(hits[0].instance == 0 && hits[1].prim == SHEAF_INVALID_ID);
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, 3, 0));
    CHECK(hits[1].instance == 1 && hits[1].t == 8.0f);
    p.mask = ~0u;
    /* Removing an instance needs a commit, then it is gone. */
    CHECK_OK(sheaf_context_remove_instance(ctx, 2));
    CHECK_STATUS(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, ~0u, 0), SHEAF_STATUS_NOT_BUILT);
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, ~0u, 0));
    CHECK(hits[0].instance == 0 && hits[0].t == 9.0f);
    /* The squares wind counter-clockwise seen from +z: rays going down meet
     * their front. Culling back faces keeps them, culling front faces skips
     * them; both flags, or unknown ones, are refused. */
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, ~0u, SHEAF_RAY_FLAG_CULL_BACK_FACING));
    CHECK(hits[0].instance == 0 && hits[0].t == 9.0f && hits[1].instance == 1);
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, ~0u, SHEAF_RAY_FLAG_CULL_FRONT_FACING));
    CHECK(hits[0].prim == SHEAF_INVALID_ID && hits[1].prim == SHEAF_INVALID_ID);
    CHECK_OK(sheaf_context_occluded_scene(ctx, NULL, rays, occ, 4, ~0u, SHEAF_RAY_FLAG_CULL_FRONT_FACING));
    CHECK(occ[0] == 0 && occ[1] == 0);
    rays[0].dir[2] = 1.0f; /* from below, going up: the back of instance 0 */
    rays[0].org[2] = -10.0f;
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, hits, 1, ~0u, SHEAF_RAY_FLAG_CULL_FRONT_FACING));
    CHECK(hits[0].instance == 0 && hits[0].t == 11.0f);
    CHECK_STATUS(sheaf_context_trace_scene(ctx, NULL, rays, hits, 4, ~0u, 3u), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_occluded_scene(ctx, NULL, rays, occ, 4, ~0u, 8u), SHEAF_STATUS_INVALID_ARGUMENT);
    sheaf_context_destroy(ctx);
    return true;
}

static bool test_refit_and_rebuild_updates(void) {
    sheaf_context *ctx = scene_context(2, 2, 16);
    float v[4][3];
    uint32_t idx[6];
    sheaf_mesh m = square();
    sheaf_geometry_params p;
    sheaf_refit_info ri;
    sheaf_ray r = down_at(0.25f, 0.5f);
    sheaf_scene_hit hit;
    float xf[12];
    CHECK(ctx != NULL);
    memcpy(v, SQUARE_V, sizeof v);
    memcpy(idx, SQUARE_I, sizeof idx);
    m.vertices = &v[0][0];
    m.indices = idx;
    CHECK_OK(sheaf_geometry_params_default(&p));
    p.mode = SHEAF_UPDATE_MODE_REFIT;
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 0, &m, &p));
    p.mode = SHEAF_UPDATE_MODE_REBUILD;
    p.max_triangles = 4;
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 1, &m, &p));
    placed(xf, 1.0f, 0.0f, 0.0f, 0.0f);
    CHECK_OK(sheaf_context_set_instance(ctx, 0, 0, xf, ~0u));
    placed(xf, 1.0f, 5.0f, 0.0f, 0.0f);
    CHECK_OK(sheaf_context_set_instance(ctx, 1, 1, xf, ~0u));
    /* Lift the square to z = 0.5 and refit geometry 0. */
    v[0][2] = v[1][2] = v[2][2] = v[3][2] = 0.5f;
    CHECK_OK(sheaf_context_update_scene_geometry(ctx, 0, &m, &ri));
    CHECK(ri.rebuilt == 0 && ri.sah_after > 0.0f);
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, &r, &hit, 1, ~0u, 0));
    CHECK(hit.instance == 0 && hit.t == 9.5f);
    /* A refit needs the same triangle count. */
    m.triangle_count = 1;
    CHECK_STATUS(sheaf_context_update_scene_geometry(ctx, 0, &m, NULL), SHEAF_STATUS_INVALID_ARGUMENT);
    /* Geometry 1 rebuilds with one triangle (within its 4), not with 5. */
    CHECK_OK(sheaf_context_update_scene_geometry(ctx, 1, &m, &ri));
    CHECK(ri.sah_after == 0.0f && ri.rebuilt == 0); /* zeroed: not a refit */
    m.triangle_count = 2;
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    r = down_at(5.25f, 0.75f); /* over the second triangle, now gone */
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, &r, &hit, 1, ~0u, 0));
    CHECK(hit.prim == SHEAF_INVALID_ID);
    r = down_at(5.75f, 0.25f);
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, &r, &hit, 1, ~0u, 0));
    CHECK(hit.instance == 1 && hit.prim == 0 && hit.t == 9.5f);
    sheaf_context_destroy(ctx);
    return true;
}

static bool test_bad_input_changes_nothing(void) {
    sheaf_context *ctx = scene_context(2, 2, 3);
    sheaf_context *plain = scene_context(0, 0, 0);
    sheaf_mesh m = square();
    sheaf_geometry_params p;
    sheaf_ray r = down_at(0.25f, 0.5f);
    sheaf_scene_hit hit;
    float xf[12];
    CHECK(ctx != NULL && plain != NULL);
    CHECK_OK(sheaf_geometry_params_default(&p));
    /* No two-level scene in a context without max_geometries. */
    CHECK_STATUS(sheaf_context_set_scene_geometry(plain, 0, &m, NULL), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_commit_scene(plain, NULL), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_trace_scene(plain, NULL, &r, &hit, 1, ~0u, 0), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_set_scene_geometry(ctx, 0, NULL, NULL), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_set_scene_geometry(ctx, 2, &m, NULL), SHEAF_STATUS_INVALID_ARGUMENT);
    p.mode = 7;
    CHECK_STATUS(sheaf_context_set_scene_geometry(ctx, 0, &m, &p), SHEAF_STATUS_INVALID_ARGUMENT);
    p.mode = SHEAF_UPDATE_MODE_STATIC;
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 0, &m, &p));
    /* 3 triangles in the budget: 2 taken, a second square does not fit. */
    CHECK_STATUS(sheaf_context_set_scene_geometry(ctx, 1, &m, &p), SHEAF_STATUS_CAPACITY_TRIANGLES);
    sheaf_bvh_params watertight;
    CHECK_OK(sheaf_bvh_params_default(&watertight));
    watertight.test = SHEAF_TRI_TEST_WATERTIGHT;
    p.bvh = &watertight;
    m.triangle_count = 1;
    CHECK_STATUS(sheaf_context_set_scene_geometry(ctx, 1, &m, &p), SHEAF_STATUS_INVALID_ARGUMENT);
    m.triangle_count = 2;
    CHECK_STATUS(sheaf_context_update_scene_geometry(ctx, 0, &m, NULL), SHEAF_STATUS_INVALID_ARGUMENT);
    placed(xf, 1.0f, 0.0f, 0.0f, 0.0f);
    CHECK_STATUS(sheaf_context_set_instance(ctx, 0, 1, xf, ~0u), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_set_instance(ctx, 2, 0, xf, ~0u), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_set_instance(ctx, 0, 0, NULL, ~0u), SHEAF_STATUS_NULL_POINTER);
    CHECK_OK(sheaf_context_set_instance(ctx, 0, 0, xf, ~0u));
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    placed(xf, 0.0f, 0.0f, 0.0f, 0.0f); /* singular */
    CHECK_STATUS(sheaf_context_set_instance(ctx, 1, 0, xf, ~0u), SHEAF_STATUS_INVALID_ARGUMENT);
    placed(xf, 1.0f, NAN, 0.0f, 0.0f);
    CHECK_STATUS(sheaf_context_set_instance(ctx, 1, 0, xf, ~0u), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_remove_scene_geometry(ctx, 0), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_remove_instance(ctx, 1), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_trace_scene(ctx, NULL, &r, NULL, 1, ~0u, 0), SHEAF_STATUS_NULL_POINTER);
    /* Nothing changed: still committed, still hit. */
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, &r, &hit, 1, ~0u, 0));
    CHECK(hit.instance == 0 && hit.t == 10.0f);
    CHECK_OK(sheaf_context_remove_instance(ctx, 0));
    CHECK_OK(sheaf_context_remove_scene_geometry(ctx, 0));
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, &r, &hit, 1, ~0u, 0));
    CHECK(hit.prim == SHEAF_INVALID_ID);
    sheaf_context_destroy(ctx);
    sheaf_context_destroy(plain);
    return true;
}

/* Every BVH method through instances gives the single rays' hits, bit for
 * bit: a 16 x 16 grid of camera rays as 8 x 8 packets over three rotated,
 * mirrored and overlapping instances of a pyramid. */
static bool test_packet_methods_equal_single_rays(void) {
    static const sheaf_method METHODS[8] = {SHEAF_METHOD_BVH_SINGLE, SHEAF_METHOD_BVH_WIDE, SHEAF_METHOD_BVH_SIMD,
                                            SHEAF_METHOD_BVH_MASKED, SHEAF_METHOD_BVH_RANGED,
                                            SHEAF_METHOD_BVH_PARTITION, SHEAF_METHOD_BVH_WIDE_RANGED,
                                            SHEAF_METHOD_BVH_FRUSTUM};
    sheaf_context *ctx = scene_context(1, 3, 6);
    sheaf_mesh m;
    sheaf_trace_params tp;
    sheaf_ray rays[256];
    sheaf_scene_hit want[256], got[256];
    uint8_t occ_want[256], occ_got[256];
    float xf[12];
    int i, k, hits = 0;
    CHECK(ctx != NULL);
    m = pyramid();
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 0, &m, NULL));
    placed(xf, 1.0f, -1.5f, 0.0f, 0.0f);
    CHECK_OK(sheaf_context_set_instance(ctx, 0, 0, xf, ~0u));
    placed(xf, -0.8f, 1.2f, 0.2f, 0.3f); /* mirrored in every axis */
    CHECK_OK(sheaf_context_set_instance(ctx, 1, 0, xf, ~0u));
    placed(xf, 0.6f, 0.0f, 0.1f, 0.8f);
    xf[1] = 0.3f; /* sheared */
    CHECK_OK(sheaf_context_set_instance(ctx, 2, 0, xf, ~0u));
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    /* Packets of 8 x 8 in 2x2 quads: ray k of packet P, quad q, lane l. */
    for (k = 0; k < 256; ++k) {
        int packet = k / 64, q = (k % 64) / 4, l = k % 4;
        int x = (packet % 2) * 8 + (q % 4) * 2 + (l % 2), y = (packet / 2) * 8 + (q / 4) * 2 + (l / 2);
        rays[k] = eye_ray(x, y, 16);
    }
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, want, 256, ~0u, 0));
    CHECK_OK(sheaf_context_occluded_scene(ctx, NULL, rays, occ_want, 256, ~0u, 0));
    for (k = 0; k < 256; ++k)
        hits += want[k].prim != SHEAF_INVALID_ID;
    CHECK(hits > 40);
    for (i = 0; i < 8; ++i) {
        CHECK_OK(sheaf_trace_params_default(&tp));
        tp.method = METHODS[i];
        tp.packet = 8;
        CHECK_OK(sheaf_context_trace_scene(ctx, &tp, rays, got, 256, ~0u, 0));
        CHECK_OK(sheaf_context_occluded_scene(ctx, &tp, rays, occ_got, 256, ~0u, 0));
        for (k = 0; k < 256; ++k) {
            CHECK(got[k].prim == want[k].prim && got[k].instance == want[k].instance);
            CHECK(memcmp(&got[k].t, &want[k].t, sizeof(float)) == 0);
            CHECK(occ_got[k] == occ_want[k]);
        }
    }
    {
        /* The same rays as a stream (the sheaf_ray array read field by
           field: stride 32) into interleaved hits (the sheaf_scene_hit
           array: stride 24): single rays and the frustum packets give the
           same answers, bit for bit. */
        sheaf_ray_stream rs;
        sheaf_hit_stream hs;
        const sheaf_trace_params *ps[2];
        int j;
        rs.org_x = &rays[0].org[0], rs.org_y = &rays[0].org[1], rs.org_z = &rays[0].org[2];
        rs.dir_x = &rays[0].dir[0], rs.dir_y = &rays[0].dir[1], rs.dir_z = &rays[0].dir[2];
        rs.tmin = &rays[0].tmin, rs.tmax = &rays[0].tmax, rs.stride = sizeof(sheaf_ray);
        hs.t = &got[0].t, hs.u = &got[0].u, hs.v = &got[0].v, hs.prim = &got[0].prim;
        hs.geometry = &got[0].geometry, hs.instance = &got[0].instance, hs.stride = sizeof(sheaf_scene_hit);
        CHECK_OK(sheaf_trace_params_default(&tp));
        tp.method = SHEAF_METHOD_BVH_FRUSTUM;
        tp.packet = 8;
        ps[0] = NULL;
        ps[1] = &tp;
        for (j = 0; j < 2; ++j) {
            memset(got, 0, sizeof got);
            memset(occ_got, 7, sizeof occ_got);
            CHECK_OK(sheaf_context_trace_scene_stream(ctx, ps[j], &rs, &hs, 256, ~0u, 0));
            CHECK_OK(sheaf_context_occluded_scene_stream(ctx, ps[j], &rs, occ_got, 256, ~0u, 0));
            CHECK(memcmp(got, want, sizeof got) == 0);
            CHECK(memcmp(occ_got, occ_want, sizeof occ_got) == 0);
        }
        hs.instance = &got[0].geometry; /* two outputs on one array */
        CHECK_STATUS(sheaf_context_trace_scene_stream(ctx, &tp, &rs, &hs, 256, ~0u, 0),
                     SHEAF_STATUS_INVALID_ARGUMENT);
        hs.instance = NULL; /* not written */
        CHECK_OK(sheaf_context_trace_scene_stream(ctx, &tp, &rs, &hs, 256, ~0u, 0));
        CHECK_STATUS(sheaf_context_trace_scene_stream(ctx, &tp, &rs, &hs, 256, ~0u, 3),
                     SHEAF_STATUS_INVALID_ARGUMENT);
    }
    {
        /* Camera packets made in the kernel (sheaf_context_trace_scene_camera):
           every pixel's hit is sheaf_frame_camera_ray's ray's, bit for bit,
           single rays and frustum packets. */
        sheaf_frame f;
        sheaf_pixel_rect r = {1, 2, 16, 16};
        sheaf_ray cr;
        const sheaf_trace_params *ps[2];
        int j;
        uint32_t x, y;
        memset(&f, 0, sizeof f);
        f.camera.eye[1] = 0.8f, f.camera.eye[2] = 6.0f;
        f.camera.look_at[1] = 0.3f;
        f.camera.up[1] = 1.0f;
        f.camera.fov_y_deg = 40.0f;
        f.width = 16, f.height = 16;
        CHECK_OK(sheaf_trace_params_default(&tp));
        tp.method = SHEAF_METHOD_BVH_FRUSTUM;
        tp.packet = 8;
        ps[0] = NULL;
        ps[1] = &tp;
        for (j = 0; j < 2; ++j) {
            memset(got, 0, sizeof got);
            CHECK_OK(sheaf_context_trace_scene_camera(ctx, ps[j], &f.camera, 16, 16, &r, got, 15, ~0u, 0));
            hits = 0;
            for (y = r.y0; y < r.y1; ++y)
                for (x = r.x0; x < r.x1; ++x) {
                    const sheaf_scene_hit *g = &got[(y - r.y0) * 15 + (x - r.x0)];
                    sheaf_scene_hit w;
                    CHECK_OK(sheaf_frame_camera_ray(&f, x, y, &cr));
                    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, &cr, &w, 1, ~0u, 0));
                    CHECK(g->prim == w.prim && g->instance == w.instance && g->geometry == w.geometry);
                    CHECK(memcmp(&g->t, &w.t, sizeof(float)) == 0);
                    hits += w.prim != SHEAF_INVALID_ID;
                }
            CHECK(hits > 20);
        }
        CHECK_STATUS(sheaf_context_trace_scene_camera(ctx, &tp, &f.camera, 16, 16, &r, got, 15, ~0u, 3),
                     SHEAF_STATUS_INVALID_ARGUMENT);
        {
            /* A rectangle at the u32 edge of a UINT32_MAX x 2 image and of
               a 2 x UINT32_MAX one: accepted, its pixels written and
               nothing else (the buffer is exactly the rectangle's, so
               ASan and valgrind see a write past it), at every packet
               side (packets overhang the rectangle past 2^32). */
            uint32_t sides[5] = {2, 4, 8, 16, 32}, k, e;
            for (e = 0; e < 2; ++e) {
                sheaf_pixel_rect edge;
                uint32_t w = e ? 2u : UINT32_MAX, h = e ? UINT32_MAX : 2u;
                size_t row, n;
                sheaf_scene_hit *buf;
                if (e) edge.x0 = 0, edge.y0 = UINT32_MAX - 5, edge.x1 = 2, edge.y1 = UINT32_MAX;
                else edge.x0 = UINT32_MAX - 5, edge.y0 = 0, edge.x1 = UINT32_MAX, edge.y1 = 2;
                row = edge.x1 - edge.x0;
                n = row * (edge.y1 - edge.y0);
                buf = (sheaf_scene_hit *)malloc(n * sizeof *buf);
                CHECK(buf != NULL);
                f.width = w, f.height = h;
                for (k = 0; k < 5; ++k) {
                    tp.packet = sides[k];
                    memset(buf, 0xAB, n * sizeof *buf);
                    CHECK_OK(sheaf_context_trace_scene_camera(ctx, &tp, &f.camera, w, h, &edge, buf, row, ~0u, 0));
                    for (y = edge.y0; y < edge.y1; ++y)
                        for (x = edge.x0; x < edge.x1; ++x) {
                            const sheaf_scene_hit *g = &buf[(y - edge.y0) * row + (x - edge.x0)];
                            sheaf_scene_hit w1;
                            CHECK_OK(sheaf_frame_camera_ray(&f, x, y, &cr));
                            CHECK_OK(sheaf_context_trace_scene(ctx, NULL, &cr, &w1, 1, ~0u, 0));
                            CHECK(g->prim == w1.prim && g->instance == w1.instance);
                            CHECK(memcmp(&g->t, &w1.t, sizeof(float)) == 0);
                        }
                }
                free(buf);
            }
            f.width = 16, f.height = 16;
        }
    }
    CHECK_OK(sheaf_trace_params_default(&tp));
    tp.method = SHEAF_METHOD_GRID_CGT;
    CHECK_STATUS(sheaf_context_trace_scene(ctx, &tp, rays, got, 256, ~0u, 0), SHEAF_STATUS_INVALID_ARGUMENT);
    sheaf_context_destroy(ctx);
    return true;
}

/* The grid and the kd-tree over the flattened scene: packets equal their
 * single rays, both families give the same world hits, ids map back, and
 * another mask or a new commit is refused until they are rebuilt. */
static bool test_flattened_scene_for_grid_and_kd(void) {
    sheaf_limits l;
    sheaf_context *ctx = NULL;
    sheaf_mesh m;
    sheaf_trace_params tp;
    sheaf_ray rays[64];
    sheaf_scene_hit dda[64], cgt[64], kd[64], two[64], out;
    sheaf_hit world;
    sheaf_grid_params gp;
    uint8_t occ[64];
    float xf[12];
    int k, hits = 0;
    CHECK_OK(sheaf_limits_default(64, &l));
    l.structures = SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_GRID | SHEAF_STRUCTURE_KD;
    l.max_geometries = 1;
    l.max_instances = 3;
    l.max_scene_triangles = 6;
    CHECK_OK(sheaf_context_create(&l, &ctx));
    m = pyramid();
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 0, &m, NULL));
    placed(xf, 1.0f, -1.5f, 0.0f, 0.0f);
    CHECK_OK(sheaf_context_set_instance(ctx, 0, 0, xf, 1));
    placed(xf, -0.8f, 1.2f, 0.2f, 0.3f);
    CHECK_OK(sheaf_context_set_instance(ctx, 1, 0, xf, 1));
    placed(xf, 0.6f, 0.0f, 0.1f, 0.8f);
    CHECK_OK(sheaf_context_set_instance(ctx, 2, 0, xf, 2));
    CHECK_STATUS(sheaf_context_build_scene_grid(ctx, NULL, 3), SHEAF_STATUS_NOT_BUILT);
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    CHECK_OK(sheaf_context_build_scene_grid(ctx, NULL, 3));
    CHECK_OK(sheaf_context_build_scene_kd(ctx, NULL, 3));
    for (k = 0; k < 64; ++k) {
        int q = k / 4, x = (q % 4) * 2 + (k % 2), y = (q / 4) * 2 + (k % 4) / 2;
        rays[k] = eye_ray(x, y, 8);
    }
    CHECK_OK(sheaf_trace_params_default(&tp));
    tp.packet = 8;
    tp.method = SHEAF_METHOD_GRID_DDA;
    CHECK_OK(sheaf_context_trace_scene(ctx, &tp, rays, dda, 64, 3, 0));
    tp.method = SHEAF_METHOD_GRID_CGT;
    CHECK_OK(sheaf_context_trace_scene(ctx, &tp, rays, cgt, 64, 3, 0));
    tp.method = SHEAF_METHOD_KD_PACKET;
    CHECK_OK(sheaf_context_trace_scene(ctx, &tp, rays, kd, 64, 3, 0));
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, rays, two, 64, 3, 0));
    for (k = 0; k < 64; ++k) {
        CHECK(cgt[k].prim == dda[k].prim && cgt[k].instance == dda[k].instance);
        CHECK(memcmp(&cgt[k].t, &dda[k].t, sizeof(float)) == 0);
        CHECK(kd[k].prim == dda[k].prim && kd[k].instance == dda[k].instance);
        CHECK(memcmp(&kd[k].t, &dda[k].t, sizeof(float)) == 0);
        /* The same ids as the two-level BVH on these rays. */
        CHECK(two[k].prim == dda[k].prim && two[k].instance == dda[k].instance &&
              two[k].geometry == dda[k].geometry);
        hits += dda[k].prim != SHEAF_INVALID_ID;
    }
    CHECK(hits > 10);
    /* World triangle 0 is one of instance 0's; past the end is refused. */
    world.t = 1.0f;
    world.u = world.v = 0.25f;
    world.prim = 0;
    CHECK_OK(sheaf_context_scene_prim(ctx, SHEAF_STRUCTURE_GRID, &world, &out));
    CHECK(out.instance == 0 && out.geometry == 0 && out.prim < 6 && out.t == 1.0f);
    world.prim = 18;
    CHECK_STATUS(sheaf_context_scene_prim(ctx, SHEAF_STRUCTURE_GRID, &world, &out), SHEAF_STATUS_INVALID_ARGUMENT);
    world.prim = SHEAF_INVALID_ID; /* a miss maps to a miss */
    CHECK_OK(sheaf_context_scene_prim(ctx, SHEAF_STRUCTURE_KD, &world, &out));
    CHECK(out.prim == SHEAF_INVALID_ID && out.instance == SHEAF_INVALID_ID);
    CHECK_STATUS(sheaf_context_scene_prim(ctx, SHEAF_STRUCTURE_PGRID, &world, &out), SHEAF_STATUS_NOT_BUILT);
    CHECK_STATUS(sheaf_context_scene_prim(ctx, SHEAF_STRUCTURE_BVH, &world, &out), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_scene_prim(ctx, SHEAF_STRUCTURE_GRID, NULL, &out), SHEAF_STATUS_NULL_POINTER);
    CHECK_STATUS(sheaf_context_scene_prim(ctx, SHEAF_STRUCTURE_GRID, &world, NULL), SHEAF_STATUS_NULL_POINTER);
    /* kd packets' occlusion through the flattened scene. */
    tp.method = SHEAF_METHOD_KD_PACKET;
    CHECK_OK(sheaf_context_occluded_scene(ctx, &tp, rays, occ, 64, 3, 0));
    for (k = 0; k < 64; ++k)
        CHECK(occ[k] == (dda[k].prim != SHEAF_INVALID_ID));
    /* A failed build (bad params) for another mask leaves the kd-tree
     * answering for mask 3. */
    CHECK_OK(sheaf_grid_params_default(&gp));
    gp.lambda = -1.0f;
    CHECK_STATUS(sheaf_context_build_scene_grid(ctx, &gp, 1), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_OK(sheaf_context_trace_scene(ctx, &tp, rays, kd, 64, 3, 0));
    /* Another mask than the build's, culling, then a new commit. */
    tp.method = SHEAF_METHOD_GRID_DDA;
    CHECK_STATUS(sheaf_context_trace_scene(ctx, &tp, rays, dda, 64, 3, SHEAF_RAY_FLAG_CULL_BACK_FACING),
                 SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_STATUS(sheaf_context_trace_scene(ctx, &tp, rays, dda, 64, 1, 0), SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK_OK(sheaf_context_commit_scene(ctx, NULL));
    CHECK_STATUS(sheaf_context_trace_scene(ctx, &tp, rays, dda, 64, 3, 0), SHEAF_STATUS_NOT_BUILT);
    CHECK_OK(sheaf_context_build_scene_grid(ctx, NULL, 3));
    CHECK_OK(sheaf_context_trace_scene(ctx, &tp, rays, dda, 64, 3, 0));
    /* A change without a commit: NOT_BUILT for the scene's traces and ids. */
    placed(xf, 1.0f, -1.5f, 0.0f, 0.5f);
    CHECK_OK(sheaf_context_set_instance(ctx, 0, 0, xf, 1));
    CHECK_STATUS(sheaf_context_trace_scene(ctx, &tp, rays, dda, 64, 3, 0), SHEAF_STATUS_NOT_BUILT);
    world.prim = 0;
    CHECK_STATUS(sheaf_context_scene_prim(ctx, SHEAF_STRUCTURE_GRID, &world, &out), SHEAF_STATUS_NOT_BUILT);
    sheaf_context_destroy(ctx);
    return true;
}

/* The triangle budget does not fragment: with 4 of 6 triangles free in
 * two gaps of 2, a geometry reserving 4 is set after the runs slide
 * together, and the committed scene answers as before. */
static bool test_budget_compacts_instead_of_refusing(void) {
    sheaf_context *ctx = scene_context(3, 2, 6);
    sheaf_mesh m = square();
    sheaf_geometry_params p;
    sheaf_scene_info info;
    sheaf_ray r = down_at(0.25f, 0.5f);
    sheaf_scene_hit before, after;
    float xf[12];
    CHECK(ctx != NULL);
    CHECK_OK(sheaf_geometry_params_default(&p));
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 0, &m, &p));
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 1, &m, &p));
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 2, &m, &p));
    CHECK_OK(sheaf_context_remove_scene_geometry(ctx, 0));
    CHECK_OK(sheaf_context_remove_scene_geometry(ctx, 2));
    placed(xf, 1.0f, 0.0f, 0.0f, 1.0f);
    CHECK_OK(sheaf_context_set_instance(ctx, 0, 1, xf, ~0u));
    CHECK_OK(sheaf_context_commit_scene(ctx, &info));
    CHECK(info.free_triangles == 4 && info.largest_free_run == 2 && info.compactions == 0);
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, &r, &before, 1, ~0u, 0));
    CHECK(before.instance == 0 && before.geometry == 1 && before.t == 9.0f);
    /* 5 is more than is free: refused, nothing changes. */
    p.max_triangles = 5;
    CHECK_STATUS(sheaf_context_set_scene_geometry(ctx, 0, &m, &p), SHEAF_STATUS_CAPACITY_TRIANGLES);
    CHECK_OK(sheaf_context_commit_scene(ctx, &info));
    CHECK(info.compactions == 0 && info.largest_free_run == 2);
    p.max_triangles = 4;
    CHECK_OK(sheaf_context_set_scene_geometry(ctx, 0, &m, &p));
    CHECK_OK(sheaf_context_commit_scene(ctx, &info));
    CHECK(info.free_triangles == 0 && info.largest_free_run == 0);
    CHECK(info.compactions == 1 && info.compacted_triangles == 2);
    CHECK_OK(sheaf_context_trace_scene(ctx, NULL, &r, &after, 1, ~0u, 0));
    CHECK(after.instance == 0 && after.geometry == 1 && after.prim == before.prim && after.t == before.t);
    sheaf_context_destroy(ctx);
    return true;
}

int main(void) {
    int passed = 0, failed = 0;
    run_test("test_instances_ids_and_masks", test_instances_ids_and_masks, &passed, &failed);
    run_test("test_refit_and_rebuild_updates", test_refit_and_rebuild_updates, &passed, &failed);
    run_test("test_bad_input_changes_nothing", test_bad_input_changes_nothing, &passed, &failed);
    run_test("test_packet_methods_equal_single_rays", test_packet_methods_equal_single_rays, &passed, &failed);
    run_test("test_flattened_scene_for_grid_and_kd", test_flattened_scene_for_grid_and_kd, &passed, &failed);
    run_test("test_budget_compacts_instead_of_refusing", test_budget_compacts_instead_of_refusing, &passed, &failed);
    return report(passed, failed);
}
