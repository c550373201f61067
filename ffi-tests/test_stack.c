/*
 * The caller's stack: every build, trace, occluded and render call of the
 * C ABI, with 32x32 packets of every method (and 8 bounces for Whitted
 * frames), runs on a thread with a 64 KiB stack, and uses at most 16 KiB
 * of it.
 *
 * How the figure is measured: the thread paints its unused stack (from the
 * bottom up to 4 KiB below its current frame) with a byte pattern, makes
 * one call, and finds the lowest byte no longer painted: the call's high
 * water mark below the painting thread's frame (so it includes the call's
 * own frame; a call using less than 4 KiB reads as 4 KiB). glibc puts a
 * guard page under the stack, so an overflow faults instead of passing.
 *
 * Not run under valgrind (tests/c_abi.rs): painting memory below the stack
 * pointer is what memcheck rightly reports. Under AddressSanitizer (whose
 * runtime uses the bottom of thread stacks) the calls still run on the
 * 64 KiB stack, unmeasured.
 *
 * Set STACK_REPORT=1 to print the table of figures.
 */
#define _GNU_SOURCE /* pthread_getattr_np: the thread's exact stack bounds */
#include "common.h"

#include <pthread.h>

#ifndef STACK_BYTES
#define STACK_BYTES (64 * 1024)
#endif
#define BUDGET (16 * 1024)
#define MARGIN 4096
#define PAINT 0xA5

#define W 64
#define H 64
#define STRIDE (W * 4)
#define LEN (H * STRIDE)
#define NRAYS (W * H)

#if defined(__GNUC__)
#define NO_ASAN __attribute__((no_sanitize_address, noinline))
#else
#define NO_ASAN
#endif

#if defined(__SANITIZE_ADDRESS__)
#define MEASURE 0
#else
#define MEASURE 1
#endif

typedef struct job job;
struct job {
    const char *call;
    sheaf_method method;
    uint32_t packet;
    sheaf_status (*run)(job *);
    sheaf_status status;
    size_t used;
    bool overflow;
};

static sheaf_context *g_ctx;
static sheaf_frame g_frame;
static sheaf_ray g_rays[NRAYS];
static sheaf_hit g_hits[NRAYS];
static uint8_t g_occ[NRAYS];
static uint8_t g_img[LEN];
static scene *g_scene;

static sheaf_trace_params params_of(const job *j) {
    sheaf_trace_params p;
    (void)sheaf_trace_params_default(&p);
    p.method = j->method;
    p.packet = j->packet;
    p.entry = SHEAF_ENTRY_SEARCH_AEPSA;
    return p;
}

static sheaf_status run_trace(job *j) { return sheaf_context_trace(g_ctx, j->method, g_rays, g_hits, NRAYS); }
static sheaf_status run_occluded(job *j) { return sheaf_context_occluded(g_ctx, j->method, g_rays, g_occ, NRAYS); }
static sheaf_status run_trace_with(job *j) {
    sheaf_trace_params p = params_of(j);
    return sheaf_context_trace_with(g_ctx, &p, g_rays, g_hits, NRAYS);
}
static sheaf_status run_occluded_with(job *j) {
    sheaf_trace_params p = params_of(j);
    return sheaf_context_occluded_with(g_ctx, &p, g_rays, g_occ, NRAYS);
}
static sheaf_status run_trace_slot(job *j) {
    sheaf_trace_params p = params_of(j);
    return sheaf_context_trace_slot(g_ctx, 1, &p, g_rays, g_hits, NRAYS);
}
static sheaf_status run_occluded_slot(job *j) {
    sheaf_trace_params p = params_of(j);
    return sheaf_context_occluded_slot(g_ctx, 1, &p, g_rays, g_occ, NRAYS);
}
static sheaf_status run_render(job *j) { return sheaf_context_render(g_ctx, j->method, &g_frame, g_img, STRIDE, LEN); }
static sheaf_status run_render_with(job *j) {
    sheaf_trace_params p = params_of(j);
    return sheaf_context_render_with(g_ctx, &p, &p, &g_frame, g_img, STRIDE, LEN);
}
static sheaf_status run_render_rows(job *j) {
    sheaf_trace_params p = params_of(j);
    return sheaf_context_render_rows(g_ctx, 1, &p, &p, &g_frame, 0, H, g_img, STRIDE, LEN);
}
static sheaf_status run_whitted(job *j) {
    /* A mirror ground and glass boxes, 4 reflections + 4 refractions. */
    static const sheaf_material mats[2] = {{{0.6f, 0.6f, 0.6f}, 0.5f, 0.0f, 1.0f},
                                           {{0.9f, 0.8f, 0.7f}, 0.1f, 0.7f, 1.5f}};
    static const sheaf_material_range ranges[2] = {{0, 0}, {2, 1}};
    sheaf_trace_params p = params_of(j);
    sheaf_whitted_params wp;
    (void)sheaf_whitted_params_default(&wp);
    sheaf_light lights[2];
    wp.max_reflect = 4;
    wp.max_refract = 4;
    lights[0] = g_frame.light;
    lights[1] = g_frame.light;
    lights[1].position[0] += 3.0f;
    return sheaf_context_render_whitted(g_ctx, &p, &p, &p, &wp, &g_frame, lights, 2, mats, 2, ranges, 2, g_img,
                                        STRIDE, LEN);
}
static sheaf_status run_build(job *j) {
    switch (j->method) {
        case SHEAF_METHOD_GRID_DDA: return sheaf_context_build_grid(g_ctx, NULL);
        case SHEAF_METHOD_BVH_SINGLE: return sheaf_context_build_bvh(g_ctx, NULL);
        case SHEAF_METHOD_KD_SINGLE: return sheaf_context_build_kd(g_ctx, NULL);
        case SHEAF_METHOD_GRID_CGT: return sheaf_context_build_pgrid(g_ctx, NULL);
        default: return scene_set(g_ctx, g_scene); /* geometry only */
    }
}
static sheaf_status run_deferred(job *j) {
    sheaf_deferred_job d;
    memset(&d, 0, sizeof d);
    d.frame = g_frame;
    /* packet 0: the perspective and light grids; else traced passes */
    d.primary_pgrid = j->packet == 0;
    d.shadow_light_grid = j->packet == 0;
    sheaf_trace_params tp = params_of(j);
    if (j->packet == 0) tp.packet = 32;
    d.primary = &tp;
    d.shadow = &tp;
    return sheaf_context_render_deferred(g_ctx, &d, g_img, STRIDE, LEN);
}

/* ---- painting --------------------------------------------------------------- */

NO_ASAN static void paint(volatile uint8_t *lo, volatile uint8_t *hi) {
    while (lo < hi) *lo++ = PAINT;
}

NO_ASAN static volatile uint8_t *lowest_touched(volatile uint8_t *lo, volatile uint8_t *hi) {
    while (lo < hi && *lo == PAINT) ++lo;
    return lo;
}

static void *on_small_stack(void *arg) {
    job *j = (job *)arg;
    pthread_attr_t a;
    void *base = NULL;
    size_t size = 0;
    volatile uint8_t here = 0;
    volatile uint8_t *top = &here - MARGIN, *bottom, *low;
    if (pthread_getattr_np(pthread_self(), &a) != 0 || pthread_attr_getstack(&a, &base, &size) != 0) {
        j->status = SHEAF_STATUS_PANIC; /* no stack bounds: fail */
        return NULL;
    }
    pthread_attr_destroy(&a);
    bottom = (volatile uint8_t *)base + 64; /* the painting must not touch the guard */
    if (!MEASURE) {
        j->status = j->run(j);
        return NULL;
    }
    paint(bottom, top);
    j->status = j->run(j);
    low = lowest_touched(bottom, top);
    j->overflow = low == bottom;
    j->used = (size_t)(&here - low);
    return NULL;
}

/* Run `j` on a fresh thread with a STACK_BYTES stack. */
static bool measure(job *j) {
    pthread_attr_t a;
    pthread_t th;
    CHECK(pthread_attr_init(&a) == 0);
    CHECK(pthread_attr_setstacksize(&a, STACK_BYTES) == 0);
    CHECK(pthread_create(&th, &a, on_small_stack, j) == 0);
    CHECK(pthread_join(th, NULL) == 0);
    pthread_attr_destroy(&a);
    return true;
}

/* ---- the scene --------------------------------------------------------------- */

static bool setup(void) {
    sheaf_limits l;
    sheaf_pgrid_params pp;
    uint32_t x, y, i = 0;
    int bx, by;
    g_scene = scene_new();
    scene_ground(g_scene, 4.0f);
    for (bx = -2; bx <= 2; ++bx)
        for (by = -2; by <= 2; ++by)
            scene_box(g_scene, bx * 1.2f - 0.4f, by * 1.2f - 0.4f, 0.0f, bx * 1.2f + 0.4f, by * 1.2f + 0.4f,
                      0.5f + 0.1f * (float)(bx + by + 4));
    CHECK_OK(sheaf_limits_default(g_scene->nt, &l));
    l.max_image_width = W;
    l.max_image_height = H;
    l.max_threads = 2;
    l.structures = SHEAF_STRUCTURE_GRID | SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_KD | SHEAF_STRUCTURE_PGRID;
    CHECK_OK(sheaf_context_create(&l, &g_ctx));
    CHECK_OK(scene_set(g_ctx, g_scene));
    CHECK_OK(sheaf_context_build_grid(g_ctx, NULL));
    CHECK_OK(sheaf_context_build_bvh(g_ctx, NULL));
    CHECK_OK(sheaf_context_build_kd(g_ctx, NULL));
    CHECK_OK(sheaf_pgrid_params_default(&pp));
    CHECK_OK(sheaf_context_build_pgrid(g_ctx, &pp));
    g_frame = default_frame(W, H);
    /* Camera rays in 32x32 blocks of 2x2 quads, so packets are coherent. */
    for (y = 0; y < H; y += 2)
        for (x = 0; x < W; x += 2) {
            CHECK_OK(sheaf_frame_camera_ray(&g_frame, x, y, &g_rays[i++]));
            CHECK_OK(sheaf_frame_camera_ray(&g_frame, x + 1, y, &g_rays[i++]));
            CHECK_OK(sheaf_frame_camera_ray(&g_frame, x, y + 1, &g_rays[i++]));
            CHECK_OK(sheaf_frame_camera_ray(&g_frame, x + 1, y + 1, &g_rays[i++]));
        }
    /* A few tiny directions: the packets' tiny-lane fallback runs too. */
    for (i = 5; i < NRAYS; i += 997) g_rays[i].dir[0] = g_rays[i].dir[1] = 1e-30f;
    return true;
}

/* ---- the calls --------------------------------------------------------------- */

static const sheaf_method METHODS[] = {
    SHEAF_METHOD_GRID_DDA,   SHEAF_METHOD_GRID_CGT,     SHEAF_METHOD_BVH_SINGLE,
    SHEAF_METHOD_BVH_SIMD,   SHEAF_METHOD_BVH_MASKED,   SHEAF_METHOD_BVH_RANGED,
    SHEAF_METHOD_BVH_PARTITION, SHEAF_METHOD_KD_SINGLE, SHEAF_METHOD_KD_SIMD,
    SHEAF_METHOD_KD_PACKET,
};
#define N_METHODS (sizeof METHODS / sizeof METHODS[0])

static const struct {
    const char *call;
    sheaf_status (*run)(job *);
} CALLS[] = {
    {"build", run_build},
    {"trace", run_trace},
    {"occluded", run_occluded},
    {"trace_with", run_trace_with},
    {"occluded_with", run_occluded_with},
    {"trace_slot", run_trace_slot},
    {"occluded_slot", run_occluded_slot},
    {"render", run_render},
    {"render_with", run_render_with},
    {"render_rows", run_render_rows},
    {"render_whitted", run_whitted},
    {"render_deferred", run_deferred},
};
#define N_CALLS (sizeof CALLS / sizeof CALLS[0])

static bool test_every_call_fits_16k_of_a_64k_stack(void) {
    bool report = getenv("STACK_REPORT") != NULL;
    size_t worst = 0, c, m;
    const char *worst_call = "";
    CHECK(setup());
    if (report) printf("    %-16s %-22s %7s\n", "call", "method (packet 32)", "bytes");
    for (c = 0; c < N_CALLS; ++c) {
        size_t call_worst = 0;
        for (m = 0; m < N_METHODS; ++m) {
            job j;
            memset(&j, 0, sizeof j);
            j.call = CALLS[c].call;
            j.method = METHODS[m];
            j.packet = 32;
            j.run = CALLS[c].run;
            /* Deferred frames: the perspective and light grids (packet 0 here
               means "grids"), then traced passes with each method. */
            if (CALLS[c].run == run_deferred && m == 0) j.packet = 0;
            CHECK(measure(&j));
            if (j.status != SHEAF_STATUS_OK) {
                fprintf(stderr, "    %s / method %u: %s\n", j.call, (unsigned)j.method,
                        sheaf_status_string(j.status));
            }
            CHECK_OK(j.status);
            CHECK(!j.overflow);
            if (report) printf("    %-16s %-22u %7zu\n", j.call, (unsigned)j.method, j.used);
            if (j.used > BUDGET) {
                fprintf(stderr, "    %s / method %u used %zu bytes of stack (budget %d)\n", j.call,
                        (unsigned)j.method, j.used, BUDGET);
            }
            if (j.used > call_worst) call_worst = j.used;
            if (j.used > worst) {
                worst = j.used;
                worst_call = j.call;
            }
        }
        printf("    %-16s at most %6zu bytes of stack\n", CALLS[c].call, call_worst);
    }
    if (MEASURE) {
        printf("    worst: %s, %zu bytes (budget %d, thread stack %d)\n", worst_call, worst, BUDGET, STACK_BYTES);
    } else {
        printf("    every call ran on a %d-byte stack (AddressSanitizer: not measured)\n", STACK_BYTES);
    }
    CHECK(worst <= BUDGET);
    sheaf_context_destroy(g_ctx);
    free(g_scene);
    return true;
}

int main(void) {
    int passed = 0, failed = 0;
    run_test("every call fits 16 KiB of a 64 KiB stack", test_every_call_fits_16k_of_a_64k_stack, &passed,
             &failed);
    return report(passed, failed);
}
