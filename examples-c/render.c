/*
 * render.c: the smallest complete use of sheaf's C ABI.
 *
 * Builds a scene (a ground plane, a staircase of boxes, a pyramid and a
 * tower), creates a context inside a buffer it allocates itself
 * (sheaf_context_create_in: sheaf never allocates), renders one frame with
 * shadows and writes it as a binary PPM.
 *
 * With a fourth argument `whitted` it reserves and builds only the BVH and
 * renders a Whitted frame instead: a mirror floor, a glass pyramid, two
 * lights, 16x16 packets (Ranged for camera and shadow rays, Partition for
 * reflection and refraction rays).
 *
 * With `deferred` it reserves only the perspective/light grid pools and
 * renders a deferred frame: camera rays through a perspective grid, then
 * per light every shadow ray through a spherical light grid (a point light
 * and a spot light), then shading; it prints the phase times.
 *
 * Build and run from the repository root (the Makefile first runs
 * `cargo build -p sheaf --release --lib`, then links target/release/libsheaf.a):
 *   make -C examples-c            (static; `make -C examples-c shared` for the .so)
 *   examples-c/render [out.ppm] [width] [height] [whitted|deferred]
 */
#include "sheaf.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_VERTICES 1024
#define MAX_TRIANGLES 1024

static float vertices[MAX_VERTICES][3];
static uint32_t indices[MAX_TRIANGLES][3];
static uint32_t n_vertices, n_triangles;

static uint32_t vertex(float x, float y, float z) {
    vertices[n_vertices][0] = x;
    vertices[n_vertices][1] = y;
    vertices[n_vertices][2] = z;
    return n_vertices++;
}

static void triangle(uint32_t a, uint32_t b, uint32_t c) {
    indices[n_triangles][0] = a;
    indices[n_triangles][1] = b;
    indices[n_triangles][2] = c;
    n_triangles++;
}

static void quad(uint32_t a, uint32_t b, uint32_t c, uint32_t d) {
    triangle(a, b, c);
    triangle(a, c, d);
}

/* Axis-aligned box from (x0, y0, z0) to (x1, y1, z1). */
static void box(float x0, float y0, float z0, float x1, float y1, float z1) {
    uint32_t v[8];
    int i;
    for (i = 0; i < 8; ++i) v[i] = vertex((i & 1) ? x1 : x0, (i & 2) ? y1 : y0, (i & 4) ? z1 : z0);
    quad(v[0], v[2], v[3], v[1]); /* bottom */
    quad(v[4], v[5], v[7], v[6]); /* top */
    quad(v[0], v[1], v[5], v[4]);
    quad(v[2], v[6], v[7], v[3]);
    quad(v[0], v[4], v[6], v[2]);
    quad(v[1], v[3], v[7], v[5]);
}

static void pyramid(float cx, float cy, float half, float height) {
    uint32_t a = vertex(cx - half, cy - half, 0.0f), b = vertex(cx + half, cy - half, 0.0f);
    uint32_t c = vertex(cx + half, cy + half, 0.0f), d = vertex(cx - half, cy + half, 0.0f);
    uint32_t top = vertex(cx, cy, height);
    triangle(a, b, top);
    triangle(b, c, top);
    triangle(c, d, top);
    triangle(d, a, top);
}

static void build_scene(void) {
    int i;
    quad(vertex(-12.0f, -12.0f, 0.0f), vertex(12.0f, -12.0f, 0.0f), vertex(12.0f, 12.0f, 0.0f),
         vertex(-12.0f, 12.0f, 0.0f));
    for (i = 0; i < 6; ++i) box(-5.0f + (float)i, -1.0f, 0.0f, -4.0f + (float)i, 1.0f, 0.4f * (float)(i + 1));
    pyramid(3.5f, 3.0f, 1.6f, 2.5f);
    box(2.5f, -3.5f, 0.0f, 3.5f, -2.5f, 4.0f);
}

static int fail(const char *what, sheaf_status s, const sheaf_context *ctx) {
    char msg[SHEAF_ERROR_MESSAGE_MAX] = "";
    size_t n = 0;
    if (ctx != NULL) (void)sheaf_context_last_error(ctx, msg, sizeof msg, &n);
    fprintf(stderr, "%s failed: %s (%u)%s%s\n", what, sheaf_status_string(s), (unsigned)s, n ? ": " : "", msg);
    return 1;
}

int main(int argc, char **argv) {
    const char *path = argc > 1 ? argv[1] : "render.ppm";
    uint32_t width = argc > 2 ? (uint32_t)atoi(argv[2]) : 640;
    uint32_t height = argc > 3 ? (uint32_t)atoi(argv[3]) : 480;
    int whitted = argc > 4 && strcmp(argv[4], "whitted") == 0;
    int deferred = argc > 4 && strcmp(argv[4], "deferred") == 0;
    uint32_t pyramid_first = 0;
    sheaf_limits limits;
    sheaf_context *ctx = NULL;
    sheaf_frame frame;
    sheaf_stats stats;
    sheaf_status s;
    size_t need = 0, stride = (size_t)width * 4, x, y;
    void *memory, *aligned;
    uint8_t *rgba;
    FILE *out;

    if (width == 0 || height == 0) {
        fprintf(stderr, "usage: %s [out.ppm] [width] [height] [whitted|deferred]\n", argv[0]);
        return 2;
    }
    build_scene();
    pyramid_first = n_triangles - 16; /* the pyramid's 4 faces, then the tower's 12 */

    /* 1. All the memory the context will ever use, allocated here, 64-byte aligned. */
    if ((s = sheaf_limits_default(n_triangles, &limits)) != SHEAF_STATUS_OK) return fail("sheaf_limits_default", s, NULL);
    if (whitted) limits.structures = SHEAF_STRUCTURE_BVH; /* pools for the BVH only */
    if (deferred) {
        /* Only the perspective/light grid pools; they scale with the image. */
        limits.structures = SHEAF_STRUCTURE_PGRID;
        limits.max_image_width = width;
        limits.max_image_height = height;
    }
    if ((s = sheaf_required_bytes(&limits, &need)) != SHEAF_STATUS_OK) return fail("sheaf_required_bytes", s, NULL);
    memory = malloc(need + SHEAF_CONTEXT_ALIGN);
    if (memory == NULL) return 1;
    aligned = (void *)(((uintptr_t)memory + SHEAF_CONTEXT_ALIGN - 1) & ~(uintptr_t)(SHEAF_CONTEXT_ALIGN - 1));
    if ((s = sheaf_context_create_in(aligned, need, &limits, &ctx)) != SHEAF_STATUS_OK)
        return fail("sheaf_context_create_in", s, NULL);

    /* 2. Geometry (borrowed, not copied) and the grid. */
    if ((s = sheaf_context_set_geometry(ctx, &vertices[0][0], sizeof vertices[0], n_vertices, &indices[0][0],
                                        n_triangles)) != SHEAF_STATUS_OK)
        return fail("sheaf_context_set_geometry", s, ctx);
    if (whitted) {
        if ((s = sheaf_context_build_bvh(ctx, NULL)) != SHEAF_STATUS_OK) return fail("sheaf_context_build_bvh", s, ctx);
    } else if (deferred) {
        /* Loads the triangles; the grids are built per frame for its camera and lights. */
        if ((s = sheaf_context_build_pgrid(ctx, NULL)) != SHEAF_STATUS_OK)
            return fail("sheaf_context_build_pgrid", s, ctx);
    } else if ((s = sheaf_context_build_grid(ctx, NULL)) != SHEAF_STATUS_OK) {
        return fail("sheaf_context_build_grid", s, ctx);
    }

    /* 3. One frame. */
    memset(&frame, 0, sizeof frame);
    frame.camera.eye[0] = 9.0f;
    frame.camera.eye[1] = -12.0f;
    frame.camera.eye[2] = 7.0f;
    frame.camera.look_at[2] = 1.0f;
    frame.camera.up[2] = 1.0f;
    frame.camera.fov_y_deg = 45.0f;
    frame.light.position[0] = -6.0f;
    frame.light.position[1] = -8.0f;
    frame.light.position[2] = 12.0f;
    frame.light.color[0] = frame.light.color[1] = frame.light.color[2] = 1.0f;
    (void)sheaf_shading_default(&frame.shading);
    frame.width = width;
    frame.height = height;
    rgba = (uint8_t *)malloc(stride * height);
    if (rgba == NULL) return 1;
    if (whitted) {
        /* Floor (triangles 0-1) a mirror, boxes diffuse, pyramid glass, tower diffuse. */
        sheaf_material mats[3] = {{{0.5f, 0.5f, 0.55f}, 0.5f, 0.0f, 1.0f},
                                  {{0.8f, 0.78f, 0.72f}, 0.0f, 0.0f, 1.0f},
                                  {{0.9f, 0.95f, 1.0f}, 0.1f, 0.8f, 1.5f}};
        sheaf_material_range ranges[4] = {{0, 0}, {2, 1}, {0, 2}, {0, 1}};
        sheaf_light lights[2];
        sheaf_trace_params camera, secondary;
        ranges[2].first = pyramid_first;
        ranges[3].first = pyramid_first + 4;
        lights[0] = frame.light;
        lights[1] = frame.light;
        lights[1].position[0] = 8.0f;
        lights[1].color[0] = 0.5f;
        lights[1].color[1] = 0.45f;
        lights[1].color[2] = 0.3f;
        (void)sheaf_trace_params_default(&camera);
        camera.method = SHEAF_METHOD_BVH_RANGED;
        camera.packet = 16;
        secondary = camera;
        secondary.method = SHEAF_METHOD_BVH_PARTITION;
        if ((s = sheaf_context_render_whitted(ctx, &camera, &camera, &secondary, NULL, &frame, lights, 2, mats, 3,
                                              ranges, 4, rgba, stride, stride * height)) != SHEAF_STATUS_OK)
            return fail("sheaf_context_render_whitted", s, ctx);
    } else if (deferred) {
        /* The frame's light and a warm spot light on the pyramid. */
        sheaf_deferred_job job;
        sheaf_light lights[2];
        lights[0] = frame.light;
        memset(&lights[1], 0, sizeof lights[1]);
        lights[1].position[0] = 8.0f;
        lights[1].position[1] = -2.0f;
        lights[1].position[2] = 9.0f;
        lights[1].color[0] = 0.6f;
        lights[1].color[1] = 0.45f;
        lights[1].color[2] = 0.25f;
        lights[1].spot_direction[0] = 3.5f - 8.0f;
        lights[1].spot_direction[1] = 3.0f + 2.0f;
        lights[1].spot_direction[2] = -9.0f;
        lights[1].spot_angle_deg = 20.0f;
        lights[1].spot_soft_deg = 6.0f;
        memset(&job, 0, sizeof job);
        job.frame = frame;
        job.lights = lights;
        job.light_count = 2;
        job.primary_pgrid = true;
        job.shadow_light_grid = true;
        if ((s = sheaf_context_render_deferred(ctx, &job, rgba, stride, stride * height)) != SHEAF_STATUS_OK)
            return fail("sheaf_context_render_deferred", s, ctx);
    } else if ((s = sheaf_context_render(ctx, SHEAF_METHOD_GRID_DDA, &frame, rgba, stride, stride * height)) !=
               SHEAF_STATUS_OK) {
        return fail("sheaf_context_render", s, ctx);
    }
    (void)sheaf_context_stats(ctx, &stats);

    /* 4. PPM (RGB, alpha dropped). */
    out = fopen(path, "wb");
    if (out == NULL) {
        perror(path);
        return 1;
    }
    fprintf(out, "P6\n%u %u\n255\n", width, height);
    for (y = 0; y < height; ++y)
        for (x = 0; x < width; ++x) fwrite(rgba + y * stride + 4 * x, 1, 3, out);
    fclose(out);

    if (whitted)
        printf("sheaf %s: %u triangles, BVH %u nodes (depth %u), build %.3f ms, Whitted frame: %llu rays in %.3f ms -> %s\n",
               sheaf_version_string(), stats.bvh_triangles, stats.bvh_nodes, stats.bvh_depth,
               (double)stats.bvh_build_ns * 1e-6, (unsigned long long)stats.counters.rays,
               (double)stats.trace_ns * 1e-6, path);
    else if (deferred)
        printf("sheaf %s: %u triangles, deferred frame, 2 lights: perspective grid %ux%ux%u (%u refs), %llu shadow rays "
               "in %u chunks; ms: primary build %.3f, trace %.3f, rearrange %.3f, shadow build %.3f, trace %.3f, "
               "shade %.3f -> %s\n",
               sheaf_version_string(), stats.pgrid_triangles, stats.camera_tiles[0], stats.camera_tiles[1],
               stats.camera_slices, stats.camera_refs, (unsigned long long)stats.shadow_rays, stats.reorder_chunks,
               (double)stats.primary_build_ns * 1e-6, (double)stats.primary_trace_ns * 1e-6,
               (double)stats.rearrange_ns * 1e-6, (double)stats.shadow_build_ns * 1e-6,
               (double)stats.shadow_trace_ns * 1e-6, (double)stats.shade_ns * 1e-6, path);
    else
        printf("sheaf %s: %u triangles, grid %ux%ux%u (%u refs), build %.3f ms, %llu rays in %.3f ms -> %s\n",
               sheaf_version_string(), stats.triangles, stats.grid_res[0], stats.grid_res[1], stats.grid_res[2],
               stats.grid_refs, (double)stats.build_ns * 1e-6, (unsigned long long)stats.counters.rays,
               (double)stats.trace_ns * 1e-6, path);

    sheaf_context_destroy(ctx);
    free(memory);
    free(rgba);
    return 0;
}
