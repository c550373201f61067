/*
 * A program built against an older header, run against this library.
 *
 * It does not include sheaf.h: it declares the parameter structs as an
 * older header did, each ending before the fields added since sheaf 0.2
 * (sheaf_limits without max_packet_side, max_bounces, renderers and
 * max_bvh_refs; sheaf_bvh_params without quality and width;
 * sheaf_trace_params without force_opaque; sheaf_grid_params without fit;
 * sheaf_kd_params without quality and bins), and the calls it uses with
 * those structs. The library must read the fields those structs have, give
 * the missing ones their defaults (docs/c-api.md, "Upgrading"), never
 * write past them, and answer exactly as a current program does: every
 * packet method's hits equal the single ray's, bit for bit.
 *
 * It also plays a program built against a newer header (a struct longer
 * than the library's): accepted while the unknown bytes are zero, refused
 * once one is set, as is a size no version of a struct had.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

typedef uint32_t sheaf_status;
typedef struct sheaf_context sheaf_context;

/* The older header's structs: the size first, then the fields of 0.2. */
typedef struct {
    uint32_t size;
    uint32_t max_triangles, max_vertices, max_image_width, max_image_height, max_tile, max_threads;
    uint32_t max_grid_cells, max_grid_refs, projection_test, structures, max_kd_nodes, max_kd_refs;
    uint32_t max_pgrid_cells, max_pgrid_refs, max_geometries, max_instances, max_scene_triangles;
} old_limits;

typedef struct {
    uint32_t size;
    uint32_t leaf_size, bins;
    float traversal_cost;
    uint32_t test;
} old_bvh_params;

typedef struct {
    uint32_t size;
    uint32_t method, packet, macrocells, mailbox, culling, ray_kind, entry;
    float split;
    uint32_t isa;
} old_trace_params;

typedef struct {
    uint32_t size;
    float lambda;
    uint32_t macrocell, test;
} old_grid_params;

typedef struct {
    uint32_t size;
    uint32_t max_depth;
    float traversal_cost, empty_bonus;
    uint32_t test;
} old_kd_params;

typedef struct {
    float org[3], tmin, dir[3], tmax;
} ray;

typedef struct {
    float t;
    uint32_t prim;
    float u, v;
} hit;

sheaf_status sheaf_limits_default(uint32_t max_triangles, old_limits *out, size_t size);
sheaf_status sheaf_bvh_params_default(old_bvh_params *out, size_t size);
sheaf_status sheaf_trace_params_default(old_trace_params *out, size_t size);
sheaf_status sheaf_grid_params_default(old_grid_params *out, size_t size);
sheaf_status sheaf_kd_params_default(old_kd_params *out, size_t size);
sheaf_status sheaf_context_create(const old_limits *limits, sheaf_context **out);
void sheaf_context_destroy(sheaf_context *ctx);
sheaf_status sheaf_context_set_geometry(sheaf_context *ctx, const float *vertices, size_t vertex_stride_bytes,
                                        uint32_t vertex_count, const uint32_t *indices, uint32_t triangle_count);
sheaf_status sheaf_context_build_bvh(sheaf_context *ctx, const old_bvh_params *params);
sheaf_status sheaf_context_build_grid(sheaf_context *ctx, const old_grid_params *params);
sheaf_status sheaf_context_build_kd(sheaf_context *ctx, const old_kd_params *params);
sheaf_status sheaf_context_trace(const sheaf_context *ctx, uint32_t method, const ray *rays, hit *hits,
                                 size_t count);
sheaf_status sheaf_context_trace_with(const sheaf_context *ctx, const old_trace_params *params, const ray *rays,
                                      hit *hits, size_t count);

/* The values of the current header this program needs (never renumbered). */
enum {
    OK = 0,
    INVALID_ARGUMENT = 101,
    GRID_CGT = 1,
    BVH_SINGLE = 2,
    BVH_RANGED = 5,
    BVH_PARTITION = 6,
    KD_SINGLE = 7,
    KD_PACKET = 9,
    BVH_FRUSTUM = 12,
    STRUCTURES_GRID_BVH_KD = 7,
    WATERTIGHT = 1
};

static int passed, failed;
#define CHECK(c)                                                                                   \
    do {                                                                                           \
        if (c) {                                                                                   \
            ++passed;                                                                              \
        } else {                                                                                   \
            ++failed;                                                                              \
            printf("FAIL %s:%d: %s\n", __FILE__, __LINE__, #c);                                   \
        }                                                                                          \
    } while (0)

/* A struct followed by canary bytes: the library must not write past it. */
#define CANARY 0xA5
static int untouched(const unsigned char *p, size_t n) {
    size_t i;
    for (i = 0; i < n; ++i)
        if (p[i] != CANARY) return 0;
    return 1;
}

/* A ground of 2 x 2 quads and a stair of boxes: some rays hit, some miss. */
#define NV 64
#define NT 96
static float verts[NV * 3];
static uint32_t idx[NT * 3];
static uint32_t nv, nt;
static void quad(float x0, float y0, float x1, float y1, float z) {
    uint32_t b = nv;
    float c[4][2];
    int i;
    c[0][0] = x0; c[0][1] = y0;
    c[1][0] = x1; c[1][1] = y0;
    c[2][0] = x1; c[2][1] = y1;
    c[3][0] = x0; c[3][1] = y1;
    for (i = 0; i < 4; ++i) {
        verts[3 * nv] = c[i][0];
        verts[3 * nv + 1] = c[i][1];
        verts[3 * nv + 2] = z;
        ++nv;
    }
    idx[3 * nt] = b; idx[3 * nt + 1] = b + 1; idx[3 * nt + 2] = b + 2; ++nt;
    idx[3 * nt] = b; idx[3 * nt + 1] = b + 2; idx[3 * nt + 2] = b + 3; ++nt;
}
static void scene(void) {
    int i;
    for (i = 0; i < 8; ++i) quad(-4.0f + (float)i, -4.0f, -3.0f + (float)i, 4.0f, 0.25f * (float)(i % 3));
    for (i = 0; i < 4; ++i) quad(-2.0f + (float)i, -1.0f + 0.5f * (float)i, -1.2f + (float)i, 0.2f + 0.5f * (float)i, 1.0f + 0.3f * (float)i);
}

#define N 256 /* 16 x 16 camera rays */
static ray rays[N];
static void camera(void) {
    int x, y;
    for (y = 0; y < 16; ++y)
        for (x = 0; x < 16; ++x) {
            ray *r = &rays[y * 16 + x];
            float dx = -0.5f + (float)x / 15.0f, dy = -0.5f + (float)y / 15.0f, dz = -1.0f;
            float l = sqrtf(dx * dx + dy * dy + dz * dz);
            r->org[0] = 0.1f; r->org[1] = 0.2f; r->org[2] = 6.0f;
            r->dir[0] = dx * 1.2f / l; r->dir[1] = dy * 1.2f / l; r->dir[2] = dz / l;
            r->tmin = 0.0f;
            r->tmax = INFINITY;
        }
}

static int same_hits(const hit *a, const hit *b) {
    size_t i;
    for (i = 0; i < N; ++i)
        if (a[i].prim != b[i].prim || memcmp(&a[i].t, &b[i].t, sizeof(float)) != 0) return 0;
    return 1;
}

int main(void) {
    struct {
        old_limits l;
        unsigned char canary[64];
    } lim;
    struct {
        old_bvh_params p;
        unsigned char canary[64];
    } bp;
    struct {
        old_trace_params p;
        unsigned char canary[64];
    } tp;
    struct {
        old_grid_params p;
        unsigned char canary[64];
    } gp;
    struct {
        old_kd_params p;
        unsigned char canary[64];
    } kp;
    /* A newer header's bvh params: this library's fields, then one it does not know. */
    struct {
        old_bvh_params p;
        uint32_t quality, width, presplit, future;
    } newer;
    sheaf_context *ctx = NULL;
    hit ref[N], got[N], kd[N];
    int hits = 0, i;
    static const uint32_t methods[] = {BVH_SINGLE, BVH_RANGED, BVH_PARTITION, BVH_FRUSTUM, GRID_CGT, KD_PACKET};

    scene();
    camera();

    /* The defaults functions write only the older structs' bytes. */
    memset(&lim, CANARY, sizeof lim);
    memset(&bp, CANARY, sizeof bp);
    memset(&tp, CANARY, sizeof tp);
    memset(&gp, CANARY, sizeof gp);
    memset(&kp, CANARY, sizeof kp);
    CHECK(sheaf_limits_default(nt, &lim.l, sizeof lim.l) == OK);
    CHECK(sheaf_bvh_params_default(&bp.p, sizeof bp.p) == OK);
    CHECK(sheaf_trace_params_default(&tp.p, sizeof tp.p) == OK);
    CHECK(sheaf_grid_params_default(&gp.p, sizeof gp.p) == OK);
    CHECK(sheaf_kd_params_default(&kp.p, sizeof kp.p) == OK);
    CHECK(untouched(lim.canary, sizeof lim.canary) && untouched(bp.canary, sizeof bp.canary) &&
          untouched(tp.canary, sizeof tp.canary) && untouched(gp.canary, sizeof gp.canary) &&
          untouched(kp.canary, sizeof kp.canary));
    /* ... and the fields they have hold the documented defaults. */
    CHECK(lim.l.size == sizeof lim.l && lim.l.max_triangles == nt && lim.l.max_vertices == 3 * nt &&
          lim.l.structures == STRUCTURES_GRID_BVH_KD && lim.l.max_threads == 8);
    CHECK(bp.p.size == sizeof bp.p && bp.p.leaf_size == 4 && bp.p.bins == 16 && bp.p.traversal_cost == 1.0f);
    CHECK(tp.p.size == sizeof tp.p && tp.p.packet == 8 && tp.p.macrocells == 1 && tp.p.split == 2.0f);
    CHECK(gp.p.size == sizeof gp.p && kp.p.size == sizeof kp.p && kp.p.traversal_cost == 2.0f);

    /* The context and the structures, from the older structs. */
    lim.l.max_image_width = 64;
    lim.l.max_image_height = 64;
    CHECK(sheaf_context_create(&lim.l, &ctx) == OK && ctx != NULL);
    if (ctx == NULL) {
        printf("%d passed, %d failed\n", passed, failed);
        return 1;
    }
    CHECK(sheaf_context_set_geometry(ctx, verts, 12, nv, idx, nt) == OK);
    bp.p.test = WATERTIGHT;
    bp.p.leaf_size = 2;
    CHECK(sheaf_context_build_bvh(ctx, &bp.p) == OK);
    gp.p.test = WATERTIGHT;
    CHECK(sheaf_context_build_grid(ctx, &gp.p) == OK);
    kp.p.test = WATERTIGHT;
    CHECK(sheaf_context_build_kd(ctx, &kp.p) == OK);

    /* Every method answers as the single ray, bit for bit. */
    CHECK(sheaf_context_trace(ctx, BVH_SINGLE, rays, ref, N) == OK);
    for (i = 0; i < N; ++i) hits += ref[i].prim != 0xFFFFFFFFu;
    CHECK(hits > N / 4 && hits < N);
    CHECK(sheaf_context_trace(ctx, KD_SINGLE, rays, kd, N) == OK);
    CHECK(same_hits(ref, kd));
    for (i = 0; i < (int)(sizeof methods / sizeof methods[0]); ++i) {
        tp.p.method = methods[i];
        tp.p.packet = 8;
        memset(got, 0, sizeof got);
        CHECK(sheaf_context_trace_with(ctx, &tp.p, rays, got, N) == OK);
        CHECK(same_hits(ref, got));
    }

    /* A newer header's struct: zero unknown bytes are accepted ... */
    memset(&newer, 0, sizeof newer);
    CHECK((sheaf_bvh_params_default)((old_bvh_params *)&newer, sizeof newer) == OK);
    CHECK(newer.p.size == sizeof newer && newer.width == 4 && newer.presplit == 0 &&
          newer.future == 0);
    CHECK(sheaf_context_build_bvh(ctx, &newer.p) == OK);
    CHECK(sheaf_context_trace(ctx, BVH_SINGLE, rays, got, N) == OK);
    /* ... a set one is refused and changes nothing ... */
    newer.future = 1;
    CHECK(sheaf_context_build_bvh(ctx, &newer.p) == INVALID_ARGUMENT);
    /* ... and so is a size no version had (inside a field, or garbage). */
    bp.p.size = sizeof bp.p - 2;
    CHECK(sheaf_context_build_bvh(ctx, &bp.p) == INVALID_ARGUMENT);
    bp.p.size = 0xEEEEEEEEu;
    CHECK(sheaf_context_build_bvh(ctx, &bp.p) == INVALID_ARGUMENT);
    CHECK(sheaf_bvh_params_default(&bp.p, 3) == INVALID_ARGUMENT);
    bp.p.size = 0;
    CHECK(sheaf_context_build_bvh(ctx, &bp.p) == INVALID_ARGUMENT);

    sheaf_context_destroy(ctx);
    printf("%d passed, %d failed\n", passed, failed);
    return failed != 0;
}
