/*
 * embree_bench: sheaf against Embree 3 on the same triangles and the same
 * rays, from one C program.
 *
 *   embree_bench [options] SCENE.scene...
 *
 * Each SCENE.scene is written by `sheaf export` (cli/src/cmd/export.rs
 * documents the format): triangles, one named view, the point light and
 * the renderers' shadow offset. For each scene the program
 *
 *  1. makes the camera rays of every pixel with sheaf_frame_camera_ray
 *     (bit for bit the rays sheaf's renderers shoot), in packet order:
 *     32x32 pixel tiles row by row, inside a tile 2x2 quads in Morton order
 *     (lanes (x,y), (x+1,y), (x,y+1), (x+1,y+1)), so every run of 4, 16,
 *     64 or 256 rays is a 2x2, 4x4, 8x8 or 16x16 pixel packet; Embree's
 *     4/8/16-wide packets take the same rays in the same order;
 *  2. builds sheaf's grid, BVH (LOW, MEDIUM and HIGH) and kd-tree (median
 *     build time) and traces the camera rays with the BVH single ray on the
 *     MEDIUM tree: the reference hits. HIGH splits references spatially
 *     (SBVH) into the reference reserve of the context's limits:
 *     `--bvh-reserve PERCENT` (default BVH_RESERVE_PERCENT, 50) sets
 *     sheaf_limits.max_bvh_refs to max_triangles plus that percentage of
 *     it (0: no reserve, HIGH without spatial splits);
 *  3. makes the shadow ray of every lit reference hit exactly as sheaf's
 *     renderers do (PointLight::at: from the light to the hit point moved
 *     off the surface along its facing normal by max(eps, 1e-5 |light - p|),
 *     tmin 0, tmax 1), one slot per camera ray in the same packet order
 *     (inactive slots, tmin > tmax / valid = 0, for misses and unlit
 *     points; --compact-shadows packs them), traced by both libraries;
 *  4. checks those rays against sheaf's own renderer (a deferred frame:
 *     sheaf_context_deferred_pixel / _deferred_shadow_ray, bit for bit);
 *  5. times every sheaf traversal on 1 thread (sheaf_context_trace_with for
 *     camera rays; sheaf_context_occluded, whose packets are 8x8, and
 *     trace_with at 16x16 for shadow rays), checks each against the
 *     reference, and times the fastest method of each structure (a packet
 *     method unless the single ray is faster) on every thread count, and
 *     the MEDIUM tree's fastest methods on the LOW and on the HIGH tree
 *     (each answer checked against the reference too);
 *  6. builds Embree scenes at RTC_BUILD_QUALITY_LOW (with
 *     RTC_SCENE_FLAG_DYNAMIC), MEDIUM and HIGH on devices "threads=N"
 *     (first commit, and rebuilds: rtcUpdateGeometryBuffer + commits), one
 *     triangle geometry sharing sheaf's vertex and index buffers (vertex
 *     buffer padded for Embree's 16-byte loads), and times rtcIntersect1/4/
 *     8/16 and rtcOccluded1/4/8/16 on the same rays, split across threads;
 *  7. compares hits: primary rays whose triangle id differs between the
 *     sheaf reference and rtcIntersect1 (each quality), shadow rays whose
 *     occlusion differs, each explained in f64 as a tie (two hits within
 *     TIE_REL), an edge (the ray within EDGE_BARY of a triangle's edge in
 *     barycentric terms, or its line within EDGE_REL of the edge relative to
 *     the coordinates), an end (an occluder within END_REL of the ray's end
 *     or start) or else "other" (--explain prints those);
 *  8. times a dynamic frame: rebuild + camera rays + shadow-ray generation +
 *     shadow rays (each sheaf structure with its best methods; Embree LOW
 *     dynamic with its best widths).
 *
 * Threads: sheaf's trace/occluded calls are thread-safe on a built context;
 * rays go out in chunks of 1024 (a 32x32 tile) from an atomic counter to N
 * threads (the caller and N-1 pthreads). Embree's builds run on its device
 * threads ("threads=N"); its ray queries on the same N threads as sheaf's,
 * with FTZ/DAZ set in MXCSR as Embree asks (restored afterwards: sheaf
 * does not need them). Times: clock_gettime(CLOCK_MONOTONIC), median of
 * --reps runs; the Embree ray conversions (sheaf_ray to RTCRay SoA) are
 * inside Embree's times, as an application would pay them.
 *
 * Output: progress on stderr, Markdown tables on stdout; --summary FILE
 * writes key=value lines (the test reads them); --check exits 2 when the
 * agreement is outside the named bounds below.
 *
 *   embree_bench --twolevel ENV.scene ANIM.scene OBJ.scene [--frames N] ...
 *
 * instead times an engine's frame over a two-level scene in both libraries:
 * ENV static, ANIM's vertices refit every frame (4 instances), OBJ static
 * in a ring of 16 instances turning every frame; per frame update + commit,
 * ENV's camera rays and shadow rays, each library's median frame per thread
 * count, and the (instance, triangle) agreement. The section "two-level
 * scene" below describes it.
 */
#define _POSIX_C_SOURCE 200809L

#include <embree3/rtcore.h>
#include <errno.h>
#include <math.h>
#include <pmmintrin.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/utsname.h>
#include <time.h>
#include <unistd.h>
#include <xmmintrin.h>

#include "sheaf.h"

/* ---- named bounds and constants ------------------------------------------ */

/* Relative t gap under which two hits are a tie (as `sheaf bench`). */
#define TIE_REL 1e-5
/* A ray grazes an edge when its barycentric distance to it is under
 * EDGE_BARY (as `sheaf bench`), or when the ray's line passes within
 * EDGE_REL of the edge relative to the largest coordinate magnitude
 * involved (16 f32 ulps: f32 triangle tests err by a few ulps of the
 * coordinates, more for rays at a grazing angle to the triangle). */
#define EDGE_BARY 1e-5
#define EDGE_REL 1e-6
/* Relative distance of an occluder to the shadow ray's end (or start). */
#define END_REL 1e-5
/* --check: most disagreeing rays (primary or shadow) with no tie, edge or
 * end explanation, per scene and quality. */
#define MAX_UNEXPLAINED 0
/* --check: most disagreeing rays of any kind, as a fraction of the rays
 * (ties and edges included): 1 in 10,000. */
#define MAX_DIFF_FRACTION 1e-4
/* Rays per work item handed to a thread: one 32x32 pixel tile. */
#define CHUNK 1024
/* The renderers' shadow offset relative to the ray's length (SHADOW_OFFSET_REL). */
#define SHADOW_OFFSET_REL 1e-5f
#define MAX_THREADS 16
#define MAX_REPS 31
/* The BVH's reference reserve for SHEAF_BUILD_QUALITY_HIGH's spatial splits,
 * percent of the triangles (--bvh-reserve): sheaf_limits.max_bvh_refs =
 * max_triangles + max_triangles * BVH_RESERVE_PERCENT / 100. */
#define BVH_RESERVE_PERCENT 50
#define MAX_BVH_RESERVE_PERCENT 1000

/* ---- small utilities ----------------------------------------------------- */

static void die(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "embree_bench: error: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
    exit(1);
}

static void progress(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fflush(stderr);
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    return (n % 2) ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static void *xmalloc(size_t n)
{
    void *p = NULL;
    if (posix_memalign(&p, 64, n ? n : 64) != 0)
        die("out of memory (%zu bytes)", n);
    return p;
}

static void check_sheaf(const sheaf_context *ctx, sheaf_status st, const char *what)
{
    if (st != SHEAF_STATUS_OK) {
        char msg[SHEAF_ERROR_MESSAGE_MAX] = "";
        size_t w = 0;
        if (ctx)
            sheaf_context_last_error(ctx, msg, sizeof msg, &w);
        die("%s: %s (%s)", what, sheaf_status_string(st), msg);
    }
}

static double load_average(void)
{
    double l = -1.0;
    FILE *f = fopen("/proc/loadavg", "r");
    if (f) {
        if (fscanf(f, "%lf", &l) != 1)
            l = -1.0;
        fclose(f);
    }
    return l;
}

/* ---- the scene file (sheaf export) --------------------------------------- */

typedef struct {
    char label[512];
    char view[512];
    uint32_t nv, nt, width, height, excluded;
    float eye[3], look_at[3], up[3], fov, light[3], eps;
    float *verts;   /* 3 nv floats and one more: Embree reads 16 bytes at a time */
    uint32_t *idx;  /* 3 nt */
    uint32_t nframes; /* animation frames (`sheaf export --frames`), else 0 */
    float *frames;  /* 3 nv floats per frame */
} Scene;

static uint32_t rd_u32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static float rd_f32(const unsigned char *p)
{
    uint32_t u = rd_u32(p);
    float f;
    memcpy(&f, &u, 4);
    return f;
}

static void read_scene(const char *path, Scene *s)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        die("cannot open %s: %s", path, strerror(errno));
    fseek(f, 0, SEEK_END);
    long len = ftell(f);
    fseek(f, 0, SEEK_SET);
    if (len < 88)
        die("%s: too short for a sheaf export", path);
    unsigned char *buf = malloc((size_t)len);
    if (!buf || fread(buf, 1, (size_t)len, f) != (size_t)len)
        die("cannot read %s", path);
    fclose(f);
    if (memcmp(buf, "SHEAFSC1", 8) != 0 || rd_u32(buf + 8) != 1)
        die("%s: not a version 1 sheaf export (run `sheaf export`)", path);
    memset(s, 0, sizeof *s);
    s->nv = rd_u32(buf + 12);
    s->nt = rd_u32(buf + 16);
    s->width = rd_u32(buf + 20);
    s->height = rd_u32(buf + 24);
    const unsigned char *p = buf + 28;
    for (int i = 0; i < 3; i++) s->eye[i] = rd_f32(p + 4 * i);
    for (int i = 0; i < 3; i++) s->look_at[i] = rd_f32(p + 12 + 4 * i);
    for (int i = 0; i < 3; i++) s->up[i] = rd_f32(p + 24 + 4 * i);
    s->fov = rd_f32(p + 36);
    for (int i = 0; i < 3; i++) s->light[i] = rd_f32(p + 40 + 4 * i);
    s->eps = rd_f32(p + 52);
    s->excluded = rd_u32(p + 56);
    size_t off = 88;
    char *strs[2] = {s->label, s->view};
    for (int k = 0; k < 2; k++) {
        if (off + 4 > (size_t)len)
            die("%s: truncated", path);
        uint32_t n = rd_u32(buf + off);
        off += 4;
        if (off + n > (size_t)len)
            die("%s: truncated", path);
        size_t c = n < 511 ? n : 511;
        memcpy(strs[k], buf + off, c);
        strs[k][c] = 0;
        off += n;
    }
    size_t need = off + 12 * (size_t)s->nv + 12 * (size_t)s->nt;
    if ((size_t)len >= need + 4) {
        /* The optional animation: u32 F, then F frames of 3 nv floats. */
        s->nframes = rd_u32(buf + need);
        size_t fb = 12 * (size_t)s->nv * s->nframes;
        if ((size_t)len != need + 4 + fb)
            die("%s: %ld bytes, expected %zu for %u frames", path, len, need + 4 + fb, s->nframes);
        s->frames = xmalloc(fb + 4);
        for (size_t i = 0; i < 3 * (size_t)s->nv * s->nframes; i++) s->frames[i] = rd_f32(buf + need + 4 + 4 * i);
    } else if ((size_t)len != need)
        die("%s: %ld bytes, expected %zu", path, len, need);
    s->verts = xmalloc(4 * (3 * (size_t)s->nv + 1));
    s->idx = xmalloc(12 * (size_t)s->nt + 4);
    for (size_t i = 0; i < 3 * (size_t)s->nv; i++) s->verts[i] = rd_f32(buf + off + 4 * i);
    s->verts[3 * (size_t)s->nv] = 0.0f;
    off += 12 * (size_t)s->nv;
    for (size_t i = 0; i < 3 * (size_t)s->nt; i++) {
        s->idx[i] = rd_u32(buf + off + 4 * i);
        if (s->idx[i] >= s->nv)
            die("%s: index %u out of range", path, s->idx[i]);
    }
    free(buf);
}

/* ---- rays ------------------------------------------------------------------ */

/* Quad (x, y) of Morton index i (x in the even bits), as sheaf's renderer. */
static void demorton(uint32_t i, uint32_t *x, uint32_t *y)
{
    *x = *y = 0;
    for (int b = 0; b < 5; b++) {
        *x |= ((i >> (2 * b)) & 1u) << b;
        *y |= ((i >> (2 * b + 1)) & 1u) << b;
    }
}

typedef struct { float x, y, z; } V3;
static V3 v3(const float *p) { V3 r = {p[0], p[1], p[2]}; return r; }
static V3 sub(V3 a, V3 b) { V3 r = {a.x - b.x, a.y - b.y, a.z - b.z}; return r; }
static V3 add(V3 a, V3 b) { V3 r = {a.x + b.x, a.y + b.y, a.z + b.z}; return r; }
static V3 mul(V3 a, float s) { V3 r = {a.x * s, a.y * s, a.z * s}; return r; }
/* glam's Vec3::dot and Vec3::cross, term for term. */
static float dot(V3 a, V3 b) { return (a.x * b.x) + (a.y * b.y) + (a.z * b.z); }
static V3 cross(V3 a, V3 b)
{
    V3 r = {a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y};
    return r;
}
static float length(V3 a) { return sqrtf(dot(a, a)); }
/* glam's normalize_or_zero: times 1/length when that is finite and positive. */
static V3 normalize_or_zero(V3 a)
{
    float rcp = 1.0f / length(a);
    if (isfinite(rcp) && rcp > 0.0f)
        return mul(a, rcp);
    V3 z = {0, 0, 0};
    return z;
}

/* The shadow ray sheaf's renderers shoot for the camera ray `r` hitting
 * the triangle (a, b, c) at `t` toward the point light `light_p` with the
 * scene's shadow offset `eps` (render::deferred::shadow_ray, PointLight::at
 * for a point light): 1 and *out when the surface faces the light, else 0. */
static int shadow_ray_tri(V3 a, V3 b, V3 c, const float *light_p, float eps, const sheaf_ray *r, float t,
                          sheaf_ray *out)
{
    V3 n = normalize_or_zero(cross(sub(b, a), sub(c, a)));
    V3 d = v3(r->dir);
    if (dot(n, d) > 0.0f)
        n = mul(n, -1.0f);
    V3 p = add(v3(r->org), mul(d, t));
    V3 light = v3(light_p);
    V3 to = sub(light, p);
    float len = length(to);
    to = normalize_or_zero(to);
    float lit = dot(n, to) * 1.0f; /* a point light's spot factor is 1 */
    if (!(lit > 0.0f))
        return 0;
    float rel = SHADOW_OFFSET_REL * len;
    float off = eps > rel ? eps : rel; /* f32::max */
    if (isnan(eps)) off = rel;
    V3 end = add(p, mul(n, off));
    V3 dir = sub(end, light);
    out->org[0] = light.x; out->org[1] = light.y; out->org[2] = light.z;
    out->tmin = 0.0f;
    out->dir[0] = dir.x; out->dir[1] = dir.y; out->dir[2] = dir.z;
    out->tmax = 1.0f;
    return 1;
}

/* The shadow ray for the camera ray `r` hitting triangle `prim` of `s` at
 * `t`, toward the scene's light (shadow_ray_tri). */
static int shadow_ray(const Scene *s, const sheaf_ray *r, float t, uint32_t prim, sheaf_ray *out)
{
    const uint32_t *i = s->idx + 3 * (size_t)prim;
    return shadow_ray_tri(v3(s->verts + 3 * (size_t)i[0]), v3(s->verts + 3 * (size_t)i[1]),
                          v3(s->verts + 3 * (size_t)i[2]), s->light, s->eps, r, t, out);
}

/* A slot without a shadow ray (a miss, or a surface facing away from the
 * light): tmin > tmax, which sheaf reports as a miss without tracing it and
 * Embree gets as an invalid lane (valid = 0) or skips. */
static void inactive_ray(const Scene *s, sheaf_ray *out)
{
    memcpy(out->org, s->light, sizeof out->org);
    out->tmin = 0.0f;
    out->dir[0] = 1.0f;
    out->dir[1] = out->dir[2] = 0.0f;
    out->tmax = -1.0f;
}

static int is_active(const sheaf_ray *r) { return r->tmax >= r->tmin; }

/* ---- work split across threads --------------------------------------------- */

enum Lib { LIB_SHEAF, LIB_EMBREE };
/* K_SCENE_TRACE / K_SCENE_OCC: sheaf's two-level scene
 * (sheaf_context_trace_scene / _occluded_scene with `params`). */
enum Kind { K_TRACE, K_OCCLUDED, K_TRACE_OCC, K_FRAME_SHADOW, K_SCENE_TRACE, K_SCENE_OCC };

typedef struct Job Job;
struct Job {
    size_t n;          /* rays (or pixels for K_FRAME_SHADOW) */
    size_t next;       /* next unclaimed ray, atomic */
    int lib, kind;
    /* sheaf */
    const sheaf_context *ctx;
    sheaf_trace_params params; /* K_TRACE, K_TRACE_OCC, K_FRAME_SHADOW (trace_with shadows) */
    sheaf_method occ_method;   /* K_OCCLUDED and K_FRAME_SHADOW with occ_via_trace == 0 */
    int occ_via_trace;
    int compact;       /* K_FRAME_SHADOW: shadow rays packed, else one slot per pixel */
    /* Embree */
    RTCScene scene;
    int width;         /* 1, 4, 8, 16 */
    int incoherent;    /* RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT (else COHERENT) */
    /* data */
    const Scene *s;
    const sheaf_ray *rays;
    sheaf_hit *hits;       /* sheaf K_TRACE output; K_FRAME_SHADOW input (sheaf) */
    uint32_t *prim;        /* Embree K_TRACE output; K_FRAME_SHADOW input (Embree) */
    uint32_t *inst;        /* Embree K_TRACE output when not NULL: instID[0] (two-level scene) */
    sheaf_scene_hit *shits; /* sheaf K_SCENE_TRACE output */
    float *t;              /* Embree K_TRACE output; K_FRAME_SHADOW input (Embree) */
    uint8_t *occ;          /* K_OCCLUDED / K_TRACE_OCC output */
    size_t shadow_rays, occluded; /* K_FRAME_SHADOW counts, atomic */
    int status;            /* first sheaf error */
    /* "soa:NAME" (sheaf): the rays as a stream (sheaf_ray_stream, packed
     * arrays made before the timing) and the hits into a hit stream */
    float *soa[8];         /* org x y z, dir x y z, tmin, tmax; NULL: sheaf_ray arrays */
    float *sh[3];          /* stream hits t, u, v */
    uint32_t *sh_prim;
    /* "cam:NAME" (sheaf): camera rays made in the kernel, one 32x32 tile
     * per chunk (sheaf_context_trace_camera), hits per pixel into cam_hits */
    const sheaf_frame *frame;
    sheaf_hit *cam_hits;
    const uint32_t *pix;   /* K_FRAME_SHADOW with cam_hits: ray k's pixel */
    int stream_shadows;    /* K_FRAME_SHADOW (sheaf): shadow rays as ray streams */
    /* Embree K_TRACE: camera rays laid out as RTCRayHit16 before the timing */
    struct RTCRayHit16 *prep;
};

static void embree_trace(Job *j, size_t b, size_t e);
static void embree_occluded(Job *j, const sheaf_ray *rays, uint8_t *occ, size_t n);

static void sheaf_occluded_n(Job *j, const sheaf_ray *rays, uint8_t *occ, size_t n)
{
    sheaf_status st;
    if (j->occ_via_trace) {
        sheaf_hit h[CHUNK];
        st = sheaf_context_trace_with(j->ctx, &j->params, rays, h, n);
        for (size_t k = 0; k < n && st == SHEAF_STATUS_OK; k++)
            occ[k] = h[k].prim != SHEAF_INVALID_ID;
    } else {
        /* The configuration's packet side (sheaf_context_occluded would take 8x8). */
        sheaf_trace_params p = j->params;
        p.method = j->occ_method;
        st = sheaf_context_occluded_with(j->ctx, &p, rays, occ, n);
    }
    if (st != SHEAF_STATUS_OK)
        j->status = (int)st;
}

/* Occlusion of n rays handed to sheaf as a packed ray stream (the layout
 * conversion is the caller's, inside the time, as Embree's). */
static void sheaf_occluded_stream_n(Job *j, const sheaf_ray *rays, uint8_t *occ, size_t n)
{
    float f[8][CHUNK], ht[3][CHUNK]; /* 44 KB of the thread's stack */
    uint32_t hp[CHUNK];
    for (size_t k = 0; k < n; k++) {
        const sheaf_ray *r = &rays[k];
        f[0][k] = r->org[0], f[1][k] = r->org[1], f[2][k] = r->org[2];
        f[3][k] = r->dir[0], f[4][k] = r->dir[1], f[5][k] = r->dir[2];
        f[6][k] = r->tmin, f[7][k] = r->tmax;
    }
    sheaf_ray_stream rs = {f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], sizeof(float)};
    sheaf_status st;
    if (j->occ_via_trace) {
        sheaf_hit_stream hs = {ht[0], ht[1], ht[2], hp, NULL, NULL, sizeof(float)};
        st = sheaf_context_trace_stream(j->ctx, &j->params, &rs, &hs, n);
        for (size_t k = 0; k < n && st == SHEAF_STATUS_OK; k++) occ[k] = hp[k] != SHEAF_INVALID_ID;
    } else {
        sheaf_trace_params p = j->params;
        p.method = j->occ_method;
        st = sheaf_context_occluded_stream(j->ctx, &p, &rs, occ, n);
    }
    if (st != SHEAF_STATUS_OK)
        j->status = (int)st;
}

static void frame_shadows(Job *j, size_t b, size_t e)
{
    sheaf_ray sr[CHUNK];
    uint8_t occ[CHUNK];
    size_t m = 0;
    for (size_t k = b; k < e; k++) {
        uint32_t prim;
        float t;
        if (j->lib == LIB_SHEAF) {
            const sheaf_hit *h = j->cam_hits ? &j->cam_hits[j->pix[k]] : &j->hits[k];
            prim = h->prim;
            t = h->t;
        } else {
            prim = j->prim[k];
            t = j->t[k];
        }
        if (prim != SHEAF_INVALID_ID && shadow_ray(j->s, &j->rays[k], t, prim, &sr[m]))
            m++;
        else if (!j->compact)
            inactive_ray(j->s, &sr[m++]);
    }
    if (m == 0)
        return;
    if (j->lib == LIB_SHEAF && j->stream_shadows)
        sheaf_occluded_stream_n(j, sr, occ, m);
    else if (j->lib == LIB_SHEAF)
        sheaf_occluded_n(j, sr, occ, m);
    else
        embree_occluded(j, sr, occ, m);
    size_t o = 0, a = 0;
    for (size_t k = 0; k < m; k++) {
        o += occ[k];
        a += is_active(&sr[k]);
    }
    __atomic_fetch_add(&j->shadow_rays, a, __ATOMIC_RELAXED);
    __atomic_fetch_add(&j->occluded, o, __ATOMIC_RELAXED);
}

/* Rays b..e of the job's stream (soa:) and its hit stream. */
static sheaf_ray_stream soa_rays(const Job *j, size_t b)
{
    sheaf_ray_stream r = {j->soa[0] + b, j->soa[1] + b, j->soa[2] + b, j->soa[3] + b,
                          j->soa[4] + b, j->soa[5] + b, j->soa[6] + b, j->soa[7] + b, sizeof(float)};
    return r;
}

/* The chunk of rays b..e (one 32x32 tile: camera_rays' order) traced as
 * camera packets made in the kernel, hits per pixel. */
static void camera_chunk(Job *j, size_t b)
{
    const sheaf_frame *f = j->frame;
    uint32_t c = (uint32_t)(b / CHUNK), tiles_x = f->width / 32;
    sheaf_pixel_rect r = {32 * (c % tiles_x), 32 * (c / tiles_x), 0, 0};
    r.x1 = r.x0 + 32;
    r.y1 = r.y0 + 32;
    sheaf_status st = sheaf_context_trace_camera(j->ctx, &j->params, &f->camera, f->width, f->height, &r,
                                                 j->cam_hits + (size_t)r.y0 * f->width + r.x0, f->width);
    if (st != SHEAF_STATUS_OK)
        j->status = (int)st;
}

static void run_chunk(Job *j, size_t b, size_t e)
{
    if (j->cam_hits && j->kind == K_TRACE) {
        camera_chunk(j, b);
        return;
    }
    if (j->soa[0] && j->lib == LIB_SHEAF && (j->kind == K_TRACE || j->kind == K_OCCLUDED)) {
        sheaf_ray_stream r = soa_rays(j, b);
        sheaf_status st;
        if (j->kind == K_TRACE) {
            sheaf_hit_stream h = {j->sh[0] + b, j->sh[1] + b, j->sh[2] + b, j->sh_prim + b, NULL, NULL,
                                  sizeof(float)};
            st = sheaf_context_trace_stream(j->ctx, &j->params, &r, &h, e - b);
        } else {
            sheaf_trace_params p = j->params;
            p.method = j->occ_method;
            st = sheaf_context_occluded_stream(j->ctx, &p, &r, j->occ + b, e - b);
        }
        if (st != SHEAF_STATUS_OK)
            j->status = (int)st;
        return;
    }
    if (j->kind == K_FRAME_SHADOW) {
        frame_shadows(j, b, e);
        return;
    }
    if (j->lib == LIB_SHEAF) {
        sheaf_status st = SHEAF_STATUS_OK;
        if (j->kind == K_TRACE)
            st = sheaf_context_trace_with(j->ctx, &j->params, j->rays + b, j->hits + b, e - b);
        else if (j->kind == K_SCENE_TRACE)
            st = sheaf_context_trace_scene(j->ctx, &j->params, j->rays + b, j->shits + b, e - b, ~0u, 0);
        else if (j->kind == K_SCENE_OCC)
            st = sheaf_context_occluded_scene(j->ctx, &j->params, j->rays + b, j->occ + b, e - b, ~0u, 0);
        else
            sheaf_occluded_n(j, j->rays + b, j->occ + b, e - b);
        if (st != SHEAF_STATUS_OK)
            j->status = (int)st;
    } else if (j->kind == K_TRACE) {
        embree_trace(j, b, e);
    } else {
        embree_occluded(j, j->rays + b, j->occ + b, e - b);
    }
}

static void *worker(void *arg)
{
    Job *j = arg;
    unsigned csr = _mm_getcsr();
    if (j->lib == LIB_EMBREE) {
        _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
        _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
    }
    for (;;) {
        size_t b = __atomic_fetch_add(&j->next, (size_t)CHUNK, __ATOMIC_RELAXED);
        if (b >= j->n)
            break;
        size_t e = b + CHUNK < j->n ? b + CHUNK : j->n;
        run_chunk(j, b, e);
    }
    _mm_setcsr(csr);
    return NULL;
}

/* Run `j` on `threads` threads (the caller and threads - 1 pthreads); seconds. */
static double run_job(Job *j, int threads)
{
    pthread_t th[MAX_THREADS];
    j->next = 0;
    j->shadow_rays = j->occluded = 0;
    double t0 = now_s();
    for (int i = 1; i < threads; i++)
        if (pthread_create(&th[i], NULL, worker, j) != 0)
            die("pthread_create failed");
    worker(j);
    for (int i = 1; i < threads; i++) pthread_join(th[i], NULL);
    double t1 = now_s();
    if (j->status != 0)
        die("sheaf trace failed: %s", sheaf_status_string((sheaf_status)j->status));
    return t1 - t0;
}

/* ---- Embree ray queries ------------------------------------------------------ */

#define FILL_LANE(R, l, src)                                      \
    do {                                                          \
        (R).org_x[l] = (src)->org[0];                             \
        (R).org_y[l] = (src)->org[1];                             \
        (R).org_z[l] = (src)->org[2];                             \
        (R).tnear[l] = (src)->tmin;                               \
        (R).dir_x[l] = (src)->dir[0];                             \
        (R).dir_y[l] = (src)->dir[1];                             \
        (R).dir_z[l] = (src)->dir[2];                             \
        (R).time[l] = 0.0f;                                       \
        (R).tfar[l] = (src)->tmax;                                \
        (R).mask[l] = 0xFFFFFFFFu;                                \
        (R).id[l] = 0;                                            \
        (R).flags[l] = 0;                                         \
    } while (0)

#define TRACE_N(W, RH, FN)                                                           \
    for (size_t k = b; k < e; k += W) {                                               \
        RH rh;                                                                        \
        int valid[W];                                                                 \
        for (int l = 0; l < W; l++) {                                                 \
            size_t r = k + (size_t)l < e ? k + (size_t)l : e - 1;                     \
            valid[l] = k + (size_t)l < e ? -1 : 0;                                    \
            FILL_LANE(rh.ray, l, &j->rays[r]);                                        \
            rh.hit.geomID[l] = RTC_INVALID_GEOMETRY_ID;                               \
            rh.hit.instID[0][l] = RTC_INVALID_GEOMETRY_ID;                            \
        }                                                                             \
        FN(valid, j->scene, &ctx, &rh);                                               \
        for (int l = 0; l < W && k + (size_t)l < e; l++) {                            \
            int hit = rh.hit.geomID[l] != RTC_INVALID_GEOMETRY_ID;                    \
            j->prim[k + l] = hit ? rh.hit.primID[l] : SHEAF_INVALID_ID;               \
            j->t[k + l] = hit ? rh.ray.tfar[l] : INFINITY;                            \
            if (j->inst)                                                              \
                j->inst[k + l] = hit ? rh.hit.instID[0][l] : SHEAF_INVALID_ID;        \
        }                                                                             \
    }

#define OCCLUDED_N(W, RT, FN)                                                        \
    for (size_t k = 0; k < n; k += W) {                                               \
        RT ray;                                                                       \
        int valid[W];                                                                 \
        for (int l = 0; l < W; l++) {                                                 \
            size_t r = k + (size_t)l < n ? k + (size_t)l : n - 1;                     \
            valid[l] = k + (size_t)l < n && is_active(&rays[r]) ? -1 : 0;              \
            FILL_LANE(ray, l, &rays[r]);                                              \
        }                                                                             \
        FN(valid, j->scene, &ctx, &ray);                                              \
        for (int l = 0; l < W && k + (size_t)l < n; l++)                              \
            occ[k + l] = valid[l] && ray.tfar[l] < 0.0f;                              \
    }

/* rtcIntersect16 on the camera rays laid out as RTCRayHit16 before the
 * timing (b, e multiples of 16): each frame resets the packets' tfar (the
 * camera rays' tmax, +inf) and hit ids, then reads the hits out as
 * embree_trace does. */
static void embree_trace_prepared(Job *j, size_t b, size_t e)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    int valid[16];
    for (int l = 0; l < 16; l++) valid[l] = -1;
    for (size_t k = b; k < e; k += 16) {
        struct RTCRayHit16 *rh = &j->prep[k / 16];
        for (int l = 0; l < 16; l++) {
            rh->ray.tfar[l] = INFINITY;
            rh->hit.geomID[l] = RTC_INVALID_GEOMETRY_ID;
            rh->hit.instID[0][l] = RTC_INVALID_GEOMETRY_ID;
        }
        rtcIntersect16(valid, j->scene, &ctx, rh);
        for (int l = 0; l < 16; l++) {
            int hit = rh->hit.geomID[l] != RTC_INVALID_GEOMETRY_ID;
            j->prim[k + l] = hit ? rh->hit.primID[l] : SHEAF_INVALID_ID;
            j->t[k + l] = hit ? rh->ray.tfar[l] : INFINITY;
        }
    }
}

static void embree_trace(Job *j, size_t b, size_t e)
{
    if (j->prep) {
        embree_trace_prepared(j, b, e);
        return;
    }
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    ctx.flags = j->incoherent ? RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT : RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    switch (j->width) {
    case 1:
        for (size_t k = b; k < e; k++) {
            struct RTCRayHit rh;
            const sheaf_ray *r = &j->rays[k];
            rh.ray.org_x = r->org[0];
            rh.ray.org_y = r->org[1];
            rh.ray.org_z = r->org[2];
            rh.ray.tnear = r->tmin;
            rh.ray.dir_x = r->dir[0];
            rh.ray.dir_y = r->dir[1];
            rh.ray.dir_z = r->dir[2];
            rh.ray.time = 0.0f;
            rh.ray.tfar = r->tmax;
            rh.ray.mask = 0xFFFFFFFFu;
            rh.ray.id = 0;
            rh.ray.flags = 0;
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
            rtcIntersect1(j->scene, &ctx, &rh);
            int hit = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
            j->prim[k] = hit ? rh.hit.primID : SHEAF_INVALID_ID;
            j->t[k] = hit ? rh.ray.tfar : INFINITY;
            if (j->inst)
                j->inst[k] = hit ? rh.hit.instID[0] : SHEAF_INVALID_ID;
        }
        break;
    case 4: TRACE_N(4, struct RTCRayHit4, rtcIntersect4) break;
    case 8: TRACE_N(8, struct RTCRayHit8, rtcIntersect8) break;
    default: TRACE_N(16, struct RTCRayHit16, rtcIntersect16) break;
    }
}

static void embree_occluded(Job *j, const sheaf_ray *rays, uint8_t *occ, size_t n)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    ctx.flags = j->incoherent ? RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT : RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    switch (j->width) {
    case 1:
        for (size_t k = 0; k < n; k++) {
            struct RTCRay ray;
            const sheaf_ray *r = &rays[k];
            if (!is_active(r)) {
                occ[k] = 0;
                continue;
            }
            ray.org_x = r->org[0];
            ray.org_y = r->org[1];
            ray.org_z = r->org[2];
            ray.tnear = r->tmin;
            ray.dir_x = r->dir[0];
            ray.dir_y = r->dir[1];
            ray.dir_z = r->dir[2];
            ray.time = 0.0f;
            ray.tfar = r->tmax;
            ray.mask = 0xFFFFFFFFu;
            ray.id = 0;
            ray.flags = 0;
            rtcOccluded1(j->scene, &ctx, &ray);
            occ[k] = ray.tfar < 0.0f;
        }
        break;
    case 4: OCCLUDED_N(4, struct RTCRay4, rtcOccluded4) break;
    case 8: OCCLUDED_N(8, struct RTCRay8, rtcOccluded8) break;
    default: OCCLUDED_N(16, struct RTCRay16, rtcOccluded16) break;
    }
}

/* Embree's nearest hit of one ray (the occluder of a shadow ray). */
static uint32_t embree_nearest(RTCScene scene, const sheaf_ray *r)
{
    struct RTCIntersectContext ctx;
    struct RTCRayHit rh;
    rtcInitIntersectContext(&ctx);
    rh.ray.org_x = r->org[0];
    rh.ray.org_y = r->org[1];
    rh.ray.org_z = r->org[2];
    rh.ray.tnear = r->tmin;
    rh.ray.dir_x = r->dir[0];
    rh.ray.dir_y = r->dir[1];
    rh.ray.dir_z = r->dir[2];
    rh.ray.time = 0.0f;
    rh.ray.tfar = r->tmax;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene, &ctx, &rh);
    return rh.hit.geomID != RTC_INVALID_GEOMETRY_ID ? rh.hit.primID : SHEAF_INVALID_ID;
}

static void embree_error(void *user, enum RTCError code, const char *msg)
{
    (void)user;
    fprintf(stderr, "embree_bench: Embree error %d: %s\n", (int)code, msg ? msg : "");
}

typedef struct {
    RTCScene scene;
    RTCGeometry geom;
} EScene;

static const char *QUALITY_NAME[3] = {"LOW", "MEDIUM", "HIGH"};

/* Quality index of a LOW + DYNAMIC scene whose geometry is committed with
 * RTC_BUILD_QUALITY_REFIT: later commits refit its BVH. */
#define Q_REFIT 3

/* A new Embree scene of `s` at quality q (LOW, MEDIUM, HIGH or Q_REFIT; LOW
 * and Q_REFIT with RTC_SCENE_FLAG_DYNAMIC), one triangle geometry sharing the
 * scene's buffers; seconds to first commit. */
static double embree_build(RTCDevice dev, const Scene *s, int q, EScene *out)
{
    enum RTCBuildQuality quality = q == 1 ? RTC_BUILD_QUALITY_MEDIUM
                                 : q == 2 ? RTC_BUILD_QUALITY_HIGH
                                          : RTC_BUILD_QUALITY_LOW;
    double t0 = now_s();
    RTCScene sc = rtcNewScene(dev);
    rtcSetSceneFlags(sc, q == 0 || q == Q_REFIT ? RTC_SCENE_FLAG_DYNAMIC : RTC_SCENE_FLAG_NONE);
    rtcSetSceneBuildQuality(sc, quality);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(g, q == Q_REFIT ? RTC_BUILD_QUALITY_REFIT : quality);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, s->verts, 0,
                               3 * sizeof(float), s->nv);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, s->idx, 0,
                               3 * sizeof(uint32_t), s->nt);
    rtcCommitGeometry(g);
    rtcAttachGeometryByID(sc, g, 0);
    rtcCommitScene(sc);
    double t1 = now_s();
    if (rtcGetDeviceError(dev) != RTC_ERROR_NONE)
        die("Embree build failed");
    out->scene = sc;
    out->geom = g;
    return t1 - t0;
}

/* A per-frame rebuild: the vertices changed (in place), commit again. */
static double embree_rebuild(EScene *e)
{
    double t0 = now_s();
    rtcUpdateGeometryBuffer(e->geom, RTC_BUFFER_TYPE_VERTEX, 0);
    rtcCommitGeometry(e->geom);
    rtcCommitScene(e->scene);
    return now_s() - t0;
}

static void embree_release(EScene *e)
{
    rtcReleaseGeometry(e->geom);
    rtcReleaseScene(e->scene);
}

/* ---- f64 explanations of disagreements ----------------------------------------- */

typedef struct {
    double t, u, v;
    int ok; /* a non-degenerate triangle */
} Hit64;

/* Moller-Trumbore in f64 without range checks: t and the barycentrics. */
static Hit64 isect64(const Scene *s, const sheaf_ray *r, uint32_t prim)
{
    Hit64 h = {0, 0, 0, 0};
    const uint32_t *i = s->idx + 3 * (size_t)prim;
    double a[3], b[3], c[3], o[3], d[3];
    for (int k = 0; k < 3; k++) {
        a[k] = s->verts[3 * (size_t)i[0] + k];
        b[k] = s->verts[3 * (size_t)i[1] + k];
        c[k] = s->verts[3 * (size_t)i[2] + k];
        o[k] = r->org[k];
        d[k] = r->dir[k];
    }
    double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double p[3] = {d[1] * e2[2] - d[2] * e2[1], d[2] * e2[0] - d[0] * e2[2], d[0] * e2[1] - d[1] * e2[0]};
    double det = e1[0] * p[0] + e1[1] * p[1] + e1[2] * p[2];
    if (det == 0.0 || !isfinite(det))
        return h;
    double inv = 1.0 / det;
    double tv[3] = {o[0] - a[0], o[1] - a[1], o[2] - a[2]};
    h.u = (tv[0] * p[0] + tv[1] * p[1] + tv[2] * p[2]) * inv;
    double q[3] = {tv[1] * e1[2] - tv[2] * e1[1], tv[2] * e1[0] - tv[0] * e1[2], tv[0] * e1[1] - tv[1] * e1[0]};
    h.v = (d[0] * q[0] + d[1] * q[1] + d[2] * q[2]) * inv;
    h.t = (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) * inv;
    h.ok = 1;
    return h;
}

/* How close the ray passes to an edge of `prim` (|smallest barycentric|). */
static double edge_gap(Hit64 h)
{
    if (!h.ok)
        return 0.0; /* degenerate: every ray grazes it */
    double w = 1.0 - h.u - h.v;
    double m = fabs(h.u);
    if (fabs(h.v) < m) m = fabs(h.v);
    if (fabs(w) < m) m = fabs(w);
    return m;
}

static int g_explain; /* --explain: print each unexplained disagreement */

/* Distance from the ray's line to the nearest edge of `prim`, relative to
 * the largest coordinate magnitude of the triangle and the ray's origin
 * (f32 triangle tests err by some ulps of that magnitude; a grazing ray
 * passes close to the edges even where it crosses the plane far from them). */
static double edge_distance_rel(const Scene *s, const sheaf_ray *r, uint32_t prim)
{
    const uint32_t *ix = s->idx + 3 * (size_t)prim;
    double v[3][3], o[3], d[3], mag = 0.0, best = INFINITY;
    for (int k = 0; k < 3; k++) {
        o[k] = r->org[k];
        d[k] = r->dir[k];
        if (fabs(o[k]) > mag) mag = fabs(o[k]);
        for (int c = 0; c < 3; c++) {
            v[c][k] = s->verts[3 * (size_t)ix[c] + k];
            if (fabs(v[c][k]) > mag) mag = fabs(v[c][k]);
        }
    }
    for (int c = 0; c < 3; c++) {
        const double *a = v[c], *b = v[(c + 1) % 3];
        double e[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double w[3] = {o[0] - a[0], o[1] - a[1], o[2] - a[2]};
        double A = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        double B = d[0] * e[0] + d[1] * e[1] + d[2] * e[2];
        double C = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
        double D = d[0] * w[0] + d[1] * w[1] + d[2] * w[2];
        double E = e[0] * w[0] + e[1] * w[1] + e[2] * w[2];
        double den = A * C - B * B, rr;
        /* Closest point of the segment (parameter rr in [0, 1]) to the line. */
        if (C == 0.0)
            rr = 0.0;
        else if (den <= 1e-15 * A * C)
            rr = 0.0; /* parallel: any point; the endpoints are checked below too */
        else
            rr = (A * E - B * D) / den;
        double cand[3] = {rr < 0 ? 0 : rr > 1 ? 1 : rr, 0.0, 1.0};
        for (int i = 0; i < 3; i++) {
            double q[3] = {a[0] + cand[i] * e[0] - o[0], a[1] + cand[i] * e[1] - o[1], a[2] + cand[i] * e[2] - o[2]};
            double sq = (q[0] * d[0] + q[1] * d[1] + q[2] * d[2]) / A; /* closest point of the line */
            double x[3] = {q[0] - sq * d[0], q[1] - sq * d[1], q[2] - sq * d[2]};
            double dist = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
            if (dist < best) best = dist;
        }
    }
    return mag > 0 ? best / mag : best;
}

static int grazes(const Scene *s, const sheaf_ray *r, uint32_t prim, Hit64 h)
{
    return edge_gap(h) <= EDGE_BARY || edge_distance_rel(s, r, prim) <= EDGE_REL;
}

typedef struct {
    size_t rays, hits_sheaf, hits_embree, differ, ties, edges, ends, other;
    size_t width_differ; /* Embree 4/8/16-wide answers that differ from rtcIntersect1's */
} Agreement;

/* Camera rays: sheaf's reference against Embree's rtcIntersect1. */
static void agree_primary(const Scene *s, const sheaf_ray *rays, const sheaf_hit *ref,
                          const uint32_t *eprim, const float *et, size_t n, Agreement *a)
{
    for (size_t k = 0; k < n; k++) {
        uint32_t A = ref[k].prim, B = eprim[k];
        a->hits_sheaf += A != SHEAF_INVALID_ID;
        a->hits_embree += B != SHEAF_INVALID_ID;
        if (A == B)
            continue;
        a->differ++;
        Hit64 ha = {0, 0, 0, 0}, hb = {0, 0, 0, 0};
        if (A != SHEAF_INVALID_ID) ha = isect64(s, &rays[k], A);
        if (B != SHEAF_INVALID_ID) hb = isect64(s, &rays[k], B);
        if (A != SHEAF_INVALID_ID && B != SHEAF_INVALID_ID && ha.ok && hb.ok) {
            double m = fabs(ha.t) > fabs(hb.t) ? fabs(ha.t) : fabs(hb.t);
            if (fabs(ha.t - hb.t) <= TIE_REL * m) {
                a->ties++;
                continue;
            }
        }
        if ((A != SHEAF_INVALID_ID && grazes(s, &rays[k], A, ha)) ||
            (B != SHEAF_INVALID_ID && grazes(s, &rays[k], B, hb))) {
            a->edges++;
            continue;
        }
        a->other++;
        if (g_explain)
            fprintf(stderr,
                    "  unexplained camera ray %zu: org (%a %a %a) dir (%a %a %a): sheaf %u t %.9g "
                    "(f64 t %.12g, bary %.3g %.3g %.3g, edge distance %.3g), Embree %u t %.9g (f64 t %.12g, bary %.3g %.3g %.3g, edge distance %.3g)\n",
                    k, rays[k].org[0], rays[k].org[1], rays[k].org[2], rays[k].dir[0], rays[k].dir[1],
                    rays[k].dir[2], A, ref[k].t, ha.t, ha.u, ha.v, 1 - ha.u - ha.v,
                    A != SHEAF_INVALID_ID ? edge_distance_rel(s, &rays[k], A) : NAN, B, et[k], hb.t, hb.u, hb.v,
                    1 - hb.u - hb.v, B != SHEAF_INVALID_ID ? edge_distance_rel(s, &rays[k], B) : NAN);
    }
}

/* Shadow rays: sheaf's occlusion against Embree's; each disagreement's
 * occluders (sheaf's BVH single nearest hit, Embree's rtcIntersect1) are
 * checked for an edge or the ray's end. */
static void agree_shadow(const Scene *s, const sheaf_context *ctx, RTCScene scene,
                         const sheaf_ray *rays, const uint8_t *ref, const uint8_t *eocc,
                         size_t n, Agreement *a)
{
    sheaf_trace_params p;
    sheaf_trace_params_default(&p);
    p.method = SHEAF_METHOD_BVH_SINGLE;
    for (size_t k = 0; k < n; k++) {
        a->hits_sheaf += ref[k];
        a->hits_embree += eocc[k];
        if (ref[k] == eocc[k])
            continue;
        a->differ++;
        sheaf_hit h;
        check_sheaf(ctx, sheaf_context_trace_with(ctx, &p, &rays[k], &h, 1), "trace");
        uint32_t occl[2] = {h.prim, embree_nearest(scene, &rays[k])};
        int edge = 0, end = 0;
        for (int i = 0; i < 2; i++) {
            if (occl[i] == SHEAF_INVALID_ID)
                continue;
            Hit64 x = isect64(s, &rays[k], occl[i]);
            if (grazes(s, &rays[k], occl[i], x))
                edge = 1;
            if (x.ok && (fabs(1.0 - x.t) <= END_REL || fabs(x.t) <= END_REL))
                end = 1;
        }
        if (end)
            a->ends++;
        else if (edge)
            a->edges++;
        else {
            a->other++;
            if (g_explain)
                fprintf(stderr, "  unexplained shadow ray %zu: sheaf %s (occluder %u), Embree %s (occluder %u)\n", k,
                        ref[k] ? "occluded" : "lit", occl[0], eocc[k] ? "occluded" : "lit", occl[1]);
        }
    }
}

/* ---- sheaf configurations ---------------------------------------------------------- */

/* S_BVH: the BVH's binned SAH (MEDIUM) build, whose methods are all timed.
 * S_BVH_LOW: its fast (Morton, LOW) build, S_BVH_HIGH: its HIGH build
 * (spatial splits into the reserve --bvh-reserve sizes), each traced with
 * the methods that were fastest on the MEDIUM tree. */
enum { S_GRID, S_BVH, S_BVH_LOW, S_BVH_HIGH, S_KD, NSTRUCT };
static const char *STRUCT_NAME[NSTRUCT + 1] = {"grid", "BVH MEDIUM", "BVH LOW", "BVH HIGH", "kd",
                                               "perspective/light grids"};
/* The dynamic frame's rows: the structures, then the perspective/light grids' deferred frame. */
enum { F_PGRID = NSTRUCT, NFRAME };
/* The dynamic frame leaves the HIGH build out (a build for static scenes;
 * Embree's frame is LOW + DYNAMIC). */
static int in_frame(int st) { return st != S_BVH_HIGH; }

/* What the caller's threads join. */
enum { J_BVH_LOW, J_REFIT, J_GRID, J_DEFERRED, J_KD, J_BVH_MEDIUM, J_BVH_HIGH };
static const char *JOIN_NAME[] = {"BVH LOW build", "refit",         "grid build",   "deferred frame",
                                  "kd build",      "BVH MEDIUM build", "BVH HIGH build"};

/* One thread of a joined call (sheaf_context_build_bvh_joined,
 * sheaf_context_refit_bvh_joined, sheaf_context_build_grid_joined). */
typedef struct {
    sheaf_context *ctx;
    sheaf_bvh_params p;
    int what;
    /* J_DEFERRED: the job and the framebuffer (read by the leader only). */
    const sheaf_deferred_job *job;
    uint8_t *rgba;
    size_t rgba_len;
    uint32_t index, count;
    sheaf_status status;
} JoinArg;

static void *join_thread(void *arg)
{
    JoinArg *a = arg;
    a->status = a->what == J_REFIT ? sheaf_context_refit_bvh_joined(a->ctx, NULL, NULL, a->index, a->count)
              : a->what == J_GRID  ? sheaf_context_build_grid_joined(a->ctx, NULL, a->index, a->count)
              : a->what == J_KD    ? sheaf_context_build_kd_joined(a->ctx, NULL, a->index, a->count)
              : a->what == J_DEFERRED
                  ? sheaf_context_render_deferred_joined(a->ctx, a->job, a->rgba, 4 * (size_t)a->job->frame.width,
                                                         a->rgba_len, a->index, a->count)
                  : sheaf_context_build_bvh_joined(a->ctx, &a->p, a->index, a->count);
    return NULL;
}

/* The LOW build, a refit, the grid build or a deferred frame (`job` into
 * `rgba`, rows of the frame's width) joined by T threads (this one leads;
 * the others are started here, as run_job starts its tracing threads). */
static sheaf_status sheaf_joined_call(sheaf_context *ctx, int T, int what, const sheaf_deferred_job *job, uint8_t *rgba,
                                      size_t rgba_len)
{
    pthread_t th[MAX_THREADS];
    JoinArg a[MAX_THREADS];
    for (int i = 0; i < T; i++) {
        a[i].ctx = ctx;
        sheaf_bvh_params_default(&a[i].p);
        a[i].p.quality = what == J_BVH_MEDIUM ? SHEAF_BUILD_QUALITY_MEDIUM
                       : what == J_BVH_HIGH   ? SHEAF_BUILD_QUALITY_HIGH
                                              : SHEAF_BUILD_QUALITY_LOW;
        a[i].p.width = 4; /* as sheaf_build */
        a[i].what = what;
        a[i].job = job;
        a[i].rgba = rgba;
        a[i].rgba_len = rgba_len;
        a[i].index = (uint32_t)i;
        a[i].count = (uint32_t)T;
    }
    for (int i = 1; i < T; i++)
        if (pthread_create(&th[i], NULL, join_thread, &a[i]) != 0)
            die("pthread_create failed");
    join_thread(&a[0]);
    for (int i = 1; i < T; i++) pthread_join(th[i], NULL);
    for (int i = 1; i < T; i++)
        if (a[i].status != a[0].status)
            die("joined %s: thread %d returned %s, the leader %s", JOIN_NAME[what], i,
                sheaf_status_string(a[i].status), sheaf_status_string(a[0].status));
    return a[0].status;
}

static sheaf_status sheaf_joined(sheaf_context *ctx, int T, int what) { return sheaf_joined_call(ctx, T, what, NULL, NULL, 0); }
static sheaf_status sheaf_build_low_joined(sheaf_context *ctx, int T) { return sheaf_joined(ctx, T, J_BVH_LOW); }
static sheaf_status sheaf_refit_joined(sheaf_context *ctx, int T) { return sheaf_joined(ctx, T, J_REFIT); }
static sheaf_status sheaf_grid_joined(sheaf_context *ctx, int T) { return sheaf_joined(ctx, T, J_GRID); }
static sheaf_status sheaf_kd_joined(sheaf_context *ctx, int T) { return sheaf_joined(ctx, T, J_KD); }

/* Build structure st into the context (the BVH at MEDIUM, LOW or HIGH), the
 * BVH with `width` children per node for single rays (4: also the wide tree). */
static sheaf_status sheaf_build_width(sheaf_context *ctx, int st, uint32_t width)
{
    sheaf_bvh_params bp;
    sheaf_bvh_params_default(&bp);
    bp.quality = st == S_BVH_LOW    ? SHEAF_BUILD_QUALITY_LOW
               : st == S_BVH_HIGH   ? SHEAF_BUILD_QUALITY_HIGH
                                    : SHEAF_BUILD_QUALITY_MEDIUM;
    bp.width = width;
    return st == S_GRID ? sheaf_context_build_grid(ctx, NULL)
         : st == S_KD   ? sheaf_context_build_kd(ctx, NULL)
                        : sheaf_context_build_bvh(ctx, &bp);
}

/* Every BVH with its wide tree: the method tables' bvh-wide, bvh-wide-ranged
 * and bvh-frustum walk it, and the LOW tree is traced per frame by the SAH
 * tree's fastest methods (bvh-frustum: without the wide tree it would fall
 * back to binary Ranged packets); the collapse is timed in the rebuild. */
static sheaf_status sheaf_build(sheaf_context *ctx, int st)
{
    return sheaf_build_width(ctx, st, 4);
}

typedef struct {
    const char *name;
    int structure;
    sheaf_method method;
    uint32_t packet;
    sheaf_entry_search entry;
    int packet_method; /* SIMD rays and n x n packets (else a single-ray method) */
    int occ_via_trace; /* shadows: nearest hit through trace_with (16x16), not occluded */
} Cfg;

static const Cfg PRIMARY_CFGS[] = {
    {"grid-dda", S_GRID, SHEAF_METHOD_GRID_DDA, 8, SHEAF_ENTRY_SEARCH_NONE, 0, 0},
    {"grid-cgt 4x4", S_GRID, SHEAF_METHOD_GRID_CGT, 4, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"grid-cgt 8x8", S_GRID, SHEAF_METHOD_GRID_CGT, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"grid-cgt 16x16", S_GRID, SHEAF_METHOD_GRID_CGT, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-single", S_BVH, SHEAF_METHOD_BVH_SINGLE, 8, SHEAF_ENTRY_SEARCH_NONE, 0, 0},
    {"bvh-wide", S_BVH, SHEAF_METHOD_BVH_WIDE, 8, SHEAF_ENTRY_SEARCH_NONE, 0, 0},
    {"bvh-simd", S_BVH, SHEAF_METHOD_BVH_SIMD, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-masked 8x8", S_BVH, SHEAF_METHOD_BVH_MASKED, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-masked 16x16", S_BVH, SHEAF_METHOD_BVH_MASKED, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-ranged 8x8", S_BVH, SHEAF_METHOD_BVH_RANGED, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-wide-ranged 8x8", S_BVH, SHEAF_METHOD_BVH_WIDE_RANGED, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-ranged 16x16", S_BVH, SHEAF_METHOD_BVH_RANGED, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-frustum 4x4", S_BVH, SHEAF_METHOD_BVH_FRUSTUM, 4, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-frustum 8x8", S_BVH, SHEAF_METHOD_BVH_FRUSTUM, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-frustum 16x16", S_BVH, SHEAF_METHOD_BVH_FRUSTUM, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-frustum 32x32", S_BVH, SHEAF_METHOD_BVH_FRUSTUM, 32, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-partition 8x8", S_BVH, SHEAF_METHOD_BVH_PARTITION, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-partition 16x16", S_BVH, SHEAF_METHOD_BVH_PARTITION, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"kd-single", S_KD, SHEAF_METHOD_KD_SINGLE, 8, SHEAF_ENTRY_SEARCH_NONE, 0, 0},
    {"kd-simd", S_KD, SHEAF_METHOD_KD_SIMD, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"kd-packet 8x8", S_KD, SHEAF_METHOD_KD_PACKET, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"kd-packet 16x16", S_KD, SHEAF_METHOD_KD_PACKET, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"kd-packet 16x16 aepsa", S_KD, SHEAF_METHOD_KD_PACKET, 16, SHEAF_ENTRY_SEARCH_AEPSA, 1, 0},
};
#define N_PRIMARY_CFGS (sizeof PRIMARY_CFGS / sizeof PRIMARY_CFGS[0])

static const Cfg SHADOW_CFGS[] = {
    {"grid-dda", S_GRID, SHEAF_METHOD_GRID_DDA, 8, SHEAF_ENTRY_SEARCH_NONE, 0, 0},
    {"grid-cgt 8x8", S_GRID, SHEAF_METHOD_GRID_CGT, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"grid-cgt 16x16 nearest", S_GRID, SHEAF_METHOD_GRID_CGT, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 1},
    {"bvh-single", S_BVH, SHEAF_METHOD_BVH_SINGLE, 8, SHEAF_ENTRY_SEARCH_NONE, 0, 0},
    {"bvh-wide", S_BVH, SHEAF_METHOD_BVH_WIDE, 8, SHEAF_ENTRY_SEARCH_NONE, 0, 0},
    {"bvh-simd", S_BVH, SHEAF_METHOD_BVH_SIMD, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-masked 8x8", S_BVH, SHEAF_METHOD_BVH_MASKED, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-ranged 8x8", S_BVH, SHEAF_METHOD_BVH_RANGED, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-wide-ranged 8x8", S_BVH, SHEAF_METHOD_BVH_WIDE_RANGED, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-partition 8x8", S_BVH, SHEAF_METHOD_BVH_PARTITION, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-frustum 4x4", S_BVH, SHEAF_METHOD_BVH_FRUSTUM, 4, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-frustum 8x8", S_BVH, SHEAF_METHOD_BVH_FRUSTUM, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-frustum 16x16", S_BVH, SHEAF_METHOD_BVH_FRUSTUM, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-frustum 32x32", S_BVH, SHEAF_METHOD_BVH_FRUSTUM, 32, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"bvh-ranged 16x16 nearest", S_BVH, SHEAF_METHOD_BVH_RANGED, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 1},
    {"bvh-partition 16x16 nearest", S_BVH, SHEAF_METHOD_BVH_PARTITION, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 1},
    {"kd-single", S_KD, SHEAF_METHOD_KD_SINGLE, 8, SHEAF_ENTRY_SEARCH_NONE, 0, 0},
    {"kd-simd", S_KD, SHEAF_METHOD_KD_SIMD, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"kd-packet 8x8", S_KD, SHEAF_METHOD_KD_PACKET, 8, SHEAF_ENTRY_SEARCH_NONE, 1, 0},
    {"kd-packet 16x16 nearest", S_KD, SHEAF_METHOD_KD_PACKET, 16, SHEAF_ENTRY_SEARCH_NONE, 1, 1},
};
#define N_SHADOW_CFGS (sizeof SHADOW_CFGS / sizeof SHADOW_CFGS[0])

static sheaf_trace_params cfg_params(const Cfg *c, sheaf_ray_kind kind)
{
    sheaf_trace_params p;
    sheaf_trace_params_default(&p);
    p.method = c->method;
    p.packet = c->packet;
    p.culling = true;
    p.macrocells = true;
    p.ray_kind = kind;
    p.entry = c->entry;
    return p;
}

/* ---- options ----------------------------------------------------------------------- */

typedef struct {
    int reps;
    int threads[4];
    int nthreads;
    uint32_t width, height; /* 0: the file's */
    int check;
    int check_rays;
    int compact_shadows;
    const char *summary;
    const char *profile; /* --profile NAME: time one configuration only (for perf) */
    int profile_shadow;  /* --profile-shadow: its shadow rays, not camera rays */
    const char *ab;      /* --ab A,B,..: configurations timed in interleaved rounds */
    const char *twolevel[3]; /* --twolevel ENV ANIM OBJ: the two-level scene's files */
    int frames;              /* --frames: the two-level scene's frames (default 24) */
    const char *ppm;         /* --ppm FILE: the two-level scene's frame 0 as sheaf sees it */
    int filter;              /* --filter: the two-level scene's ANIM cut out by any-hit filters */
    int updates;             /* --updates: the LOW build and the refit against Embree's, interleaved */
    int bvh_reserve;         /* --bvh-reserve: the HIGH build's reference reserve, percent of the triangles */
} Options;

/* sheaf_limits.max_bvh_refs for `nt` triangles: nt and the spatial-split
 * reserve, --bvh-reserve percent of nt (0: nt, no reserve). */
static uint32_t bvh_refs(const Options *o, uint32_t nt)
{
    uint64_t refs = (uint64_t)nt + (uint64_t)nt * (uint64_t)o->bvh_reserve / 100u;
    if (refs > UINT32_MAX)
        die("--bvh-reserve %d: %llu BVH references for %u triangles do not fit sheaf_limits.max_bvh_refs",
            o->bvh_reserve, (unsigned long long)refs, nt);
    return (uint32_t)refs;
}

/* ---- per-scene run --------------------------------------------------------------------- */

typedef struct {
    double mrays;     /* median */
    size_t mismatch;  /* rays whose answer differs from the reference */
} Speed;

static double mrays(size_t n, double s) { return s > 0 ? (double)n / s * 1e-6 : 0.0; }

static double time_job(Job *j, int threads, int reps)
{
    double t[MAX_REPS];
    for (int r = 0; r < reps; r++) t[r] = run_job(j, threads);
    return median(t, reps);
}

static FILE *g_summary;

static void summary(const char *scene, const char *key, double value)
{
    if (g_summary)
        fprintf(g_summary, "%s %s=%.17g\n", scene, key, value);
}

/* A short scene name for tables and summary keys. */
static void short_name(const char *label, char *out, size_t n)
{
    const char *b = strrchr(label, '/');
    b = b ? b + 1 : label;
    if (strncmp(b, "builtin:", 8) == 0)
        b += 8;
    snprintf(out, n, "%s", b);
    char *dot = strrchr(out, '.');
    if (dot && strcmp(dot, ".obj") == 0)
        *dot = 0;
}

static int g_fail; /* --check failures */

/* One line of the closing summary table per scene. */
typedef struct {
    char name[64];
    uint32_t triangles;
    double ratio_p[4], ratio_s[4], ratio_f[4]; /* sheaf / Embree per thread count */
    double ratio_b[4], ratio_r[4]; /* sheaf BVH LOW build / Embree LOW rebuild; BVH refit / Embree refit */
    const char *frame_struct[4];
    size_t p_differ, p_ties, p_edges, s_differ, s_edges, s_ends, unexplained; /* MEDIUM; unexplained: all qualities */
} SceneResult;
static SceneResult g_results[64];
static int g_nresults;

static const int WIDTHS[4] = {1, 4, 8, 16};

/* Everything one scene's run measures ([4]: per thread count, [3]: per Embree quality). */
typedef struct {
    const Options *o;
    Scene s;
    char name[512];
    uint32_t W, H;
    size_t N; /* camera rays */
    int reps;
    double load0, load1;
    sheaf_frame frame;
    sheaf_ray *rays;  /* camera rays in packet order */
    uint32_t *pix;    /* pixel index of each camera ray */
    sheaf_context *ctx;
    sheaf_limits lim;      /* ctx's limits */
    sheaf_context *hctx;   /* --ab / --profile: a BVH-only context holding the HIGH tree (high_context) */
    double build_ms[NSTRUCT];
    sheaf_stats bvh_stats[NSTRUCT]; /* S_BVH, S_BVH_HIGH: the tree of the last timed build */
    sheaf_hit *ref, *hits; /* reference hits; scratch */
    Job job;               /* sheaf camera-ray job template */
    size_t nhits, NS, NSL, nocc, internal; /* hits, shadow rays, shadow slots, occluded, self-check mismatches */
    sheaf_ray *srays;
    size_t *slot_of;       /* shadow slot of each camera ray, or SIZE_MAX */
    uint8_t *sref, *socc, *socc1; /* reference occlusion; scratch; rtcOccluded1's */
    long ray_check;
    Speed pspeed[N_PRIMARY_CFGS], sspeed[N_SHADOW_CFGS];
    int pbest[NSTRUCT], sbest[NSTRUCT];
    double pbest_mr[NSTRUCT][4], sbest_mr[NSTRUCT][4];
    double e_first[4][3], e_rebuild[4][3], e_prim[4][3][4], e_shad[4][3][4]; /* [threads][quality][width] */
    double refit_ms[4];              /* [threads]: sheaf_context_refit_bvh_joined, the same vertices */
    double low_ms[4];                /* [threads]: the BVH LOW build joined by that many threads */
    double sah_ms[2][4];             /* [MEDIUM, HIGH][threads]: the SAH builds joined likewise */
    double grid_ms[4];               /* [threads]: the grid build joined by that many threads */
    double kd_ms[4];                 /* [threads]: the kd build joined by that many threads */
    double anim[4][4], anim_parts[4][4][3]; /* [ANIM mode][threads]: mean ms per frame; update, camera, shadows */
    size_t anim_differ;              /* frames whose sheaf refit-tree hits differ from the rebuilt tree's */
    double e_refit_first[4], e_refit[4]; /* [threads]: Embree LOW + geometry REFIT */
    Agreement ap[3], as[3];
    uint32_t *eprim, *eprim1;
    float *et;
    double frame_e[4], frame_e_parts[4][3];
    /* Each library's fastest interface (fastest_frames): [sheaf, Embree][threads] */
    double fast[2][4], fast_parts[2][4][3], fast_ratio[4];
    int frame_e_pw[4], frame_e_sw[4];
    double frame_s[NFRAME][4], frame_s_parts[NFRAME][4][3];
    double sheaf_best_p[4], sheaf_best_s[4], emb_best_p[4], emb_best_s[4], best_frame[4];
    int best_st[4];
} Bench;

/* The frame of the scene's view (camera, light, W x H, shadows on) and its
 * camera rays in packet order (*rays; *pix: each ray's pixel index). */
static void camera_rays(const Scene *s, uint32_t W, uint32_t H, sheaf_frame *frame, sheaf_ray **rays, uint32_t **pix)
{
    size_t N = (size_t)W * H;
    memset(frame, 0, sizeof *frame);
    memcpy(frame->camera.eye, s->eye, sizeof s->eye);
    memcpy(frame->camera.look_at, s->look_at, sizeof s->look_at);
    memcpy(frame->camera.up, s->up, sizeof s->up);
    frame->camera.fov_y_deg = s->fov;
    memcpy(frame->light.position, s->light, sizeof s->light);
    frame->light.color[0] = frame->light.color[1] = frame->light.color[2] = 1.0f;
    frame->light.spot_direction[2] = -1.0f;
    sheaf_shading_default(&frame->shading);
    frame->shading.shadows = true;
    frame->width = W;
    frame->height = H;
    sheaf_ray *r = *rays = xmalloc(N * sizeof **rays);
    uint32_t *p = *pix = xmalloc(N * sizeof **pix);
    size_t k = 0;
    for (uint32_t ty = 0; ty < H; ty += 32)
        for (uint32_t tx = 0; tx < W; tx += 32)
            for (uint32_t q = 0; q < 256; q++) {
                uint32_t qx, qy;
                demorton(q, &qx, &qy);
                for (uint32_t l = 0; l < 4; l++) {
                    uint32_t x = tx + 2 * qx + (l & 1), y = ty + 2 * qy + (l >> 1);
                    check_sheaf(NULL, sheaf_frame_camera_ray(frame, x, y, &r[k]), "camera ray");
                    p[k++] = y * W + x;
                }
            }
}

/* Read the scene, make the camera rays in packet order, create the sheaf context. */
static void setup_scene(Bench *b, const char *path)
{
    read_scene(path, &b->s);
    short_name(b->s.label, b->name, sizeof b->name);
    b->W = b->o->width ? b->o->width : b->s.width;
    b->H = b->o->height ? b->o->height : b->s.height;
    if (b->W % 32 || b->H % 32 || b->W == 0 || b->H == 0)
        die("%s: image %ux%u: width and height must be multiples of 32 (32x32 tiles)", b->name, b->W, b->H);
    b->N = (size_t)b->W * b->H;
    b->reps = b->o->reps;
    b->load0 = load_average();
    progress("== %s: %u triangles, %u vertices, %ux%u, %s\n", b->name, b->s.nt, b->s.nv, b->W, b->H, b->s.view);

    camera_rays(&b->s, b->W, b->H, &b->frame, &b->rays, &b->pix);

    /* The sheaf context: grid, BVH, kd-tree (and the deferred frame's pools). */
    sheaf_limits lim;
    sheaf_limits_default(b->s.nt, &lim);
    lim.max_vertices = b->s.nv;
    lim.max_image_width = b->W;
    lim.max_image_height = b->H;
    lim.max_threads = MAX_THREADS;
    lim.structures = SHEAF_STRUCTURE_GRID | SHEAF_STRUCTURE_BVH | SHEAF_STRUCTURE_KD |
                     (b->o->check_rays ? SHEAF_STRUCTURE_PGRID : 0);
    /* The HIGH build's spatial splits go into this reserve. */
    lim.max_bvh_refs = bvh_refs(b->o, b->s.nt);
    b->ctx = NULL;
    for (int attempt = 0;; attempt++) {
        size_t bytes = 0;
        check_sheaf(NULL, sheaf_required_bytes(&lim, &bytes), "limits");
        check_sheaf(NULL, sheaf_context_create(&lim, &b->ctx), "sheaf_context_create");
        check_sheaf(b->ctx, sheaf_context_set_geometry(b->ctx, b->s.verts, 12, b->s.nv, b->s.idx, b->s.nt), "set_geometry");
        sheaf_status st = sheaf_context_build_grid(b->ctx, NULL);
        if (st == SHEAF_STATUS_OK)
            break;
        if ((st == SHEAF_STATUS_CAPACITY_GRID_CELLS || st == SHEAF_STATUS_CAPACITY_GRID_REFS) && attempt < 4) {
            /* Grow the grid pools as `sheaf render` does, and start again. */
            if (lim.max_grid_cells == 0) lim.max_grid_cells = 8 * b->s.nt + 64;
            if (lim.max_grid_refs == 0) lim.max_grid_refs = 16 * b->s.nt + 1024;
            if (st == SHEAF_STATUS_CAPACITY_GRID_CELLS) lim.max_grid_cells *= 2;
            else lim.max_grid_refs *= 2;
            sheaf_context_destroy(b->ctx);
            b->ctx = NULL;
            continue;
        }
        check_sheaf(b->ctx, st, "build_grid");
    }
    b->lim = lim;
}

/* The context of the HIGH tree for --ab and --profile (made on first use):
 * ctx's limits with only the BVH's pools (the same reference reserve), the
 * scene set, the BVH built at HIGH with its wide tree. Those modes trace
 * HIGH-tree configurations beside MEDIUM (or LOW) ones, so the two trees
 * live in two contexts; the tables rebuild ctx instead (time_sheaf_methods). */
static sheaf_context *high_context(Bench *b)
{
    if (!b->hctx) {
        sheaf_limits lim = b->lim;
        lim.structures = SHEAF_STRUCTURE_BVH;
        check_sheaf(NULL, sheaf_context_create(&lim, &b->hctx), "sheaf_context_create (HIGH tree)");
        check_sheaf(b->hctx, sheaf_context_set_geometry(b->hctx, b->s.verts, 12, b->s.nv, b->s.idx, b->s.nt),
                    "set_geometry (HIGH tree)");
        check_sheaf(b->hctx, sheaf_build(b->hctx, S_BVH_HIGH), "build (HIGH tree)");
    }
    return b->hctx;
}

/* sheaf's builds, median of reps, on the calling thread. */
static void time_sheaf_builds(Bench *b)
{
    /* Builds, median of reps (sheaf builds on the calling thread). */
    for (int st = 0; st < NSTRUCT; st++) {
        double t[MAX_REPS];
        /* --profile: each structure once, the kd-tree only when profiled
         * (its build would dominate the profile). */
        int reps = b->o->profile ? 1 : b->reps;
        if (b->o->profile && st == S_KD && strncmp(b->o->profile, "kd-", 3))
            continue;
        /* --profile traces the HIGH tree in a context of its own (high_context). */
        if (b->o->profile && st == S_BVH_HIGH)
            continue;
        for (int r = 0; r < reps; r++) {
            double t0 = now_s();
            sheaf_status e = sheaf_build(b->ctx, st);
            t[r] = now_s() - t0;
            check_sheaf(b->ctx, e, "build");
        }
        b->build_ms[st] = 1e3 * median(t, reps);
        if (st == S_BVH || st == S_BVH_HIGH) {
            const sheaf_stats *bs = &b->bvh_stats[st];
            check_sheaf(b->ctx, sheaf_context_stats(b->ctx, &b->bvh_stats[st]), "stats");
            progress("  sheaf %s build %.1f ms (%u nodes, %u leaves, depth %u, SAH cost %.2f)\n", STRUCT_NAME[st],
                     b->build_ms[st], bs->bvh_nodes, bs->bvh_leaves, bs->bvh_depth, bs->bvh_sah_cost);
        } else
            progress("  sheaf %s build %.1f ms\n", STRUCT_NAME[st], b->build_ms[st]);
    }
    /* The LOW build, the grid, the kd-tree and the MEDIUM and HIGH builds
     * joined by each thread count (1: the calling thread; every one is the
     * same for any count). */
    for (int g = 0; g < 5; g++)
        for (int ti = 0; ti < b->o->nthreads; ti++) {
            int T = b->o->threads[ti];
            double t[MAX_REPS];
            int reps = b->o->profile ? 1 : b->reps;
            for (int r = 0; r < reps; r++) {
                double t0 = now_s();
                sheaf_status e = g == 4 ? sheaf_joined(b->ctx, T, J_BVH_HIGH)
                               : g == 3 ? sheaf_joined(b->ctx, T, J_BVH_MEDIUM)
                               : g == 2 ? sheaf_kd_joined(b->ctx, T)
                               : g      ? sheaf_grid_joined(b->ctx, T)
                                        : sheaf_build_low_joined(b->ctx, T);
                t[r] = now_s() - t0;
                check_sheaf(b->ctx, e, "joined build");
            }
            double *ms = g >= 3 ? b->sah_ms[g - 3] : g == 2 ? b->kd_ms : g ? b->grid_ms : b->low_ms;
            ms[ti] = 1e3 * median(t, reps);
            progress("  sheaf %s joined by %d threads %.1f ms\n",
                     g == 4   ? "BVH HIGH build"
                     : g == 3 ? "BVH MEDIUM build"
                     : g == 2 ? "kd build"
                     : g      ? "grid"
                              : "BVH LOW build",
                     T, ms[ti]);
        }
    /* The reference, the checks and the method tables use the SAH tree. */
    check_sheaf(b->ctx, sheaf_build(b->ctx, S_BVH), "build");
    /* The BVH refit to the same vertices (its cost does not depend on how
     * far they moved), joined by each thread count, median of reps. */
    if (!b->o->profile) {
        /* The refit of the binary tree and its wide tree (width 4), which
         * the fastest packets (bvh-frustum) walk; then the SAH tree again. */
        check_sheaf(b->ctx, sheaf_build_width(b->ctx, S_BVH, 4), "build");
        for (int ti = 0; ti < b->o->nthreads; ti++) {
            int T = b->o->threads[ti];
            double t[MAX_REPS];
            for (int r = 0; r < b->reps; r++) {
                double t0 = now_s();
                sheaf_status e = sheaf_refit_joined(b->ctx, T);
                t[r] = now_s() - t0;
                check_sheaf(b->ctx, e, "refit");
            }
            b->refit_ms[ti] = 1e3 * median(t, b->reps);
            progress("  sheaf BVH refit joined by %d threads %.1f ms\n", T, b->refit_ms[ti]);
        }
        check_sheaf(b->ctx, sheaf_build(b->ctx, S_BVH), "build");
    }
}

/* The reference (BVH single ray) camera hits, the shadow rays and their occlusion. */
static void make_reference(Bench *b)
{
    /* Reference: BVH single ray. */
    b->ref = xmalloc(b->N * sizeof *b->ref);
    b->hits = xmalloc(b->N * sizeof *b->hits);
    memset(&b->job, 0, sizeof b->job);
    b->job.lib = LIB_SHEAF;
    b->job.kind = K_TRACE;
    b->job.ctx = b->ctx;
    b->job.s = &b->s;
    b->job.rays = b->rays;
    b->job.n = b->N;
    b->job.hits = b->ref;
    b->job.params = cfg_params(&PRIMARY_CFGS[4], SHEAF_RAY_KIND_PRIMARY);
    run_job(&b->job, 1);
    b->nhits = 0;
    for (size_t k = 0; k < b->N; k++) b->nhits += b->ref[k].prim != SHEAF_INVALID_ID;

    /* Shadow rays of the reference hits: one slot per camera ray in the
     * same packet order (inactive slots for misses and unlit surfaces), as
     * the renderer's shadow packets; or packed (--compact-shadows). */
    b->srays = xmalloc((b->N + 1) * sizeof *b->srays);
    b->slot_of = xmalloc((b->N + 1) * sizeof *b->slot_of);
    b->NS = b->NSL = 0; /* shadow rays, slots */
    for (size_t k = 0; k < b->N; k++) {
        sheaf_ray r;
        int lit = b->ref[k].prim != SHEAF_INVALID_ID && shadow_ray(&b->s, &b->rays[k], b->ref[k].t, b->ref[k].prim, &r);
        b->NS += lit;
        b->slot_of[k] = lit ? b->NSL : SIZE_MAX;
        if (lit)
            b->srays[b->NSL++] = r;
        else if (!b->o->compact_shadows)
            inactive_ray(&b->s, &b->srays[b->NSL++]);
    }
    b->sref = xmalloc(b->NSL + 1);
    b->socc = xmalloc(b->NSL + 1);
    b->socc1 = xmalloc(b->NSL + 1);
    {
        Job sj = b->job;
        sj.kind = K_OCCLUDED;
        sj.occ_method = SHEAF_METHOD_BVH_SINGLE;
        sj.occ_via_trace = 0;
        sj.rays = b->srays;
        sj.n = b->NSL;
        sj.occ = b->sref;
        run_job(&sj, 1);
    }
    b->nocc = 0;
    for (size_t k = 0; k < b->NSL; k++) b->nocc += b->sref[k];
    progress("  %zu camera rays, %zu hits, %zu shadow rays, %zu occluded\n", b->N, b->nhits, b->NS, b->nocc);
}

/* The rays against a sheaf deferred frame, bit for bit. */
static void check_rays(Bench *b)
{
    /* Are these the rays sheaf's renderer shoots? A deferred frame, bit for bit. */
    b->ray_check = -1;
    if (b->o->check_rays) {
        sheaf_deferred_job dj;
        memset(&dj, 0, sizeof dj);
        dj.frame = b->frame;
        sheaf_trace_params pp = cfg_params(&PRIMARY_CFGS[9], SHEAF_RAY_KIND_PRIMARY);
        sheaf_trace_params sp = cfg_params(&PRIMARY_CFGS[9], SHEAF_RAY_KIND_SHADOW);
        dj.primary = &pp;
        dj.shadow = &sp;
        uint8_t *rgba = xmalloc(4 * b->N);
        check_sheaf(b->ctx, sheaf_context_render_deferred(b->ctx, &dj, rgba, 4 * (size_t)b->W, 4 * b->N), "render_deferred");
        free(rgba);
        b->ray_check = 0;
        for (size_t k = 0; k < b->N; k++) {
            uint32_t x = b->pix[k] % b->W, y = b->pix[k] / b->W;
            sheaf_hit h;
            uint8_t bits;
            sheaf_ray dr;
            bool has = false;
            check_sheaf(b->ctx, sheaf_context_deferred_pixel(b->ctx, x, y, &h, &bits), "deferred_pixel");
            check_sheaf(b->ctx, sheaf_context_deferred_shadow_ray(b->ctx, x, y, &b->frame.light, &dr, &has), "deferred_shadow_ray");
            size_t si = b->slot_of[k];
            int mine = si != SIZE_MAX;
            if (h.prim != b->ref[k].prim || memcmp(&h.t, &b->ref[k].t, 4) != 0 || (int)has != mine ||
                (mine && (memcmp(&dr, &b->srays[si], sizeof dr) != 0 || (bits & 1) != b->sref[si])))
                b->ray_check++;
        }
        progress("  rays against sheaf's deferred frame: %ld of %zu pixels differ\n", b->ray_check, b->N);
    }
}

/* Structure st's fastest camera and shadow methods on thread count ti
 * (the built structure in the context): Mrays/s, every answer checked
 * against the reference bit for bit. */
static void time_best(Bench *b, int st, int ti)
{
    int T = b->o->threads[ti];
    Job j = b->job;
    j.hits = b->hits;
    j.params = cfg_params(&PRIMARY_CFGS[b->pbest[st]], SHEAF_RAY_KIND_PRIMARY);
    b->pbest_mr[st][ti] = mrays(b->N, time_job(&j, T, b->reps));
    for (size_t k = 0; k < b->N; k++)
        b->internal += b->hits[k].prim != b->ref[k].prim || memcmp(&b->hits[k].t, &b->ref[k].t, 4) != 0;
    const Cfg *sc = &SHADOW_CFGS[b->sbest[st]];
    j.kind = sc->occ_via_trace ? K_TRACE_OCC : K_OCCLUDED;
    j.occ_method = sc->method;
    j.occ_via_trace = sc->occ_via_trace;
    j.params = cfg_params(sc, SHEAF_RAY_KIND_SHADOW);
    j.rays = b->srays;
    j.n = b->NSL;
    j.occ = b->socc;
    b->sbest_mr[st][ti] = mrays(b->NS, time_job(&j, T, b->reps));
    for (size_t k = 0; k < b->NSL; k++) b->internal += b->socc[k] != b->sref[k];
}

/* Every sheaf method on 1 thread, the fastest per structure on every thread count. */
static void time_sheaf_methods(Bench *b)
{
    /* Every sheaf traversal on one thread; the reference's answers must come back. */
    for (size_t c = 0; c < N_PRIMARY_CFGS; c++) {
        Job j = b->job;
        j.hits = b->hits;
        j.params = cfg_params(&PRIMARY_CFGS[c], SHEAF_RAY_KIND_PRIMARY);
        double t = time_job(&j, 1, b->reps);
        size_t mm = 0;
        for (size_t k = 0; k < b->N; k++)
            mm += b->hits[k].prim != b->ref[k].prim || memcmp(&b->hits[k].t, &b->ref[k].t, 4) != 0;
        b->pspeed[c].mrays = mrays(b->N, t);
        b->pspeed[c].mismatch = mm;
        b->internal += mm;
        progress("  primary %-24s %7.2f Mrays/s%s\n", PRIMARY_CFGS[c].name, b->pspeed[c].mrays, mm ? " MISMATCH" : "");
    }
    for (size_t c = 0; c < N_SHADOW_CFGS; c++) {
        Job j = b->job;
        j.kind = SHADOW_CFGS[c].occ_via_trace ? K_TRACE_OCC : K_OCCLUDED;
        j.occ_method = SHADOW_CFGS[c].method;
        j.occ_via_trace = SHADOW_CFGS[c].occ_via_trace;
        j.params = cfg_params(&SHADOW_CFGS[c], SHEAF_RAY_KIND_SHADOW);
        j.rays = b->srays;
        j.n = b->NSL;
        j.occ = b->socc;
        double t = time_job(&j, 1, b->reps);
        size_t mm = 0;
        for (size_t k = 0; k < b->NSL; k++) mm += b->socc[k] != b->sref[k];
        b->sspeed[c].mrays = mrays(b->NS, t);
        b->sspeed[c].mismatch = mm;
        b->internal += mm;
        progress("  shadow  %-24s %7.2f Mrays/s%s\n", SHADOW_CFGS[c].name, b->sspeed[c].mrays, mm ? " MISMATCH" : "");
    }

    /* Fastest method per structure on 1 thread: the fastest packet method (SIMD
     * rays or n x n packets), or the single ray when that is faster still
     * (named so in the tables); then that method on every thread count. */
    for (int st = 0; st < NSTRUCT; st++) {
        b->pbest[st] = b->sbest[st] = -1;
        if (st == S_BVH_LOW || st == S_BVH_HIGH) {
            /* The SAH tree's fastest methods on the LOW (HIGH) tree, every
             * thread count: trace speed of the fast (spatial-split) build
             * against the SAH build; every answer checked against the
             * reference (time_best). */
            b->pbest[st] = b->pbest[S_BVH];
            b->sbest[st] = b->sbest[S_BVH];
            check_sheaf(b->ctx, sheaf_build(b->ctx, st), "build");
            for (int ti = 0; ti < b->o->nthreads; ti++) {
                size_t before = b->internal;
                time_best(b, st, ti);
                progress("  sheaf %s tree, %d threads: primary %.2f, shadow %.2f Mrays/s%s\n", STRUCT_NAME[st],
                         b->o->threads[ti], b->pbest_mr[st][ti], b->sbest_mr[st][ti],
                         b->internal != before ? " MISMATCH" : "");
            }
            check_sheaf(b->ctx, sheaf_build(b->ctx, S_BVH), "build");
            continue;
        }
        for (size_t c = 0; c < N_PRIMARY_CFGS; c++)
            if (PRIMARY_CFGS[c].structure == st && (b->pbest[st] < 0 || b->pspeed[c].mrays > b->pspeed[b->pbest[st]].mrays))
                b->pbest[st] = (int)c;
        for (size_t c = 0; c < N_SHADOW_CFGS; c++)
            if (SHADOW_CFGS[c].structure == st && (b->sbest[st] < 0 || b->sspeed[c].mrays > b->sspeed[b->sbest[st]].mrays))
                b->sbest[st] = (int)c;
        for (int ti = 0; ti < b->o->nthreads; ti++) {
            int T = b->o->threads[ti];
            if (T == 1) {
                b->pbest_mr[st][ti] = b->pspeed[b->pbest[st]].mrays;
                b->sbest_mr[st][ti] = b->sspeed[b->sbest[st]].mrays;
                continue;
            }
            time_best(b, st, ti);
            progress("  sheaf %s best on %d threads: primary %.2f, shadow %.2f Mrays/s\n",
                     STRUCT_NAME[st], T, b->pbest_mr[st][ti], b->sbest_mr[st][ti]);
        }
    }
}

/* Embree's device configuration for T threads. With SHEAF_ISA=avx2 (or
 * sse2) Embree is capped to the same level (its max_isa), so both libraries
 * trace at one width on an AVX-512 machine standing in for an AVX2 one. */
static void embree_cfg(char *cfg, size_t n, int T)
{
    const char *isa = getenv("SHEAF_ISA");
    if (isa && (!strcmp(isa, "avx2") || !strcmp(isa, "sse2")))
        snprintf(cfg, n, "threads=%d,max_isa=%s", T, !strcmp(isa, "avx2") ? "avx2" : "sse4.2");
    else
        snprintf(cfg, n, "threads=%d", T);
}

/* Embree builds, rays, agreement and its dynamic frame, per thread count and quality. */
/* The dynamic frame with each library's fastest interface, the two in
 * interleaved rounds on T threads. sheaf: BVH LOW rebuild joined by the T
 * threads, camera packets made in the kernel (sheaf_context_trace_camera, one
 * 32x32 tile per call, the LOW tree's fastest camera configuration), shadow
 * rays handed over as packed ray streams (its fastest shadow configuration).
 * Embree: LOW + DYNAMIC rebuild, rtcIntersect16 on RTCRayHit16 packets laid
 * out before the timing (each frame resets tfar and the hit ids), shadow rays
 * written into RTCRay16 for rtcOccluded16. The camera rays' layout is outside
 * both times (sheaf makes them in the kernel; Embree's are prepared); making
 * the shadow rays and converting them to each library's layout is inside
 * both. */
static void fastest_frames(Bench *b, EScene *es, int T, int ti)
{
    size_t np = b->N / 16;
    struct RTCRayHit16 *prep = NULL;
    if (posix_memalign((void **)&prep, 64, np * sizeof *prep) != 0) die("out of memory");
    sheaf_hit *cam = xmalloc(b->N * sizeof *cam);
    memset(prep, 0, np * sizeof *prep);
    for (size_t k = 0; k < b->N; k++) FILL_LANE(prep[k / 16].ray, k % 16, &b->rays[k]);
    Job sj = b->job;
    sj.frame = &b->frame;
    sj.cam_hits = cam;
    sj.pix = b->pix;
    sj.n = b->N;
    const Cfg *pc = &PRIMARY_CFGS[b->pbest[S_BVH_LOW]], *sc = &SHADOW_CFGS[b->sbest[S_BVH_LOW]];
    Job ej;
    memset(&ej, 0, sizeof ej);
    ej.lib = LIB_EMBREE;
    ej.s = &b->s;
    ej.scene = es->scene;
    ej.rays = b->rays;
    ej.n = b->N;
    ej.prim = b->eprim;
    ej.t = b->et;
    ej.width = 16;
    ej.compact = sj.compact = b->o->compact_shadows;
    double t[2][4][MAX_REPS], ratio[MAX_REPS];
    for (int r = 0; r < b->reps; r++) {
        double t0 = now_s();
        check_sheaf(b->ctx, sheaf_build_low_joined(b->ctx, T), "build");
        t[0][1][r] = now_s() - t0;
        sj.kind = K_TRACE;
        sj.params = cfg_params(pc, SHEAF_RAY_KIND_PRIMARY);
        t[0][2][r] = run_job(&sj, T);
        sj.kind = K_FRAME_SHADOW;
        sj.stream_shadows = 1;
        sj.occ_method = sc->method;
        sj.occ_via_trace = sc->occ_via_trace;
        sj.params = cfg_params(sc, SHEAF_RAY_KIND_SHADOW);
        t[0][3][r] = run_job(&sj, T);
        if (sj.shadow_rays != b->NS || sj.occluded != b->nocc)
            b->internal++;
        t[1][1][r] = embree_rebuild(es);
        ej.kind = K_TRACE;
        ej.prep = prep;
        t[1][2][r] = run_job(&ej, T);
        ej.kind = K_FRAME_SHADOW;
        ej.prep = NULL;
        t[1][3][r] = run_job(&ej, T);
        for (int l = 0; l < 2; l++) t[l][0][r] = t[l][1][r] + t[l][2][r] + t[l][3][r];
        ratio[r] = t[0][0][r] / t[1][0][r];
    }
    /* The kernel's camera hits are the reference's, bit for bit. */
    for (size_t k = 0; k < b->N; k++)
        if (cam[b->pix[k]].prim != b->ref[k].prim || memcmp(&cam[b->pix[k]].t, &b->ref[k].t, 4) != 0)
            b->internal++;
    for (int l = 0; l < 2; l++) {
        b->fast[l][ti] = 1e3 * median(t[l][0], b->reps);
        for (int part = 0; part < 3; part++) b->fast_parts[l][ti][part] = 1e3 * median(t[l][part + 1], b->reps);
    }
    b->fast_ratio[ti] = median(ratio, b->reps);
    progress("  fastest interfaces, %d threads: sheaf %.1f ms, Embree %.1f ms\n", T, b->fast[0][ti], b->fast[1][ti]);
    free(prep);
    free(cam);
}

static void time_embree(Bench *b)
{
    /* Embree: per thread count a device; per quality a scene. */
    b->eprim = xmalloc(b->N * sizeof *b->eprim);
    b->eprim1 = xmalloc(b->N * sizeof *b->eprim1);
    b->et = xmalloc(b->N * sizeof *b->et);
    for (int ti = 0; ti < b->o->nthreads; ti++) {
        int T = b->o->threads[ti];
        char cfg[64];
        embree_cfg(cfg, sizeof cfg, T);
        RTCDevice dev = rtcNewDevice(cfg);
        if (!dev)
            die("rtcNewDevice(\"%s\") failed (error %d)", cfg, (int)rtcGetDeviceError(NULL));
        rtcSetDeviceErrorFunction(dev, embree_error, NULL);
        {
            /* LOW + geometry REFIT: refits after the first commit. */
            EScene es;
            double t[MAX_REPS];
            b->e_refit_first[ti] = 1e3 * embree_build(dev, &b->s, Q_REFIT, &es);
            for (int r = 0; r < b->reps; r++) t[r] = embree_rebuild(&es);
            b->e_refit[ti] = 1e3 * median(t, b->reps);
            progress("  Embree LOW + REFIT, %d threads: first build %.1f ms, refit %.1f ms\n", T,
                     b->e_refit_first[ti], b->e_refit[ti]);
            embree_release(&es);
        }
        for (int q = 0; q < 3; q++) {
            EScene es;
            b->e_first[ti][q] = 1e3 * embree_build(dev, &b->s, q, &es);
            double t[MAX_REPS];
            for (int r = 0; r < b->reps; r++) t[r] = embree_rebuild(&es);
            b->e_rebuild[ti][q] = 1e3 * median(t, b->reps);
            progress("  Embree %s, %d threads: first build %.1f ms, rebuild %.1f ms\n", QUALITY_NAME[q], T,
                     b->e_first[ti][q], b->e_rebuild[ti][q]);
            Job j;
            memset(&j, 0, sizeof j);
            j.lib = LIB_EMBREE;
            j.s = &b->s;
            j.scene = es.scene;
            for (int w = 0; w < 4; w++) {
                j.kind = K_TRACE;
                j.width = WIDTHS[w];
                j.rays = b->rays;
                j.n = b->N;
                j.prim = w == 0 ? b->eprim1 : b->eprim;
                j.t = b->et;
                b->e_prim[ti][q][w] = mrays(b->N, time_job(&j, T, b->reps));
                if (ti == 0 && w == 0)
                    agree_primary(&b->s, b->rays, b->ref, b->eprim1, b->et, b->N, &b->ap[q]);
                if (ti == 0 && w > 0)
                    for (size_t k = 0; k < b->N; k++) b->ap[q].width_differ += b->eprim[k] != b->eprim1[k];
                j.kind = K_OCCLUDED;
                j.rays = b->srays;
                j.n = b->NSL;
                j.occ = b->socc;
                b->e_shad[ti][q][w] = mrays(b->NS, time_job(&j, T, b->reps));
                if (ti == 0 && w == 0) {
                    memcpy(b->socc1, b->socc, b->NSL); /* rtcOccluded1's answers */
                    agree_shadow(&b->s, b->ctx, es.scene, b->srays, b->sref, b->socc, b->NSL, &b->as[q]);
                }
                if (ti == 0 && w > 0)
                    for (size_t k = 0; k < b->NSL; k++) b->as[q].width_differ += b->socc[k] != b->socc1[k];
                progress("    rtcIntersect%d %.2f, rtcOccluded%d %.2f Mrays/s\n", WIDTHS[w], b->e_prim[ti][q][w],
                         WIDTHS[w], b->e_shad[ti][q][w]);
            }
            if (q == 0) {
                /* Dynamic frame: rebuild + camera rays + shadow rays, LOW dynamic, best widths. */
                int pw = 0, sw = 0;
                for (int w = 1; w < 4; w++) {
                    if (b->e_prim[ti][0][w] > b->e_prim[ti][0][pw]) pw = w;
                    if (b->e_shad[ti][0][w] > b->e_shad[ti][0][sw]) sw = w;
                }
                double tf[MAX_REPS], tb[MAX_REPS], tp[MAX_REPS], ts[MAX_REPS];
                for (int r = 0; r < b->reps; r++) {
                    tb[r] = embree_rebuild(&es);
                    j.kind = K_TRACE;
                    j.width = WIDTHS[pw];
                    j.rays = b->rays;
                    j.n = b->N;
                    j.prim = b->eprim;
                    j.t = b->et;
                    tp[r] = run_job(&j, T);
                    j.kind = K_FRAME_SHADOW;
                    j.compact = b->o->compact_shadows;
                    j.width = WIDTHS[sw];
                    ts[r] = run_job(&j, T);
                    tf[r] = tb[r] + tp[r] + ts[r];
                }
                b->frame_e[ti] = 1e3 * median(tf, b->reps);
                b->frame_e_parts[ti][0] = 1e3 * median(tb, b->reps);
                b->frame_e_parts[ti][1] = 1e3 * median(tp, b->reps);
                b->frame_e_parts[ti][2] = 1e3 * median(ts, b->reps);
                b->frame_e_pw[ti] = WIDTHS[pw];
                b->frame_e_sw[ti] = WIDTHS[sw];
                progress("  Embree LOW dynamic frame, %d threads: %.1f ms\n", T, b->frame_e[ti]);
                fastest_frames(b, &es, T, ti);
            }
            embree_release(&es);
        }
        rtcReleaseDevice(dev);
    }
}

/* sheaf's dynamic frames, each structure with its fastest methods. */
static void time_sheaf_frames(Bench *b)
{
    /* sheaf dynamic frames: each structure with its best methods. */
    for (int st = 0; st < NSTRUCT; st++)
        for (int ti = 0; ti < b->o->nthreads && in_frame(st); ti++) {
            int T = b->o->threads[ti];
            double tf[MAX_REPS], tb[MAX_REPS], tp[MAX_REPS], ts[MAX_REPS];
            for (int r = 0; r < b->reps; r++) {
                double t0 = now_s();
                sheaf_status e = st == S_BVH_LOW ? sheaf_build_low_joined(b->ctx, T)
                               : st == S_GRID    ? sheaf_grid_joined(b->ctx, T)
                               : st == S_KD      ? sheaf_kd_joined(b->ctx, T)
                                                 : sheaf_build(b->ctx, st);
                tb[r] = now_s() - t0;
                check_sheaf(b->ctx, e, "build");
                Job j = b->job;
                j.hits = b->hits;
                j.params = cfg_params(&PRIMARY_CFGS[b->pbest[st]], SHEAF_RAY_KIND_PRIMARY);
                tp[r] = run_job(&j, T);
                const Cfg *sc = &SHADOW_CFGS[b->sbest[st]];
                j.kind = K_FRAME_SHADOW;
                j.compact = b->o->compact_shadows;
                j.occ_method = sc->method;
                j.occ_via_trace = sc->occ_via_trace;
                j.params = cfg_params(sc, SHEAF_RAY_KIND_SHADOW);
                ts[r] = run_job(&j, T);
                if (j.shadow_rays != b->NS || j.occluded != b->nocc)
                    b->internal++;
                tf[r] = tb[r] + tp[r] + ts[r];
            }
            b->frame_s[st][ti] = 1e3 * median(tf, b->reps);
            b->frame_s_parts[st][ti][0] = 1e3 * median(tb, b->reps);
            b->frame_s_parts[st][ti][1] = 1e3 * median(tp, b->reps);
            b->frame_s_parts[st][ti][2] = 1e3 * median(ts, b->reps);
            progress("  sheaf %s dynamic frame, %d threads: %.1f ms\n", STRUCT_NAME[st], T, b->frame_s[st][ti]);
        }
    b->load1 = load_average();
}

/* A context with only the perspective/light grids' pools, `refs` pairs
 * (0: the default), the scene set. */
static sheaf_context *pgrid_context(Bench *b, uint32_t refs)
{
    sheaf_limits lim;
    sheaf_context *ctx = NULL;
    sheaf_limits_default(b->s.nt, &lim);
    lim.max_vertices = b->s.nv;
    lim.max_image_width = b->W;
    lim.max_image_height = b->H;
    lim.max_threads = MAX_THREADS;
    lim.structures = SHEAF_STRUCTURE_PGRID;
    lim.max_pgrid_refs = refs;
    lim.max_bvh_refs = bvh_refs(b->o, b->s.nt); /* as setup_scene's (no BVH pools here: no memory) */
    check_sheaf(NULL, sheaf_context_create(&lim, &ctx), "sheaf_context_create (perspective/light grids)");
    check_sheaf(ctx, sheaf_context_set_geometry(ctx, b->s.verts, 12, b->s.nv, b->s.idx, b->s.nt), "set_geometry");
    return ctx;
}

/* The perspective/light grid paper's dynamic frame, in a context of its
 * own (whose pair pool grows, as `sheaf render` grows it, until the
 * frame's grids fit): the scene loaded into the grids' pools again (the
 * vertices changed), then a deferred frame (perspective grid camera rays,
 * the light's grid and its sorted shadow rays, every phase joined by the
 * T threads through sheaf_context_render_deferred_joined), without its
 * shading (the other frames shade nothing). Parts from sheaf's phase
 * times: rebuild = load + both grid builds; primary = camera traversal;
 * shadows = rearrangement + shadow traversal. */
static void time_sheaf_pgrid_frames(Bench *b)
{
    sheaf_pgrid_params pp;
    sheaf_pgrid_params_default(&pp);
    sheaf_deferred_job dj;
    memset(&dj, 0, sizeof dj);
    dj.frame = b->frame;
    dj.primary_pgrid = true;
    dj.shadow_light_grid = true;
    uint8_t *rgba = xmalloc(4 * b->N);
    uint32_t refs = 0;
    sheaf_context *ctx = NULL;
    for (int attempt = 0;; attempt++) {
        ctx = pgrid_context(b, refs);
        check_sheaf(ctx, sheaf_context_build_pgrid(ctx, &pp), "build_pgrid");
        sheaf_status e = sheaf_context_render_deferred(ctx, &dj, rgba, 4 * (size_t)b->W, 4 * b->N);
        if (e == SHEAF_STATUS_OK) break;
        if (e != SHEAF_STATUS_CAPACITY_PGRID_REFS || attempt == 4) check_sheaf(ctx, e, "render_deferred (perspective/light grids)");
        sheaf_context_destroy(ctx);
        refs = refs ? 2 * refs : 16 * b->s.nt + (1u << 20);
    }
    for (int ti = 0; ti < b->o->nthreads; ti++) {
        int T = b->o->threads[ti];
        double tf[MAX_REPS], tb[MAX_REPS], tp[MAX_REPS], ts[MAX_REPS];
        for (int r = 0; r < b->reps; r++) {
            double t0 = now_s();
            check_sheaf(ctx, sheaf_context_build_pgrid(ctx, &pp), "build_pgrid");
            double tl = now_s() - t0;
            check_sheaf(ctx, sheaf_joined_call(ctx, T, J_DEFERRED, &dj, rgba, 4 * b->N), "render_deferred_joined");
            double tw = now_s() - t0;
            sheaf_stats st;
            check_sheaf(ctx, sheaf_context_stats(ctx, &st), "stats");
            if (st.shadow_rays != b->NS) b->internal++;
            tf[r] = tw - 1e-9 * (double)st.shade_ns;
            tb[r] = tl + 1e-9 * (double)(st.primary_build_ns + st.shadow_build_ns);
            tp[r] = 1e-9 * (double)st.primary_trace_ns;
            ts[r] = 1e-9 * (double)(st.rearrange_ns + st.shadow_trace_ns);
        }
        b->frame_s[F_PGRID][ti] = 1e3 * median(tf, b->reps);
        b->frame_s_parts[F_PGRID][ti][0] = 1e3 * median(tb, b->reps);
        b->frame_s_parts[F_PGRID][ti][1] = 1e3 * median(tp, b->reps);
        b->frame_s_parts[F_PGRID][ti][2] = 1e3 * median(ts, b->reps);
        progress("  sheaf perspective/light grid frame, %d threads: %.1f ms\n", T, b->frame_s[F_PGRID][ti]);
    }
    sheaf_context_destroy(ctx);
    free(rgba);
}

/* The animation (`sheaf export --frames`). Per frame its vertices are
 * written in place (untimed: the application's work), then timed: the
 * update, the camera rays and the shadow rays, each library with its
 * fastest methods (sheaf: the SAH tree's fastest BVH methods; Embree: the
 * widths fastest on LOW). sheaf updates by a LOW rebuild or by refitting
 * the SAH tree of frame 0; Embree by a LOW + DYNAMIC rebuild or LOW +
 * geometry REFIT. The refit tree's camera hits must equal the rebuilt
 * tree's on every frame (a hash per frame). */
enum { A_SHEAF_LOW, A_SHEAF_REFIT, A_EMBREE_LOW, A_EMBREE_REFIT, NANIM };
static const char *ANIM_NAME[NANIM] = {"sheaf BVH LOW rebuild", "sheaf BVH refit (SAH tree of frame 0)",
                                       "Embree LOW + DYNAMIC rebuild", "Embree LOW + geometry REFIT"};

static uint64_t hits_hash(const sheaf_hit *h, size_t n)
{
    uint64_t x = 1469598103934665603ull; /* FNV-1a */
    for (size_t k = 0; k < n; k++) {
        uint32_t t;
        memcpy(&t, &h[k].t, 4);
        x = (x ^ h[k].prim) * 1099511628211ull;
        x = (x ^ t) * 1099511628211ull;
    }
    return x;
}

static void time_animation(Bench *b)
{
    Scene *s = &b->s;
    size_t vb = 12 * (size_t)s->nv;
    uint64_t *hash = xmalloc(2 * s->nframes * sizeof *hash);
    for (int ti = 0; ti < b->o->nthreads; ti++) {
        int T = b->o->threads[ti];
        char cfg[64];
        embree_cfg(cfg, sizeof cfg, T);
        RTCDevice dev = rtcNewDevice(cfg);
        if (!dev)
            die("rtcNewDevice(\"%s\") failed", cfg);
        int pw = 0, sw = 0;
        for (int w = 0; w < 4; w++) {
            if (WIDTHS[w] == b->frame_e_pw[ti]) pw = w;
            if (WIDTHS[w] == b->frame_e_sw[ti]) sw = w;
        }
        for (int m = 0; m < NANIM; m++) {
            EScene es;
            memcpy(s->verts, s->frames, vb);
            if (m == A_SHEAF_REFIT)
                check_sheaf(b->ctx, sheaf_build_width(b->ctx, S_BVH, 2), "build");
            if (m == A_EMBREE_LOW || m == A_EMBREE_REFIT)
                embree_build(dev, s, m == A_EMBREE_LOW ? 0 : Q_REFIT, &es);
            double sum[3] = {0, 0, 0};
            for (uint32_t f = 0; f < s->nframes; f++) {
                memcpy(s->verts, s->frames + 3 * (size_t)s->nv * f, vb);
                double t0 = now_s(), tb;
                Job j;
                if (m == A_SHEAF_LOW || m == A_SHEAF_REFIT) {
                    sheaf_status e = m == A_SHEAF_LOW ? sheaf_build_low_joined(b->ctx, T)
                                                      : sheaf_refit_joined(b->ctx, T);
                    tb = now_s() - t0;
                    check_sheaf(b->ctx, e, "animation update");
                    j = b->job;
                    j.hits = b->hits;
                    j.params = cfg_params(&PRIMARY_CFGS[b->pbest[S_BVH]], SHEAF_RAY_KIND_PRIMARY);
                    sum[1] += run_job(&j, T);
                    if (ti == 0)
                        hash[2 * f + (m == A_SHEAF_REFIT)] = hits_hash(b->hits, b->N);
                    const Cfg *sc = &SHADOW_CFGS[b->sbest[S_BVH]];
                    j.kind = K_FRAME_SHADOW;
                    j.compact = b->o->compact_shadows;
                    j.occ_method = sc->method;
                    j.occ_via_trace = sc->occ_via_trace;
                    j.params = cfg_params(sc, SHEAF_RAY_KIND_SHADOW);
                    sum[2] += run_job(&j, T);
                } else {
                    tb = embree_rebuild(&es);
                    memset(&j, 0, sizeof j);
                    j.lib = LIB_EMBREE;
                    j.s = s;
                    j.scene = es.scene;
                    j.kind = K_TRACE;
                    j.width = WIDTHS[pw];
                    j.rays = b->rays;
                    j.n = b->N;
                    j.prim = b->eprim;
                    j.t = b->et;
                    sum[1] += run_job(&j, T);
                    j.kind = K_FRAME_SHADOW;
                    j.compact = b->o->compact_shadows;
                    j.width = WIDTHS[sw];
                    sum[2] += run_job(&j, T);
                }
                sum[0] += tb;
            }
            if (m == A_EMBREE_LOW || m == A_EMBREE_REFIT)
                embree_release(&es);
            for (int k = 0; k < 3; k++) b->anim_parts[m][ti][k] = 1e3 * sum[k] / s->nframes;
            b->anim[m][ti] = b->anim_parts[m][ti][0] + b->anim_parts[m][ti][1] + b->anim_parts[m][ti][2];
            progress("  animation, %s, %d threads: %.1f ms per frame\n", ANIM_NAME[m], T, b->anim[m][ti]);
        }
        rtcReleaseDevice(dev);
    }
    for (uint32_t f = 0; f < s->nframes; f++) b->anim_differ += hash[2 * f] != hash[2 * f + 1];
    b->internal += b->anim_differ;
    free(hash);
    /* Back to frame 0 (the exported vertices) and the SAH tree. */
    memcpy(s->verts, s->frames, vb);
    check_sheaf(b->ctx, sheaf_build(b->ctx, S_BVH), "build");
}

/* The Markdown tables of one scene. */
static void print_tables(Bench *b)
{
    /* ---- tables ---- */
    printf("\n### %s\n\n", b->name);
    printf("%u triangles (%u excluded by sheaf: non-finite or zero area), %ux%u, %s; "
           "%zu camera rays (%zu hit), %zu shadow rays (%zu occluded); load average %.2f before, %.2f after.\n\n",
           b->s.nt, b->s.excluded, b->W, b->H, b->s.view, b->N, b->nhits, b->NS, b->nocc, b->load0, b->load1);
    printf("**Builds**, ms (median of %d; sheaf's grid, BVH builds, kd build and refit run on the caller's threads, "
           "which join them (sheaf_context_build_grid_joined, sheaf_context_build_bvh_joined, "
           "sheaf_context_build_kd_joined, sheaf_context_refit_bvh_joined; the bench starts those threads per call, inside the timing, as it "
           "does for its ray jobs); sheaf's HIGH build splits references spatially into a reserve of %d%% of the "
           "triangles (--bvh-reserve%s); Embree's on its device threads; each sheaf BVH quality beside Embree's):\n\n",
           b->reps, b->o->bvh_reserve, b->o->bvh_reserve ? "" : " 0: none, so no spatial splits");
    printf("| structure |");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" %d thread%s |", b->o->threads[ti], b->o->threads[ti] > 1 ? "s" : "");
    printf("\n|---|");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf("--:|");
    printf("\n");
    /* The grid and the kd-tree, then per quality sheaf's BVH and Embree's. */
    static const int BUILD_ROWS[] = {S_GRID, S_KD, S_BVH_LOW, -1, S_BVH, -2, S_BVH_HIGH, -3};
    for (size_t row = 0; row < sizeof BUILD_ROWS / sizeof BUILD_ROWS[0]; row++) {
        int st = BUILD_ROWS[row];
        if (st < 0) {
            int q = -st - 1;
            printf("| Embree %s%s: rebuild (first commit) |", QUALITY_NAME[q], q == 0 ? " + DYNAMIC" : "");
            for (int ti = 0; ti < b->o->nthreads; ti++) printf(" %.1f (%.1f) |", b->e_rebuild[ti][q], b->e_first[ti][q]);
            printf("\n");
            continue;
        }
        printf("| sheaf %s%s (joined by the thread count) |", STRUCT_NAME[st],
               st == S_BVH_HIGH ? " (spatial splits)" : "");
        for (int ti = 0; ti < b->o->nthreads; ti++)
            printf(" %.1f |", st == S_BVH_LOW    ? b->low_ms[ti]
                             : st == S_GRID     ? b->grid_ms[ti]
                             : st == S_KD       ? b->kd_ms[ti]
                             : st == S_BVH      ? b->sah_ms[0][ti]
                                                : b->sah_ms[1][ti]);
        printf("\n");
    }
    printf("| sheaf BVH refit (joined by the thread count) |");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" %.1f |", b->refit_ms[ti]);
    printf("\n| Embree LOW + geometry REFIT: refit (first commit) |");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" %.1f (%.1f) |", b->e_refit[ti], b->e_refit_first[ti]);
    printf("\n");
    printf("\n**Rays**, Mrays/s (median of %d; sheaf: the fastest method of each structure on 1 thread, "
           "camera rays / shadow rays, the BVH's on its MEDIUM (binned SAH) tree, then the same methods on its "
           "LOW and HIGH (spatial splits) trees; Embree: LOW / MEDIUM / HIGH):\n\n", b->reps);
    printf("| configuration |");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" primary, %dT |", b->o->threads[ti]);
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" shadow, %dT |", b->o->threads[ti]);
    printf("\n|---|");
    for (int ti = 0; ti < 2 * b->o->nthreads; ti++) printf("--:|");
    printf("\n");
    for (int st = 0; st < NSTRUCT; st++) {
        printf("| sheaf %s: %s / %s |", STRUCT_NAME[st], PRIMARY_CFGS[b->pbest[st]].name, SHADOW_CFGS[b->sbest[st]].name);
        for (int ti = 0; ti < b->o->nthreads; ti++) {
            printf(" %.2f |", b->pbest_mr[st][ti]);
            if (b->pbest_mr[st][ti] > b->sheaf_best_p[ti]) b->sheaf_best_p[ti] = b->pbest_mr[st][ti];
        }
        for (int ti = 0; ti < b->o->nthreads; ti++) {
            printf(" %.2f |", b->sbest_mr[st][ti]);
            if (b->sbest_mr[st][ti] > b->sheaf_best_s[ti]) b->sheaf_best_s[ti] = b->sbest_mr[st][ti];
        }
        printf("\n");
    }
    for (int w = 0; w < 4; w++) {
        printf("| Embree rtcIntersect%d / rtcOccluded%d |", WIDTHS[w], WIDTHS[w]);
        for (int ti = 0; ti < b->o->nthreads; ti++) {
            printf(" %.1f / %.1f / %.1f |", b->e_prim[ti][0][w], b->e_prim[ti][1][w], b->e_prim[ti][2][w]);
            for (int q = 0; q < 3; q++)
                if (b->e_prim[ti][q][w] > b->emb_best_p[ti]) b->emb_best_p[ti] = b->e_prim[ti][q][w];
        }
        for (int ti = 0; ti < b->o->nthreads; ti++) {
            printf(" %.1f / %.1f / %.1f |", b->e_shad[ti][0][w], b->e_shad[ti][1][w], b->e_shad[ti][2][w]);
            for (int q = 0; q < 3; q++)
                if (b->e_shad[ti][q][w] > b->emb_best_s[ti]) b->emb_best_s[ti] = b->e_shad[ti][q][w];
        }
        printf("\n");
    }
    printf("| **sheaf best / Embree best** |");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" **%.2f** |", b->sheaf_best_p[ti] / b->emb_best_p[ti]);
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" **%.2f** |", b->sheaf_best_s[ti] / b->emb_best_s[ti]);
    printf("\n\n**Dynamic frame**, ms (median of %d): rebuild + camera rays + shadow-ray making + shadow rays "
           "(sheaf: each structure with its best methods, the BVH HIGH build left out as Embree's HIGH is; "
           "Embree: LOW + DYNAMIC, rtcUpdateGeometryBuffer + commits, its fastest widths):\n\n", b->reps);
    printf("| |");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" %d thread%s: frame (rebuild + primary + shadows) |", b->o->threads[ti], b->o->threads[ti] > 1 ? "s" : "");
    printf("\n|---|");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf("--:|");
    printf("\n");
    for (int ti = 0; ti < b->o->nthreads; ti++) {
        b->best_st[ti] = 0;
        for (int st = 1; st < NFRAME; st++)
            if (in_frame(st) && b->frame_s[st][ti] < b->frame_s[b->best_st[ti]][ti]) b->best_st[ti] = st;
        b->best_frame[ti] = b->frame_s[b->best_st[ti]][ti];
    }
    for (int st = 0; st < NFRAME; st++) {
        if (!in_frame(st))
            continue;
        printf("| sheaf %s%s |", STRUCT_NAME[st], st == F_PGRID ? " (deferred frame, no shading; every phase joined)" : "");
        for (int ti = 0; ti < b->o->nthreads; ti++)
            printf(" %s%.1f%s (%.1f + %.1f + %.1f) |", b->best_st[ti] == st ? "**" : "", b->frame_s[st][ti],
                   b->best_st[ti] == st ? "**" : "", b->frame_s_parts[st][ti][0], b->frame_s_parts[st][ti][1],
                   b->frame_s_parts[st][ti][2]);
        printf("\n");
    }
    printf("| Embree LOW + DYNAMIC |");
    for (int ti = 0; ti < b->o->nthreads; ti++)
        printf(" %.1f (%.1f + %.1f + %.1f; rtcIntersect%d, rtcOccluded%d) |", b->frame_e[ti], b->frame_e_parts[ti][0],
               b->frame_e_parts[ti][1], b->frame_e_parts[ti][2], b->frame_e_pw[ti], b->frame_e_sw[ti]);
    printf("\n| **sheaf best / Embree (time ratio)** |");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" **%.2f** (%s) |", b->best_frame[ti] / b->frame_e[ti], STRUCT_NAME[b->best_st[ti]]);
    printf("\n\n**Dynamic frame, each library's fastest interface**, ms (interleaved rounds, median of %d): sheaf "
           "BVH LOW, camera packets made in the kernel (sheaf_context_trace_camera), shadow rays as ray streams; "
           "Embree LOW + DYNAMIC, rtcIntersect16 on RTCRayHit16 laid out before the timing, rtcOccluded16 "
           "(shadow-ray making and layout inside both times):\n\n| |", b->reps);
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" %d thread%s: frame (rebuild + primary + shadows) |", b->o->threads[ti], b->o->threads[ti] > 1 ? "s" : "");
    printf("\n|---|");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf("--:|");
    for (int l = 0; l < 2; l++) {
        printf("\n| %s |", l ? "Embree LOW, rtcIntersect16 prepared" : "sheaf BVH LOW, camera packets + streams");
        for (int ti = 0; ti < b->o->nthreads; ti++)
            printf(" %.1f (%.1f + %.1f + %.1f) |", b->fast[l][ti], b->fast_parts[l][ti][0], b->fast_parts[l][ti][1],
                   b->fast_parts[l][ti][2]);
    }
    printf("\n| **sheaf / Embree (median of per-round time ratios)** |");
    for (int ti = 0; ti < b->o->nthreads; ti++) printf(" **%.2f** |", b->fast_ratio[ti]);
    if (b->s.nframes) {
        printf("\n\n**Animation**, %u frames 1/30 s apart, mean ms per frame: update + camera rays + shadow rays "
               "(the vertices written in place before each frame, untimed); sheaf's refit tree gave the rebuilt "
               "tree's camera hits on %u of %u frames:\n\n| |", b->s.nframes,
               b->s.nframes - (unsigned)b->anim_differ, b->s.nframes);
        for (int ti = 0; ti < b->o->nthreads; ti++) printf(" %d thread%s |", b->o->threads[ti], b->o->threads[ti] > 1 ? "s" : "");
        printf("\n|---|");
        for (int ti = 0; ti < b->o->nthreads; ti++) printf("--:|");
        printf("\n");
        for (int m = 0; m < NANIM; m++) {
            printf("| %s |", ANIM_NAME[m]);
            for (int ti = 0; ti < b->o->nthreads; ti++)
                printf(" %.1f (%.1f + %.1f + %.1f) |", b->anim[m][ti], b->anim_parts[m][ti][0], b->anim_parts[m][ti][1],
                       b->anim_parts[m][ti][2]);
            printf("\n");
        }
        printf("| **sheaf best / Embree best (time ratio)** |");
        for (int ti = 0; ti < b->o->nthreads; ti++) {
            double sb = fmin(b->anim[A_SHEAF_LOW][ti], b->anim[A_SHEAF_REFIT][ti]);
            double eb = fmin(b->anim[A_EMBREE_LOW][ti], b->anim[A_EMBREE_REFIT][ti]);
            printf(" **%.2f** |", sb / eb);
        }
        printf("\n");
    }
    printf("\n\n**Agreement** (sheaf's BVH single ray, which every sheaf method matched, against Embree's "
           "rtcIntersect1 / rtcOccluded1 on the same rays; explained in f64: tie = hits within %g of each "
           "other, edge = within %g of a triangle's edge in barycentrics or the ray's line within %g of it relative to the coordinates, end = occluder within %g of the "
           "ray's end):\n\n", TIE_REL, EDGE_BARY, EDGE_REL, END_REL);
    printf("| rays | Embree quality | rays | hits sheaf / Embree | differ | ties | edges | ends | other | Embree 4/8/16-wide vs its 1-wide (sum) |\n");
    printf("|---|---|--:|--:|--:|--:|--:|--:|--:|--:|\n");
    for (int q = 0; q < 3; q++)
        printf("| primary | %s | %zu | %zu / %zu | %zu | %zu | %zu | – | %zu | %zu |\n", QUALITY_NAME[q], b->N,
               b->ap[q].hits_sheaf, b->ap[q].hits_embree, b->ap[q].differ, b->ap[q].ties, b->ap[q].edges, b->ap[q].other,
               b->ap[q].width_differ);
    for (int q = 0; q < 3; q++)
        printf("| shadow | %s | %zu | %zu / %zu occluded | %zu | – | %zu | %zu | %zu | %zu |\n", QUALITY_NAME[q], b->NS,
               b->as[q].hits_sheaf, b->as[q].hits_embree, b->as[q].differ, b->as[q].edges, b->as[q].ends, b->as[q].other,
               b->as[q].width_differ);
    printf("\nsheaf self-check: %zu answers of %zu timed sheaf runs (and of the BVH LOW and HIGH trees' runs) differ "
           "from the reference", b->internal, N_PRIMARY_CFGS + N_SHADOW_CFGS);
    if (b->ray_check >= 0)
        printf("; camera and shadow rays equal to sheaf's deferred frame on %zu of %zu pixels", b->N - (size_t)b->ray_check, b->N);
    printf(".\n\n<details><summary>every sheaf method, 1 thread (Mrays/s)</summary>\n\n");
    printf("| method | primary | | method | shadow |\n|---|--:|---|---|--:|\n");
    for (size_t r = 0; r < N_PRIMARY_CFGS || r < N_SHADOW_CFGS; r++) {
        if (r < N_PRIMARY_CFGS) printf("| %s | %.2f |", PRIMARY_CFGS[r].name, b->pspeed[r].mrays);
        else printf("| | |");
        if (r < N_SHADOW_CFGS) printf(" | %s%s | %.2f |\n", SHADOW_CFGS[r].name,
                                      SHADOW_CFGS[r].occ_via_trace ? " (trace_with)" : "", b->sspeed[r].mrays);
        else printf(" | | |\n");
    }
    printf("\n</details>\n");
    fflush(stdout);
}

/* Summary lines, --check, the closing table's line; frees the scene. */
static void finish_scene(Bench *b)
{
    /* ---- summary and checks ---- */
    summary(b->name, "triangles", b->s.nt);
    summary(b->name, "primary_rays", (double)b->N);
    summary(b->name, "shadow_rays", (double)b->NS);
    summary(b->name, "sheaf_hits", (double)b->nhits);
    summary(b->name, "sheaf_occluded", (double)b->nocc);
    summary(b->name, "sheaf_internal_mismatch", (double)b->internal);
    summary(b->name, "ray_check_mismatch", (double)b->ray_check);
    for (int q = 0; q < 3; q++) {
        char k[64];
#define SUM(field, prefix, agr)                              \
        snprintf(k, sizeof k, "%s_%s_%s", prefix, QUALITY_NAME[q], #field); \
        summary(b->name, k, (double)agr[q].field);
        SUM(hits_embree, "primary", b->ap) SUM(differ, "primary", b->ap) SUM(ties, "primary", b->ap)
        SUM(edges, "primary", b->ap) SUM(other, "primary", b->ap) SUM(width_differ, "primary", b->ap)
        SUM(hits_embree, "shadow", b->as) SUM(differ, "shadow", b->as) SUM(edges, "shadow", b->as)
        SUM(ends, "shadow", b->as) SUM(other, "shadow", b->as) SUM(width_differ, "shadow", b->as)
#undef SUM
    }
    for (int ti = 0; ti < b->o->nthreads; ti++) {
        char k[64];
        snprintf(k, sizeof k, "ratio_primary_%dT", b->o->threads[ti]);
        summary(b->name, k, b->sheaf_best_p[ti] / b->emb_best_p[ti]);
        snprintf(k, sizeof k, "ratio_shadow_%dT", b->o->threads[ti]);
        summary(b->name, k, b->sheaf_best_s[ti] / b->emb_best_s[ti]);
        snprintf(k, sizeof k, "ratio_frame_%dT", b->o->threads[ti]);
        summary(b->name, k, b->best_frame[ti] / b->frame_e[ti]);
        snprintf(k, sizeof k, "ratio_frame_fastest_%dT", b->o->threads[ti]);
        summary(b->name, k, b->fast_ratio[ti]);
        snprintf(k, sizeof k, "ratio_build_low_%dT", b->o->threads[ti]);
        summary(b->name, k, b->low_ms[ti] / b->e_rebuild[ti][0]);
        if (b->s.nframes) {
            snprintf(k, sizeof k, "ratio_animation_%dT", b->o->threads[ti]);
            summary(b->name, k, fmin(b->anim[A_SHEAF_LOW][ti], b->anim[A_SHEAF_REFIT][ti]) /
                                    fmin(b->anim[A_EMBREE_LOW][ti], b->anim[A_EMBREE_REFIT][ti]));
        }
    }
    if (g_nresults < (int)(sizeof g_results / sizeof g_results[0])) {
        SceneResult *r = &g_results[g_nresults++];
        snprintf(r->name, sizeof r->name, "%.63s", b->name);
        r->triangles = b->s.nt;
        for (int ti = 0; ti < b->o->nthreads; ti++) {
            r->ratio_p[ti] = b->sheaf_best_p[ti] / b->emb_best_p[ti];
            r->ratio_s[ti] = b->sheaf_best_s[ti] / b->emb_best_s[ti];
            r->ratio_f[ti] = b->best_frame[ti] / b->frame_e[ti];
            r->ratio_b[ti] = b->low_ms[ti] / b->e_rebuild[ti][0];
            r->ratio_r[ti] = b->refit_ms[ti] / b->e_refit[ti];
            r->frame_struct[ti] = STRUCT_NAME[b->best_st[ti]];
        }
        r->p_differ = b->ap[1].differ;
        r->p_ties = b->ap[1].ties;
        r->p_edges = b->ap[1].edges;
        r->s_differ = b->as[1].differ;
        r->s_edges = b->as[1].edges;
        r->s_ends = b->as[1].ends;
        for (int q = 0; q < 3; q++) r->unexplained += b->ap[q].other + b->as[q].other;
    }
    if (b->o->check) {
        int bad = b->internal > 0 || b->ray_check > 0;
        for (int q = 0; q < 3; q++) {
            bad |= b->ap[q].other > MAX_UNEXPLAINED || b->as[q].other > MAX_UNEXPLAINED;
            bad |= (double)b->ap[q].differ > MAX_DIFF_FRACTION * (double)b->N;
            bad |= (double)b->as[q].differ > MAX_DIFF_FRACTION * (double)(b->NS ? b->NS : 1);
        }
        if (bad) {
            fprintf(stderr, "embree_bench: %s: agreement outside the bounds (MAX_UNEXPLAINED %d, MAX_DIFF_FRACTION %g, "
                            "sheaf self-check %zu, ray check %ld)\n", b->name, MAX_UNEXPLAINED, MAX_DIFF_FRACTION, b->internal, b->ray_check);
            g_fail = 1;
        }
    }

    free(b->rays); free(b->pix); free(b->ref); free(b->hits); free(b->srays); free(b->slot_of); free(b->sref); free(b->socc); free(b->socc1);
    free(b->eprim); free(b->eprim1); free(b->et);
    free(b->s.verts); free(b->s.idx); free(b->s.frames);
    sheaf_context_destroy(b->ctx);
    if (b->hctx) sheaf_context_destroy(b->hctx);
}

/* A sheaf configuration on the HIGH tree (--ab, --profile): "high:NAME"
 * (as --ab's low:NAME) or "NAME high", e.g. "bvh-frustum 16x16 high": 1 and
 * NAME in out (n bytes), else 0 and `name` in out. */
static int high_name(const char *name, char *out, size_t n)
{
    size_t len = strlen(name);
    if (!strncmp(name, "high:", 5)) {
        snprintf(out, n, "%s", name + 5);
        return 1;
    }
    if (len > 5 && !strcmp(name + len - 5, " high")) {
        snprintf(out, n, "%.*s", (int)(len - 5), name);
        return 1;
    }
    snprintf(out, n, "%s", name);
    return 0;
}

/* A sheaf job's answers (camera hits, or shadow occlusion with `shadow`)
 * against the reference (the MEDIUM tree's BVH single ray), bit for bit:
 * run once on one thread, then the first that differs is fatal. */
static void check_job(Bench *b, Job *j, int shadow, const char *name)
{
    run_job(j, 1);
    size_t bad = 0, first = 0;
    if (shadow) {
        for (size_t k = 0; k < b->NSL; k++)
            if (j->occ[k] != b->sref[k] && !bad++) first = k;
    } else {
        for (size_t k = 0; k < b->N; k++) {
            uint32_t prim = j->soa[0] ? j->sh_prim[k] : j->hits[k].prim;
            float t = j->soa[0] ? j->sh[0][k] : j->hits[k].t;
            if ((prim != b->ref[k].prim || memcmp(&t, &b->ref[k].t, 4) != 0) && !bad++) first = k;
        }
    }
    if (bad)
        die("%s: %zu %s rays differ from the reference (the MEDIUM tree's BVH single ray), the first ray %zu", name,
            bad, shadow ? "shadow" : "camera", first);
}

/* The job timing configuration `name` on this scene: a sheaf method by its
 * table name ("bvh-ranged 8x8"), on the HIGH tree as "high:NAME" or "NAME
 * high" (a context of its own, high_context; its answers checked against the
 * reference first), or "embree-N" (Embree LOW + DYNAMIC), "embree-N-medium",
 * "embree-N-high" (rtcIntersectN / rtcOccludedN; its scene built into *es on
 * a device of `threads` threads, returned in *dev). Camera rays, or the
 * shadow rays with `shadow`; *n is the rays counted for Mrays/s. Embree's
 * outputs go to arrays of their own. */
static Job named_job(Bench *b, const char *name, int shadow, int threads, size_t *n, EScene *es,
                     RTCDevice *dev)
{
    Job j = b->job;
    j.hits = b->hits;
    *n = b->N;
    *dev = NULL;
    if (!strncmp(name, "embree-", 7)) {
        char *end;
        long w = strtol(name + 7, &end, 10);
        int q = !*end || !strcmp(end, "-low") ? 0 : !strcmp(end, "-medium") ? 1 : !strcmp(end, "-high") ? 2 : -1;
        if ((w != 1 && w != 4 && w != 8 && w != 16) || q < 0)
            die("%s: embree-N (LOW + DYNAMIC), embree-N-medium or embree-N-high, N 1, 4, 8 or 16", name);
        char cfg[64];
        embree_cfg(cfg, sizeof cfg, threads);
        *dev = rtcNewDevice(cfg);
        if (!*dev) die("rtcNewDevice failed");
        embree_build(*dev, &b->s, q, es);
        memset(&j, 0, sizeof j);
        j.lib = LIB_EMBREE;
        j.s = &b->s;
        j.scene = es->scene;
        j.width = (int)w;
        j.kind = shadow ? K_OCCLUDED : K_TRACE;
        j.rays = shadow ? b->srays : b->rays;
        j.n = shadow ? b->NSL : b->N;
        j.prim = xmalloc(b->N * sizeof *j.prim);
        j.t = xmalloc(b->N * sizeof *j.t);
        j.occ = xmalloc(b->N);
        *n = shadow ? b->NS : b->N;
    } else {
        const char *full = name;
        char base[256];
        int high = high_name(name, base, sizeof base);
        name = base;
        if (high && !strncmp(name, "embree-", 7))
            die("%s: Embree's HIGH tree is embree-N-high", full);
        if (high)
            j.ctx = high_context(b);
        /* "soa:NAME": the configuration traced from a ray stream; "cam:NAME"
         * its camera rays made in the kernel. */
        int soa = !strncmp(name, "soa:", 4), cam = !strncmp(name, "cam:", 4);
        if (soa || cam) name += 4;
        if (cam && shadow) {
            /* Shadow rays come from hits: the ray-array configuration. */
            cam = 0;
        }
        const Cfg *cfgs = shadow ? SHADOW_CFGS : PRIMARY_CFGS;
        size_t nc = shadow ? N_SHADOW_CFGS : N_PRIMARY_CFGS, c = 0;
        while (c < nc && strcmp(cfgs[c].name, name)) c++;
        if (c == nc) die("no %s configuration named \"%s\" (see the tables' names)", shadow ? "shadow" : "camera", name);
        j.params = cfg_params(&cfgs[c], shadow ? SHEAF_RAY_KIND_SHADOW : SHEAF_RAY_KIND_PRIMARY);
        if (shadow) {
            j.kind = cfgs[c].occ_via_trace ? K_TRACE_OCC : K_OCCLUDED;
            j.occ_method = cfgs[c].method;
            j.occ_via_trace = cfgs[c].occ_via_trace;
            j.rays = b->srays;
            j.n = b->NSL;
            j.occ = b->socc;
            *n = b->NS;
        }
        if (soa) {
            if (j.kind != K_TRACE && j.kind != K_OCCLUDED) die("soa:%s: not a trace or occluded configuration", name);
            for (int f = 0; f < 8; f++) j.soa[f] = xmalloc(j.n * sizeof(float));
            for (size_t k = 0; k < j.n; k++) {
                const sheaf_ray *r = &j.rays[k];
                const float v[8] = {r->org[0], r->org[1], r->org[2], r->dir[0], r->dir[1], r->dir[2], r->tmin, r->tmax};
                for (int f = 0; f < 8; f++) j.soa[f][k] = v[f];
            }
            for (int f = 0; f < 3; f++) j.sh[f] = xmalloc(j.n * sizeof(float));
            j.sh_prim = xmalloc(j.n * sizeof(uint32_t));
        }
        if (cam) {
            if (j.kind != K_TRACE) die("cam:%s: not a camera trace configuration", name);
            j.frame = &b->frame;
            j.cam_hits = xmalloc(j.n * sizeof *j.cam_hits);
            run_job(&j, 1);
            /* Every pixel's hit is the reference ray's, bit for bit. */
            for (size_t k = 0; k < j.n; k++) {
                const sheaf_hit *h = &j.cam_hits[b->pix[k]], *w = &b->ref[k];
                if (h->prim != w->prim || memcmp(&h->t, &w->t, 4) != 0)
                    die("cam:%s: pixel %u differs from the ray-array reference", name, b->pix[k]);
            }
        } else if (high) {
            /* The HIGH tree's answers are the reference's, bit for bit. */
            check_job(b, &j, shadow, full);
        }
    }
    return j;
}

static void release_job(Job *j, EScene *es, RTCDevice dev)
{
    free(j->cam_hits);
    if (j->soa[0]) {
        for (int f = 0; f < 8; f++) free(j->soa[f]);
        for (int f = 0; f < 3; f++) free(j->sh[f]);
        free(j->sh_prim);
    }
    if (!dev) return;
    free(j->prim);
    free(j->t);
    free(j->occ);
    embree_release(es);
    rtcReleaseDevice(dev);
}

/* --profile NAME: one configuration alone on one thread, reps times, so
 * `perf stat` / `perf record` see nothing else. Camera rays, or the shadow
 * rays with --profile-shadow. */
static void profile_one(Bench *b)
{
    const Options *o = b->o;
    size_t n;
    EScene es;
    RTCDevice dev;
    Job j = named_job(b, o->profile, o->profile_shadow, 1, &n, &es, &dev);
    double t = time_job(&j, 1, b->reps);
    printf("profile %s, %s rays: %.2f Mrays/s (median of %d; load average %.2f)\n", o->profile,
           o->profile_shadow ? "shadow" : "camera", mrays(n, t), b->reps, load_average());
    release_job(&j, &es, dev);
}

/* --updates: sheaf's LOW build (joined by T threads) and Embree's LOW
 * rebuild, then sheaf's refit of its SAH tree (width 4; after an untimed
 * refit, so the cached SAH is in steady state, as a frame loop has it) and
 * Embree's LOW + geometry REFIT commit, in interleaved rounds (sheaf,
 * Embree, sheaf, Embree, ...) on the same vertices: each median and the
 * median of the per-round ratios (above 1: sheaf slower). */
static void profile_updates(Bench *b, const char *scene)
{
    const Options *o = b->o;
    int reps = o->reps < 3 ? 3 : o->reps;
    printf("\n### Updates: %s, %zu triangles, %d interleaved rounds, load %.2f\n\n", scene, (size_t)b->s.nt, reps,
           load_average());
    printf("| threads | sheaf LOW build ms | Embree LOW rebuild ms | build ratio | sheaf refit ms | Embree refit ms | "
           "refit ratio |\n|--:|--:|--:|--:|--:|--:|--:|\n");
    for (int ti = 0; ti < o->nthreads; ti++) {
        int T = o->threads[ti];
        char cfg[64];
        embree_cfg(cfg, sizeof cfg, T);
        RTCDevice dev = rtcNewDevice(cfg);
        if (!dev) die("rtcNewDevice(\"%s\") failed", cfg);
        EScene low, ref;
        (void)embree_build(dev, &b->s, 0, &low);
        (void)embree_build(dev, &b->s, Q_REFIT, &ref);
        double sb[MAX_REPS], eb[MAX_REPS], sr[MAX_REPS], er[MAX_REPS], rb[MAX_REPS], rr[MAX_REPS];
        for (int r = 0; r < reps; r++) {
            double t0 = now_s();
            check_sheaf(b->ctx, sheaf_build_low_joined(b->ctx, T), "LOW build");
            sb[r] = now_s() - t0;
            eb[r] = embree_rebuild(&low);
            check_sheaf(b->ctx, sheaf_build_width(b->ctx, S_BVH, 4), "build");
            check_sheaf(b->ctx, sheaf_refit_joined(b->ctx, T), "refit");
            t0 = now_s();
            check_sheaf(b->ctx, sheaf_refit_joined(b->ctx, T), "refit");
            sr[r] = now_s() - t0;
            er[r] = embree_rebuild(&ref);
            rb[r] = sb[r] / eb[r];
            rr[r] = sr[r] / er[r];
        }
        printf("| %d | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f |\n", T, 1e3 * median(sb, reps), 1e3 * median(eb, reps),
               median(rb, reps), 1e3 * median(sr, reps), 1e3 * median(er, reps), median(rr, reps));
        fflush(stdout);
        embree_release(&low);
        embree_release(&ref);
        rtcReleaseDevice(dev);
    }
}

/* --ab "A,B,...": the named configurations timed in interleaved rounds (A B
 * .. A B ..), camera and shadow rays, on each thread count: each one's
 * median Mrays/s and the median over rounds of its per-round speed over the
 * last one's (name Embree last to read sheaf / Embree). One Markdown table. */
#define MAX_AB 8
static void profile_ab(Bench *b, const char *scene)
{
    const Options *o = b->o;
    char buf[512], *names[MAX_AB];
    int k = 0;
    snprintf(buf, sizeof buf, "%s", o->ab);
    for (char *tok = strtok(buf, ","); tok && k < MAX_AB; tok = strtok(NULL, ",")) names[k++] = tok;
    if (k < 1) die("--ab: no configuration");
    /* "low:NAME": sheaf's configurations trace the LOW (Morton) tree, as the
     * dynamic frame does; all of them or none (they share one context).
     * "high:NAME" or "NAME high" trace the HIGH tree, which lives in a
     * context of its own (high_context), so they mix with either. */
    int low = -1;
    for (int c = 0; c < k; c++) {
        int l = !strncmp(names[c], "low:", 4);
        if (l) names[c] += 4;
        char base[256];
        int h = high_name(names[c], base, sizeof base);
        if (h && l) die("--ab: low:%s: the LOW or the HIGH tree, not both", names[c]);
        if (strncmp(names[c], "embree-", 7) && !h) {
            if (low >= 0 && low != l) die("--ab: low: on every sheaf configuration of the MEDIUM/LOW context or on none");
            low = l;
        }
    }
    if (low == 1) check_sheaf(b->ctx, sheaf_build(b->ctx, S_BVH_LOW), "build");
    printf("\n### %s: interleaved rounds (median of %d; load average %.2f at start)\n\n", scene, b->reps,
           load_average());
    printf("| rays | threads | configuration | Mrays/s | speed / %s |\n|---|--:|---|--:|--:|\n", names[k - 1]);
    for (int shadow = 0; shadow < 2; shadow++) {
        for (int ti = 0; ti < o->nthreads; ti++) {
            int th = o->threads[ti];
            Job j[MAX_AB];
            EScene es[MAX_AB];
            RTCDevice dev[MAX_AB];
            size_t n[MAX_AB];
            double t[MAX_AB][MAX_REPS], ratio[MAX_AB][MAX_REPS];
            for (int c = 0; c < k; c++) {
                j[c] = named_job(b, names[c], shadow, th, &n[c], &es[c], &dev[c]);
                run_job(&j[c], th); /* warm-up */
            }
            for (int r = 0; r < b->reps; r++) {
                for (int c = 0; c < k; c++) t[c][r] = run_job(&j[c], th);
                for (int c = 0; c < k; c++)
                    ratio[c][r] = mrays(n[c], t[c][r]) / mrays(n[k - 1], t[k - 1][r]);
            }
            for (int c = 0; c < k; c++) {
                printf("| %s | %d | %s | %.2f | %.2f |\n", shadow ? "shadow" : "camera", th, names[c],
                       mrays(n[c], median(t[c], b->reps)), median(ratio[c], b->reps));
                fflush(stdout);
                release_job(&j[c], &es[c], dev[c]);
            }
        }
    }
}

static void run_scene(const char *path, const Options *o)
{
    Bench *b = calloc(1, sizeof *b);
    if (!b)
        die("out of memory");
    b->o = o;
    setup_scene(b, path);
    if (o->updates) {
        char name[64];
        short_name(path, name, sizeof name);
        profile_updates(b, name);
        free(b);
        return;
    }
    time_sheaf_builds(b);
    make_reference(b);
    if (o->profile) {
        profile_one(b);
        if (b->hctx) sheaf_context_destroy(b->hctx);
        free(b);
        return;
    }
    if (o->ab) {
        char name[64];
        short_name(path, name, sizeof name);
        profile_ab(b, name);
        if (b->hctx) sheaf_context_destroy(b->hctx);
        free(b);
        return;
    }
    check_rays(b);
    time_sheaf_methods(b);
    time_embree(b);
    time_sheaf_frames(b);
    time_sheaf_pgrid_frames(b);
    if (b->s.nframes)
        time_animation(b);
    print_tables(b);
    finish_scene(b);
    free(b);
}

/* ---- two-level scene ---------------------------------------------------------------- */

/* embree_bench --twolevel ENV.scene ANIM.scene OBJ.scene: one frame loop of
 * an engine over a two-level scene, in both libraries, on the same
 * instances and rays.
 *
 *  - geometry 0, ENV: static (sheaf STATIC, binned SAH; Embree child scene
 *    at MEDIUM, committed once), one instance, the identity;
 *  - geometry 1, ANIM (`sheaf export builtin:animated --frames F`): its
 *    vertices change every frame (sheaf REFIT: sheaf_context_update_scene_
 *    geometry; Embree child scene LOW + DYNAMIC, its geometry at
 *    RTC_BUILD_QUALITY_REFIT: the frame's vertices copied into the shared
 *    vertex buffer, rtcUpdateGeometryBuffer, rtcCommitGeometry,
 *    rtcCommitScene), TL_ANIM instances side by side on the focus (ENV's
 *    surface in front of the camera, see tl_setup), each TL_ANIM_SIZE of
 *    ENV's diagonal;
 *  - geometry 2, OBJ: static, TL_RING instances in a ring around the focus
 *    whose transforms turn every frame (sheaf_context_set_instance;
 *    rtcSetGeometryTransform + rtcCommitGeometry).
 * The object-to-world transforms are the same 12 floats for both (row-major
 * 3x4; instance ids 0, 1..TL_ANIM, then the ring, the same in both). Per
 * frame f (animation frame f mod F): update + commit (sheaf: the update,
 * the ring's set_instance, sheaf_context_commit_scene; Embree: the ANIM
 * child, the instances' commits, rtcCommitScene of the top level, LOW +
 * DYNAMIC), then ENV's camera rays (packet order as the single-scene mode)
 * traced (sheaf_context_trace_scene, TL_CFG's packets; Embree rtcIntersect8
 * or 16, whichever was faster on frame 0), then shadow rays toward ENV's
 * light traced (sheaf_context_occluded_scene, TL_CFG's shadow packets;
 * Embree's fastest of rtcOccluded8/16 on frame 0, see tl_run).
 * The shadow rays are made (untimed) from
 * sheaf's hits: the hit triangle's world vertices (its geometry's vertices
 * of this frame through its instance's transform) and shadow_ray_tri with
 * ENV's light and offset, as the renderers make them; both libraries trace
 * those same rays. Rays go to the threads in chunks as run_job hands them. */

#define TL_ANIM 4                            /* instances of ANIM */
#define TL_CFG "bvh-frustum 16x16"           /* sheaf's packets (env SHEAF_TL_CFG: another table name) */
/* The configuration the two-level mode traces with: SHEAF_TL_CFG, else TL_CFG. */
static const char *tl_cfg(void) { return getenv("SHEAF_TL_CFG") ? getenv("SHEAF_TL_CFG") : TL_CFG; }
#define TL_RING 16                           /* instances of OBJ */
#define TL_INST (1 + TL_ANIM + TL_RING)
#define TL_ANIM_SIZE 0.15f                   /* an ANIM copy's diagonal (every frame's bounds) over ENV's */
#define TL_OBJ_SIZE 0.04f                    /* an OBJ copy's diagonal over ENV's */
#define TL_RING_RADIUS 0.12f                 /* over ENV's diagonal, at most 0.6 of the eye's distance across */
#define TL_RING_HEIGHT 0.03f                 /* the ring above the ANIM copies' tops, over ENV's diagonal */
#define TL_LIFT 0.002f                       /* the ANIM copies above the focus, over ENV's diagonal */
#define TL_TURN_FRAMES 48                    /* frames per turn of the ring */
/* --check: most camera rays whose (instance, triangle) differ, and most
 * shadow rays whose occlusion differs, as a fraction of the rays. */
#define TL_MAX_DIFF_FRACTION 1e-4
#define TL_MAX_FRAMES 10000
#define TL_PI 3.14159265358979323846

enum { G_ENV, G_ANIM, G_OBJ, NGEOM }; /* geometry ids, sheaf's and the Embree child scenes' */
enum { P_UPDATE, P_CAMERA, P_SHADOW, P_FRAME, NPHASE };

typedef struct {
    const Options *o;
    Scene g[NGEOM];
    char name[NGEOM][64];
    uint32_t W, H;
    size_t N;
    int reps, frames;
    double load0, load1;
    sheaf_frame frame;
    sheaf_ray *rays; /* ENV's camera rays in packet order */
    uint32_t *pix;
    float xf[TL_INST][12]; /* the instances' transforms now */
    V3 look, up, e1, e2;   /* the focus; up, the view's direction across up, up x e1 */
    V3 obj_center;
    float obj_scale, ring_radius, ring_height;
    sheaf_context *ctx;
    sheaf_scene_hit *hits; /* sheaf's camera hits */
    sheaf_ray *srays;      /* shadow rays, one slot per camera ray */
    size_t ns;             /* active shadow rays of the frame */
    uint8_t *socc, *eocc;
    uint32_t *eprim, *einst;
    float *et;
    uint64_t scene_tris;   /* instanced triangles */
    uint64_t sheaf_tris;   /* of those, the ones sheaf traces (sheaf_scene_info.instanced_triangles) */
    double sheaf_setup_ms, embree_setup_ms[4];
    /* Agreement over every frame of the first thread count's first run. */
    size_t a_rays, a_differ, a_hits_s, a_hits_e, a_srays, a_sdiffer, a_occ_s, a_occ_e;
    double ms[4][2][NPHASE]; /* [thread count][sheaf, Embree][phase]: median over frames x runs */
    double mr[4][2];         /* Mrays/s: (camera + active shadow rays) / (camera + shadow time), median */
    int pw[4], sw[4];        /* Embree's queries (tl_run's candidates) */
    char equery[4][96];      /* their names */
} TwoLevel;

typedef struct {
    RTCDevice dev;
    EScene child[NGEOM];
    RTCScene top;
    RTCGeometry inst[TL_INST];
} TLEmbree;

/* --filter: ANIM's triangles are alpha-tested, a cut-out of each candidate's
 * (u, v) cells shifted by its triangle (a pure function of the candidate),
 * through sheaf_filter_fn in sheaf and the intersection and occlusion filter
 * functions of ANIM's geometry in Embree; u and v weigh the second and third
 * vertex in both. */
static int tl_keep(float u, float v, uint32_t prim)
{
    return ((uint32_t)(u * 6.0f) + (uint32_t)(v * 6.0f) + prim) % 3u != 0u;
}

static bool tl_sheaf_cutout(void *user, const sheaf_candidate *c)
{
    (void)user;
    return tl_keep(c->u, c->v, c->prim);
}

/* RTCHitN is N-wide structure of arrays (Ng_x, Ng_y, Ng_z, u, v, primID,
 * ...); its accessors RTCHitN_u etc. exist in C++ only. */
static void tl_embree_cutout(const struct RTCFilterFunctionNArguments *a)
{
    const float *f = (const float *)a->hit;
    const unsigned *id = (const unsigned *)a->hit;
    unsigned n = a->N;
    for (unsigned i = 0; i < n; i++) {
        if (a->valid[i] != -1) continue;
        if (!tl_keep(f[3 * n + i], f[4 * n + i], id[5 * n + i]))
            a->valid[i] = 0;
    }
}

static int tl_geom_of(uint32_t inst) { return inst == 0 ? G_ENV : inst <= TL_ANIM ? G_ANIM : G_OBJ; }

/* Geometry g's vertices in frame f (ANIM: animation frame f mod F). */
static const float *tl_verts(const TwoLevel *b, int g, uint32_t f)
{
    const Scene *s = &b->g[g];
    return g == G_ANIM ? s->frames + 3 * (size_t)s->nv * (f % s->nframes) : s->verts;
}

static void grow_bounds(const float *v, uint32_t nv, float mn[3], float mx[3])
{
    for (size_t i = 0; i < nv; i++)
        for (int k = 0; k < 3; k++) {
            float x = v[3 * i + k];
            if (x < mn[k]) mn[k] = x;
            if (x > mx[k]) mx[k] = x;
        }
}

static float diagonal(const float mn[3], const float mx[3])
{
    V3 d = {mx[0] - mn[0], mx[1] - mn[1], mx[2] - mn[2]};
    return length(d);
}

/* m (row-major 3x4) applied to the point p. */
static V3 xform_point(const float m[12], const float *p)
{
    V3 r = {m[0] * p[0] + m[1] * p[1] + m[2] * p[2] + m[3], m[4] * p[0] + m[5] * p[1] + m[6] * p[2] + m[7],
            m[8] * p[0] + m[9] * p[1] + m[10] * p[2] + m[11]};
    return r;
}

/* Object-to-world (row-major 3x4): the object's x, y, z axes to e1, e2 and
 * up (right-handed), turned by `a` about up, scaled by `sc`, the object
 * point c at `target`. */
static void tl_place(const TwoLevel *b, float m[12], float sc, float a, V3 c, V3 target)
{
    float ca = cosf(a), sa = sinf(a);
    V3 col[3] = {add(mul(b->e1, ca), mul(b->e2, sa)), add(mul(b->e1, -sa), mul(b->e2, ca)), b->up};
    float t[3] = {target.x, target.y, target.z};
    for (int r = 0; r < 3; r++) {
        for (int k = 0; k < 3; k++) {
            V3 v = col[k];
            m[4 * r + k] = sc * (r == 0 ? v.x : r == 1 ? v.y : v.z);
        }
        m[4 * r + 3] = t[r] - (m[4 * r] * c.x + m[4 * r + 1] * c.y + m[4 * r + 2] * c.z);
    }
}

/* The ring's transforms in frame f: OBJ copy k at angle 2 pi (k / TL_RING +
 * f / TL_TURN_FRAMES) around look_at, turned about up by twice that. */
static void tl_ring(TwoLevel *b, uint32_t f)
{
    for (int k = 0; k < TL_RING; k++) {
        double a = 2.0 * TL_PI * ((double)k / TL_RING + (double)(f % TL_TURN_FRAMES) / TL_TURN_FRAMES);
        V3 target = add(add(b->look, mul(b->up, b->ring_height)),
                        add(mul(b->e1, b->ring_radius * (float)cos(a)), mul(b->e2, b->ring_radius * (float)sin(a))));
        tl_place(b, b->xf[1 + TL_ANIM + k], b->obj_scale, (float)(2.0 * a), b->obj_center, target);
    }
}

static sheaf_mesh tl_mesh(const TwoLevel *b, int g, uint32_t f)
{
    sheaf_mesh m;
    m.vertices = tl_verts(b, g, f);
    m.vertex_stride_bytes = 3 * sizeof(float);
    m.vertex_count = b->g[g].nv;
    m.indices = b->g[g].idx;
    m.triangle_count = b->g[g].nt;
    return m;
}

/* Read the scenes, place the instances, make the camera rays, set up sheaf's scene. */
static void tl_setup(TwoLevel *b)
{
    const Options *o = b->o;
    for (int g = 0; g < NGEOM; g++) {
        read_scene(o->twolevel[g], &b->g[g]);
        short_name(b->g[g].label, b->name[g], sizeof b->name[g]);
    }
    Scene *env = &b->g[G_ENV], *anim = &b->g[G_ANIM], *obj = &b->g[G_OBJ];
    if (anim->nframes == 0)
        die("%s: no animation frames (export it with `sheaf export builtin:animated --frames 48`)", o->twolevel[1]);
    b->W = o->width ? o->width : env->width;
    b->H = o->height ? o->height : env->height;
    if (b->W % 32 || b->H % 32 || b->W == 0 || b->H == 0)
        die("%s: image %ux%u: width and height must be multiples of 32 (32x32 tiles)", b->name[G_ENV], b->W, b->H);
    b->N = (size_t)b->W * b->H;
    b->reps = o->reps;
    b->frames = o->frames;
    b->load0 = load_average();
    camera_rays(env, b->W, b->H, &b->frame, &b->rays, &b->pix);

    /* The bounds: sizes are relative to ENV's bounding-box diagonal D. */
    float emn[3] = {INFINITY, INFINITY, INFINITY}, emx[3] = {-INFINITY, -INFINITY, -INFINITY};
    float amn[3] = {INFINITY, INFINITY, INFINITY}, amx[3] = {-INFINITY, -INFINITY, -INFINITY};
    float omn[3] = {INFINITY, INFINITY, INFINITY}, omx[3] = {-INFINITY, -INFINITY, -INFINITY};
    grow_bounds(env->verts, env->nv, emn, emx);
    for (uint32_t f = 0; f < anim->nframes; f++) grow_bounds(tl_verts(b, G_ANIM, f), anim->nv, amn, amx);
    grow_bounds(obj->verts, obj->nv, omn, omx);
    float D = diagonal(emn, emx), Da = diagonal(amn, amx), Do = diagonal(omn, omx);
    if (!(D > 0.0f) || !(Da > 0.0f) || !(Do > 0.0f) || !isfinite(D) || !isfinite(Da) || !isfinite(Do))
        die("--twolevel: a scene with empty or non-finite bounds");
    b->scene_tris = (uint64_t)env->nt + (uint64_t)TL_ANIM * anim->nt + (uint64_t)TL_RING * obj->nt;
    progress("== two-level scene: %s (%u triangles) + %s (%u) x %d + %s (%u) x %d = %llu triangles, %ux%u, %s\n",
             b->name[G_ENV], env->nt, b->name[G_ANIM], anim->nt, TL_ANIM, b->name[G_OBJ], obj->nt, TL_RING,
             (unsigned long long)b->scene_tris, b->W, b->H, env->view);

    /* sheaf: one context, the three geometries; ENV's instance first. */
    int maxT = 1;
    for (int ti = 0; ti < o->nthreads; ti++) if (o->threads[ti] > maxT) maxT = o->threads[ti];
    sheaf_limits lim;
    check_sheaf(NULL, sheaf_limits_default(16, &lim), "limits"); /* the single-mesh pools stay unused */
    lim.structures = SHEAF_STRUCTURE_BVH;
    lim.max_threads = (uint32_t)maxT;
    lim.max_geometries = NGEOM;
    lim.max_instances = TL_INST;
    lim.max_scene_triangles = env->nt + anim->nt + obj->nt;
    check_sheaf(NULL, sheaf_context_create(&lim, &b->ctx), "sheaf_context_create");
    double t0 = now_s();
    sheaf_geometry_params gp;
    check_sheaf(NULL, sheaf_geometry_params_default(&gp), "geometry_params_default"); /* STATIC, binned SAH */
    for (int g = 0; g < NGEOM; g++) {
        sheaf_mesh m = tl_mesh(b, g, 0);
        gp.mode = g == G_ANIM ? SHEAF_UPDATE_MODE_REFIT : SHEAF_UPDATE_MODE_STATIC;
        check_sheaf(b->ctx, sheaf_context_set_scene_geometry(b->ctx, (uint32_t)g, &m, &gp), "set_scene_geometry");
    }
    double t_geom = now_s() - t0;
    static const float ID[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    memcpy(b->xf[0], ID, sizeof ID);
    check_sheaf(b->ctx, sheaf_context_set_instance(b->ctx, 0, G_ENV, b->xf[0], ~0u), "set_instance");
    check_sheaf(b->ctx, sheaf_context_commit_scene(b->ctx, NULL), "commit_scene");

    /* The focus: where the view's centre pixel meets ENV when that is
     * before look_at (a view into a crowd of objects), else look_at; then
     * dropped along -up onto ENV's surface below it (a floor) when there is
     * one within D / 2. The basis: up, e1 the view direction across up,
     * e2 = up x e1. */
    b->look = v3(env->look_at);
    b->up = normalize_or_zero(v3(env->up));
    {
        sheaf_ray cr;
        sheaf_scene_hit ch;
        check_sheaf(NULL, sheaf_frame_camera_ray(&b->frame, b->W / 2, b->H / 2, &cr), "camera ray");
        check_sheaf(b->ctx, sheaf_context_trace_scene(b->ctx, NULL, &cr, &ch, 1, ~0u, 0), "trace_scene");
        V3 d = v3(cr.dir), org = v3(cr.org);
        float t_look = dot(sub(b->look, org), d) / dot(d, d);
        if (ch.prim != SHEAF_INVALID_ID && ch.t < t_look)
            b->look = add(org, mul(d, ch.t));
        V3 start = add(b->look, mul(b->up, 1e-3f * D)), down = mul(b->up, -1.0f);
        memcpy(cr.org, &start, sizeof cr.org);
        memcpy(cr.dir, &down, sizeof cr.dir);
        cr.tmin = 0.0f;
        cr.tmax = 0.5f * D;
        check_sheaf(b->ctx, sheaf_context_trace_scene(b->ctx, NULL, &cr, &ch, 1, ~0u, 0), "trace_scene");
        if (ch.prim != SHEAF_INVALID_ID)
            b->look = add(start, mul(down, ch.t));
    }
    V3 view = sub(b->look, v3(env->eye));
    V3 across = sub(view, mul(b->up, dot(view, b->up)));
    b->e1 = normalize_or_zero(across);
    if (length(b->e1) == 0.0f) {
        V3 x = {1, 0, 0}, y = {0, 1, 0};
        b->e1 = normalize_or_zero(cross(b->up, fabsf(b->up.x) < 0.9f ? x : y));
    }
    b->e2 = cross(b->up, b->e1);
    /* ANIM (its z axis up): 2 x 2 copies side by side on the focus, a gap
     * of 12% of a copy's width between them (their ground planes never
     * overlap), TL_LIFT above it (never coplanar with ENV's surface there),
     * turned by quarter turns. */
    float sa = TL_ANIM_SIZE * D / Da;
    float ext = sa * fmaxf(amx[0] - amn[0], amx[1] - amn[1]), ah = sa * (amx[2] - amn[2]);
    V3 ac = {0.5f * (amn[0] + amx[0]), 0.5f * (amn[1] + amx[1]), 0.5f * (amn[2] + amx[2])};
    V3 base = add(b->look, mul(b->up, TL_LIFT * D + 0.5f * ah));
    for (int k = 0; k < TL_ANIM; k++) {
        float sx = (k & 1) ? 0.56f : -0.56f, sy = (k & 2) ? 0.56f : -0.56f;
        V3 target = add(base, add(mul(b->e1, sx * ext), mul(b->e2, sy * ext)));
        tl_place(b, b->xf[1 + k], sa, (float)(0.5 * TL_PI * k), ac, target);
    }
    /* OBJ: a ring around the focus, above the ANIM copies; its radius at
     * most 0.6 of the eye's distance across, so the camera stays outside. */
    b->obj_scale = TL_OBJ_SIZE * D / Do;
    V3 oc = {0.5f * (omn[0] + omx[0]), 0.5f * (omn[1] + omx[1]), 0.5f * (omn[2] + omx[2])};
    b->obj_center = oc;
    b->ring_radius = fminf(TL_RING_RADIUS * D, 0.6f * length(across));
    b->ring_height = TL_LIFT * D + ah + TL_RING_HEIGHT * D;
    tl_ring(b, 0);

    /* The other instances, and the commit. */
    if (b->o->filter)
        check_sheaf(b->ctx, sheaf_context_set_scene_geometry_filter(b->ctx, G_ANIM, tl_sheaf_cutout, NULL),
                    "set_scene_geometry_filter");
    t0 = now_s();
    for (uint32_t i = 1; i < TL_INST; i++)
        check_sheaf(b->ctx, sheaf_context_set_instance(b->ctx, i, (uint32_t)tl_geom_of(i), b->xf[i], ~0u), "set_instance");
    sheaf_scene_info si;
    check_sheaf(b->ctx, sheaf_context_commit_scene(b->ctx, &si), "commit_scene");
    b->sheaf_setup_ms = 1e3 * (t_geom + now_s() - t0);
    if (si.instances != TL_INST || si.instanced_triangles > b->scene_tris)
        die("sheaf's committed scene: %llu triangles in %u instances, expected up to %llu in %d",
            (unsigned long long)si.instanced_triangles, si.instances, (unsigned long long)b->scene_tris, TL_INST);
    b->sheaf_tris = si.instanced_triangles; /* without the triangles sheaf excludes (zero area, non-finite) */
    progress("  focus (%.4g %.4g %.4g), ANIM copies %.4g wide, ring radius %.4g; world bounds (%.4g %.4g %.4g) - "
             "(%.4g %.4g %.4g)\n", b->look.x, b->look.y, b->look.z, ext, b->ring_radius, si.bounds_min[0],
             si.bounds_min[1], si.bounds_min[2], si.bounds_max[0], si.bounds_max[1], si.bounds_max[2]);
    progress("  sheaf: 3 geometries built and the scene committed in %.1f ms (calling thread)\n", b->sheaf_setup_ms);
    b->hits = xmalloc(b->N * sizeof *b->hits);
    b->srays = xmalloc(b->N * sizeof *b->srays);
    b->socc = xmalloc(b->N);
    b->eocc = xmalloc(b->N);
    b->eprim = xmalloc(b->N * sizeof *b->eprim);
    b->einst = xmalloc(b->N * sizeof *b->einst);
    b->et = xmalloc(b->N * sizeof *b->et);
}

/* Embree on "threads=T": the three child scenes, the top level with the
 * instances (ring and ANIM at frame 0); seconds to the first top commit. */
static double tl_embree_setup(TwoLevel *b, int T, TLEmbree *e)
{
    char cfg[64];
    embree_cfg(cfg, sizeof cfg, T);
    e->dev = rtcNewDevice(cfg);
    if (!e->dev)
        die("rtcNewDevice(\"%s\") failed (error %d)", cfg, (int)rtcGetDeviceError(NULL));
    rtcSetDeviceErrorFunction(e->dev, embree_error, NULL);
    Scene *anim = &b->g[G_ANIM];
    memcpy(anim->verts, tl_verts(b, G_ANIM, 0), 12 * (size_t)anim->nv);
    double t0 = now_s();
    embree_build(e->dev, &b->g[G_ENV], 1, &e->child[G_ENV]);        /* MEDIUM */
    embree_build(e->dev, anim, Q_REFIT, &e->child[G_ANIM]);         /* LOW + DYNAMIC, geometry REFIT */
    if (b->o->filter) {
        rtcSetGeometryIntersectFilterFunction(e->child[G_ANIM].geom, tl_embree_cutout);
        rtcSetGeometryOccludedFilterFunction(e->child[G_ANIM].geom, tl_embree_cutout);
        rtcCommitGeometry(e->child[G_ANIM].geom);
        rtcCommitScene(e->child[G_ANIM].scene);
    }
    embree_build(e->dev, &b->g[G_OBJ], 1, &e->child[G_OBJ]);        /* MEDIUM */
    e->top = rtcNewScene(e->dev);
    rtcSetSceneFlags(e->top, RTC_SCENE_FLAG_DYNAMIC);
    rtcSetSceneBuildQuality(e->top, RTC_BUILD_QUALITY_LOW);
    for (uint32_t i = 0; i < TL_INST; i++) {
        RTCGeometry g = rtcNewGeometry(e->dev, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(g, e->child[tl_geom_of(i)].scene);
        rtcSetGeometryTimeStepCount(g, 1);
        rtcSetGeometryTransform(g, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, b->xf[i]);
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(e->top, g, i);
        e->inst[i] = g;
    }
    rtcCommitScene(e->top);
    double t = now_s() - t0;
    if (rtcGetDeviceError(e->dev) != RTC_ERROR_NONE)
        die("Embree two-level build failed");
    return t;
}

static void tl_embree_release(TLEmbree *e)
{
    for (int i = 0; i < TL_INST; i++) rtcReleaseGeometry(e->inst[i]);
    rtcReleaseScene(e->top);
    for (int g = 0; g < NGEOM; g++) embree_release(&e->child[g]);
    rtcReleaseDevice(e->dev);
}

/* sheaf's update + commit of frame f (the ring's transforms in b->xf); seconds. */
static double tl_sheaf_update(TwoLevel *b, uint32_t f)
{
    sheaf_mesh m = tl_mesh(b, G_ANIM, f);
    double t0 = now_s();
    check_sheaf(b->ctx, sheaf_context_update_scene_geometry(b->ctx, G_ANIM, &m, NULL), "update_scene_geometry");
    for (uint32_t i = 1 + TL_ANIM; i < TL_INST; i++)
        check_sheaf(b->ctx, sheaf_context_set_instance(b->ctx, i, G_OBJ, b->xf[i], ~0u), "set_instance");
    check_sheaf(b->ctx, sheaf_context_commit_scene(b->ctx, NULL), "commit_scene");
    return now_s() - t0;
}

/* Embree's update + commit of frame f: ANIM's vertices into its shared
 * buffer and its child scene committed (a refit), its instances committed
 * (their child changed), the ring's new transforms, the top level; seconds. */
static double tl_embree_update(TwoLevel *b, TLEmbree *e, uint32_t f)
{
    Scene *anim = &b->g[G_ANIM];
    double t0 = now_s();
    memcpy(anim->verts, tl_verts(b, G_ANIM, f), 12 * (size_t)anim->nv);
    embree_rebuild(&e->child[G_ANIM]);
    for (uint32_t i = 1; i <= TL_ANIM; i++) rtcCommitGeometry(e->inst[i]);
    for (uint32_t i = 1 + TL_ANIM; i < TL_INST; i++) {
        rtcSetGeometryTransform(e->inst[i], 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, b->xf[i]);
        rtcCommitGeometry(e->inst[i]);
    }
    rtcCommitScene(e->top);
    double t = now_s() - t0;
    if (rtcGetDeviceError(e->dev) != RTC_ERROR_NONE)
        die("Embree two-level update failed");
    return t;
}

/* The shadow rays of sheaf's camera hits in frame f, one slot per camera
 * ray (inactive for misses and unlit points): the hit triangle's world
 * vertices (frame f's vertices through its instance's transform) and
 * shadow_ray_tri toward ENV's light with ENV's offset. */
static void tl_shadow_rays(TwoLevel *b, uint32_t f)
{
    const Scene *env = &b->g[G_ENV];
    size_t ns = 0;
    for (size_t k = 0; k < b->N; k++) {
        const sheaf_scene_hit *h = &b->hits[k];
        if (h->prim != SHEAF_INVALID_ID) {
            if (h->geometry >= NGEOM || h->instance >= TL_INST || (int)h->geometry != tl_geom_of(h->instance) ||
                h->prim >= b->g[h->geometry].nt)
                die("sheaf scene hit %zu: geometry %u, instance %u, triangle %u out of range", k, h->geometry,
                    h->instance, h->prim);
            const float *v = tl_verts(b, (int)h->geometry, f), *m = b->xf[h->instance];
            const uint32_t *ix = b->g[h->geometry].idx + 3 * (size_t)h->prim;
            if (shadow_ray_tri(xform_point(m, v + 3 * (size_t)ix[0]), xform_point(m, v + 3 * (size_t)ix[1]),
                               xform_point(m, v + 3 * (size_t)ix[2]), env->light, env->eps, &b->rays[k], h->t,
                               &b->srays[k])) {
                ns++;
                continue;
            }
        }
        inactive_ray(env, &b->srays[k]);
    }
    b->ns = ns;
}

/* Count this frame's disagreements: camera rays whose (instance, triangle)
 * differ (Embree's instID[0] is the instance id, its primID the triangle in
 * the instance's geometry), shadow rays whose occlusion differs. */
static void tl_agree(TwoLevel *b)
{
    for (size_t k = 0; k < b->N; k++) {
        const sheaf_scene_hit *h = &b->hits[k];
        b->a_hits_s += h->prim != SHEAF_INVALID_ID;
        b->a_hits_e += b->eprim[k] != SHEAF_INVALID_ID;
        b->a_differ += h->prim != b->eprim[k] || (h->prim != SHEAF_INVALID_ID && h->instance != b->einst[k]);
        b->a_srays += is_active(&b->srays[k]);
        b->a_occ_s += b->socc[k];
        b->a_occ_e += b->eocc[k];
        b->a_sdiffer += b->socc[k] != b->eocc[k];
    }
    b->a_rays += b->N;
}

/* Frame 0 as sheaf traced it (sc: the camera job, ss: the shadow job), a
 * binary PPM: a colour per geometry, shaded by the facing ratio, darker in
 * shadow, misses blue. */
static void tl_write_ppm(TwoLevel *b, const char *path)
{
    static const float COLOUR[NGEOM][3] = {{0.8f, 0.8f, 0.75f}, {0.9f, 0.3f, 0.2f}, {0.25f, 0.85f, 0.3f}};
    unsigned char *img = xmalloc(3 * b->N);
    for (size_t k = 0; k < b->N; k++) {
        unsigned char *o = img + 3 * (size_t)b->pix[k];
        const sheaf_scene_hit *h = &b->hits[k];
        if (h->prim == SHEAF_INVALID_ID) {
            o[0] = 90, o[1] = 120, o[2] = 170;
            continue;
        }
        const float *v = tl_verts(b, (int)h->geometry, 0), *m = b->xf[h->instance];
        const uint32_t *ix = b->g[h->geometry].idx + 3 * (size_t)h->prim;
        V3 p0 = xform_point(m, v + 3 * (size_t)ix[0]), p1 = xform_point(m, v + 3 * (size_t)ix[1]);
        V3 p2 = xform_point(m, v + 3 * (size_t)ix[2]);
        V3 n = normalize_or_zero(cross(sub(p1, p0), sub(p2, p0)));
        float c = fabsf(dot(n, normalize_or_zero(v3(b->rays[k].dir))));
        float lit = is_active(&b->srays[k]) && !b->socc[k] ? 1.0f : 0.4f;
        for (int a = 0; a < 3; a++) o[a] = (unsigned char)(255.0f * COLOUR[h->geometry][a] * (0.3f + 0.7f * c) * lit);
    }
    FILE *f = fopen(path, "wb");
    if (!f)
        die("cannot write %s: %s", path, strerror(errno));
    fprintf(f, "P6\n%u %u\n255\n", b->W, b->H);
    if (fwrite(img, 1, 3 * b->N, f) != 3 * b->N || fclose(f) != 0)
        die("cannot write %s", path);
    free(img);
    progress("  frame 0 as sheaf traced it: %s\n", path);
}

/* The frame loop on thread count index ti. */
static void tl_run(TwoLevel *b, int ti)
{
    int T = b->o->threads[ti];
    TLEmbree e;
    tl_ring(b, 0);
    tl_sheaf_update(b, 0);
    b->embree_setup_ms[ti] = 1e3 * tl_embree_setup(b, T, &e);
    progress("  Embree on %d thread%s: child scenes and top level committed in %.1f ms\n", T, T > 1 ? "s" : "",
             b->embree_setup_ms[ti]);

    const Cfg *cfg = NULL;
    for (size_t c = 0; c < N_PRIMARY_CFGS; c++)
        if (!strcmp(PRIMARY_CFGS[c].name, tl_cfg())) cfg = &PRIMARY_CFGS[c];
    if (!cfg) die("no %s configuration", tl_cfg());
    Job sc, ss, ec, es;
    memset(&sc, 0, sizeof sc);
    sc.lib = LIB_SHEAF;
    sc.kind = K_SCENE_TRACE;
    sc.ctx = b->ctx;
    sc.s = &b->g[G_ENV];
    sc.params = cfg_params(cfg, SHEAF_RAY_KIND_PRIMARY);
    sc.rays = b->rays;
    sc.n = b->N;
    sc.shits = b->hits;
    ss = sc;
    ss.kind = K_SCENE_OCC;
    ss.params = cfg_params(cfg, SHEAF_RAY_KIND_SHADOW);
    ss.rays = b->srays;
    ss.occ = b->socc;
    memset(&ec, 0, sizeof ec);
    ec.lib = LIB_EMBREE;
    ec.kind = K_TRACE;
    ec.s = &b->g[G_ENV];
    ec.scene = e.top;
    ec.rays = b->rays;
    ec.n = b->N;
    ec.prim = b->eprim;
    ec.inst = b->einst;
    ec.t = b->et;
    es = ec;
    es.kind = K_OCCLUDED;
    es.rays = b->srays;
    es.occ = b->eocc;

    /* Frame 0, untimed: warm-up, and Embree's fastest query of each kind
     * (median of the runs): camera rays 8 or 16 wide with the COHERENT
     * context flag (Embree's advice for camera rays); shadow rays 8 wide
     * COHERENT, or 8 or 16 wide INCOHERENT (its default and its advice for
     * secondary rays). Not rtcOccluded16 with COHERENT: Embree 3.13.5's
     * AVX-512 kernel never returns on some of these scenes (it depends on
     * where its BVH nodes lie in memory; INCOHERENT, or AVX2, return). */
    run_job(&sc, T);
    tl_shadow_rays(b, 0);
    run_job(&ss, T);
    if (ti == 0 && b->o->ppm)
        tl_write_ppm(b, b->o->ppm);
    static const int CAM[2][2] = {{8, 0}, {16, 0}}, SHD[3][2] = {{8, 0}, {8, 1}, {16, 1}};
    double bc = INFINITY, bs = INFINITY;
    for (int c = 0; c < 2; c++) {
        ec.width = CAM[c][0];
        ec.incoherent = CAM[c][1];
        double t = time_job(&ec, T, b->reps);
        progress("  Embree frame 0, %d threads: rtcIntersect%d %s %.2f ms\n", T, ec.width,
                 ec.incoherent ? "INCOHERENT" : "COHERENT", 1e3 * t);
        if (t < bc) bc = t, b->pw[ti] = c;
    }
    for (int c = 0; c < 3; c++) {
        es.width = SHD[c][0];
        es.incoherent = SHD[c][1];
        double t = time_job(&es, T, b->reps);
        progress("  Embree frame 0, %d threads: rtcOccluded%d %s %.2f ms\n", T, es.width,
                 es.incoherent ? "INCOHERENT" : "COHERENT", 1e3 * t);
        if (t < bs) bs = t, b->sw[ti] = c;
    }
    ec.width = CAM[b->pw[ti]][0];
    ec.incoherent = CAM[b->pw[ti]][1];
    es.width = SHD[b->sw[ti]][0];
    es.incoherent = SHD[b->sw[ti]][1];
    snprintf(b->equery[ti], sizeof b->equery[ti], "rtcIntersect%d %s, rtcOccluded%d %s", ec.width,
             ec.incoherent ? "INCOHERENT" : "COHERENT", es.width, es.incoherent ? "INCOHERENT" : "COHERENT");

    int n = b->reps * b->frames;
    double *t[2][NPHASE], *mr[2];
    for (int l = 0; l < 2; l++) {
        for (int p = 0; p < NPHASE; p++) t[l][p] = xmalloc((size_t)n * sizeof(double));
        mr[l] = xmalloc((size_t)n * sizeof(double));
    }
    for (int r = 0; r < b->reps; r++)
        for (int f = 0; f < b->frames; f++) {
            int i = r * b->frames + f;
            tl_ring(b, (uint32_t)f); /* the application's work: untimed */
            t[0][P_UPDATE][i] = tl_sheaf_update(b, (uint32_t)f);
            t[0][P_CAMERA][i] = run_job(&sc, T);
            tl_shadow_rays(b, (uint32_t)f); /* untimed: the same rays for both */
            t[0][P_SHADOW][i] = run_job(&ss, T);
            t[1][P_UPDATE][i] = tl_embree_update(b, &e, (uint32_t)f);
            t[1][P_CAMERA][i] = run_job(&ec, T);
            t[1][P_SHADOW][i] = run_job(&es, T);
            for (int l = 0; l < 2; l++) {
                t[l][P_FRAME][i] = t[l][P_UPDATE][i] + t[l][P_CAMERA][i] + t[l][P_SHADOW][i];
                mr[l][i] = mrays(b->N + b->ns, t[l][P_CAMERA][i] + t[l][P_SHADOW][i]);
            }
            if (ti == 0 && r == 0)
                tl_agree(b);
        }
    for (int l = 0; l < 2; l++) {
        for (int p = 0; p < NPHASE; p++) {
            b->ms[ti][l][p] = 1e3 * median(t[l][p], n);
            free(t[l][p]);
        }
        b->mr[ti][l] = median(mr[l], n);
        free(mr[l]);
    }
    progress("  two-level frame, %d thread%s: sheaf %.2f ms, Embree %.2f ms (ratio %.2f)\n", T, T > 1 ? "s" : "",
             b->ms[ti][0][P_FRAME], b->ms[ti][1][P_FRAME], b->ms[ti][0][P_FRAME] / b->ms[ti][1][P_FRAME]);
    tl_embree_release(&e);
}

static double pct(size_t a, size_t n) { return n ? 100.0 * (double)a / (double)n : 0.0; }

static void tl_report(TwoLevel *b)
{
    const Options *o = b->o;
    const Scene *env = &b->g[G_ENV], *anim = &b->g[G_ANIM], *obj = &b->g[G_OBJ];
    size_t na = (size_t)TL_ANIM * anim->nt, no = (size_t)TL_RING * obj->nt;
    printf("\n### Two-level scene: %s + %s x %d + %s x %d%s\n\n", b->name[G_ENV], b->name[G_ANIM], TL_ANIM,
           b->name[G_OBJ], TL_RING, o->filter ? ", anim alpha-tested by any-hit filters" : "");
    if (o->filter)
        printf("Filtered (--filter): anim's triangles are cut out by a pure function of each candidate's (u, v) "
               "and triangle (a third of each triangle's area), in sheaf by sheaf_filter_fn on the geometry "
               "(sheaf_context_set_scene_geometry_filter), in Embree by rtcSetGeometryIntersectFilterFunction and "
               "rtcSetGeometryOccludedFilterFunction on anim's geometry, called for the candidates each library "
               "would accept.\n\n");
    printf("Triangles: env %u (%s, one instance, static); anim %u x %d = %zu (%s, refit: its vertices move every "
           "frame); obj %u x %d = %zu (%s, static, its %d instances turn every frame); %llu in all, of which "
           "%.1f%% move per frame (%.1f%% deformed, %.1f%% moved by their instance's transform); sheaf traces %llu of them (it leaves out zero-area and non-finite "
           "triangles).\n\n",
           env->nt, b->name[G_ENV], anim->nt, TL_ANIM, na, b->name[G_ANIM], obj->nt, TL_RING, no, b->name[G_OBJ],
           TL_RING, (unsigned long long)b->scene_tris, pct(na + no, b->scene_tris), pct(na, b->scene_tris),
           pct(no, b->scene_tris), (unsigned long long)b->sheaf_tris);
    printf("%ux%u camera rays of %s's view (%s) and one shadow-ray slot each toward its light; %d frames "
           "(animation frame f mod %u, the ring turning 1/%d turn per frame), each library's median frame over "
           "%d frames x %d runs; load average %.2f before, %.2f after. sheaf: a BVH per geometry (env and obj "
           "STATIC, anim REFIT; binned SAH), sheaf_context_trace_scene / sheaf_context_occluded_scene with "
           "%s packets (camera / shadow kind). Embree: env and obj child scenes at "
           "RTC_BUILD_QUALITY_MEDIUM (committed once), the anim child LOW + DYNAMIC with its geometry at "
           "RTC_BUILD_QUALITY_REFIT, the top level LOW + DYNAMIC; its fastest query width and context flag on frame 0 "
           "(camera: 8 or 16 wide, COHERENT; shadows: 8 wide COHERENT, 8 or 16 wide INCOHERENT). Update + commit: "
           "sheaf_context_update_scene_geometry + %d set_instance + commit_scene; Embree: the vertices copied into "
           "the shared buffer, rtcUpdateGeometryBuffer + commits of the anim child, %d instance commits (%d with "
           "new transforms), rtcCommitScene of the top. The shadow rays are made from sheaf's camera hits "
           "(untimed) and traced by both. Ratios are sheaf / Embree: below 1 sheaf is faster for times, above 1 "
           "for Mrays/s ((camera + shadow rays) / (camera + shadow time)).\n\n",
           b->W, b->H, b->name[G_ENV], env->view, b->frames, anim->nframes, TL_TURN_FRAMES, b->frames, b->reps,
           b->load0, b->load1, tl_cfg(), TL_RING,
           TL_ANIM + TL_RING, TL_RING);
    for (int ti = 0; ti < o->nthreads; ti++) {
        int T = o->threads[ti];
        printf("**%d thread%s** (Embree: %s):\n\n", T, T > 1 ? "s" : "", b->equery[ti]);
        printf("| | update + commit ms | camera ms | shadow ms | frame ms | Mrays/s |\n|---|--:|--:|--:|--:|--:|\n");
        for (int l = 0; l < 2; l++)
            printf("| %s | %.2f | %.2f | %.2f | %.2f | %.2f |\n", l ? "Embree" : "sheaf", b->ms[ti][l][P_UPDATE],
                   b->ms[ti][l][P_CAMERA], b->ms[ti][l][P_SHADOW], b->ms[ti][l][P_FRAME], b->mr[ti][l]);
        printf("| **sheaf / Embree** | %.2f | %.2f | %.2f | **%.2f** | %.2f |\n\n",
               b->ms[ti][0][P_UPDATE] / b->ms[ti][1][P_UPDATE], b->ms[ti][0][P_CAMERA] / b->ms[ti][1][P_CAMERA],
               b->ms[ti][0][P_SHADOW] / b->ms[ti][1][P_SHADOW], b->ms[ti][0][P_FRAME] / b->ms[ti][1][P_FRAME],
               b->mr[ti][0] / b->mr[ti][1]);
    }
    printf("Agreement over the %d frames of the first run on %d thread%s: camera rays whose (instance, triangle) "
           "differ: %zu of %zu (%.4f%%; hits sheaf %zu, Embree %zu); shadow rays whose occlusion differs: %zu of "
           "%zu (%.4f%%; occluded sheaf %zu, Embree %zu).\n\n",
           b->frames, o->threads[0], o->threads[0] > 1 ? "s" : "", b->a_differ, b->a_rays, pct(b->a_differ, b->a_rays),
           b->a_hits_s, b->a_hits_e, b->a_sdiffer, b->a_srays, pct(b->a_sdiffer, b->a_srays), b->a_occ_s, b->a_occ_e);
    printf("First builds (not in the frames): sheaf %.1f ms (three geometries and the first commit, calling thread); "
           "Embree", b->sheaf_setup_ms);
    for (int ti = 0; ti < o->nthreads; ti++)
        printf("%s %.1f ms (%d thread%s)", ti ? "," : "", b->embree_setup_ms[ti], o->threads[ti], o->threads[ti] > 1 ? "s" : "");
    printf(" (three child scenes and the top level).\n");
    fflush(stdout);

    summary("twolevel", "triangles", (double)b->scene_tris);
    summary("twolevel", "moving_fraction", (double)(na + no) / (double)b->scene_tris);
    summary("twolevel", "camera_rays", (double)b->a_rays);
    summary("twolevel", "camera_differ", (double)b->a_differ);
    summary("twolevel", "shadow_rays", (double)b->a_srays);
    summary("twolevel", "shadow_differ", (double)b->a_sdiffer);
    for (int ti = 0; ti < o->nthreads; ti++) {
        static const char *PH[NPHASE] = {"update", "camera", "shadow", "frame"};
        char k[64];
        for (int p = 0; p < NPHASE; p++) {
            snprintf(k, sizeof k, "T%d.%s_ratio", o->threads[ti], PH[p]);
            summary("twolevel", k, b->ms[ti][0][p] / b->ms[ti][1][p]);
            snprintf(k, sizeof k, "T%d.sheaf_%s_ms", o->threads[ti], PH[p]);
            summary("twolevel", k, b->ms[ti][0][p]);
            snprintf(k, sizeof k, "T%d.embree_%s_ms", o->threads[ti], PH[p]);
            summary("twolevel", k, b->ms[ti][1][p]);
        }
        snprintf(k, sizeof k, "T%d.mrays_ratio", o->threads[ti]);
        summary("twolevel", k, b->mr[ti][0] / b->mr[ti][1]);
    }
    if (o->check && ((double)b->a_differ > TL_MAX_DIFF_FRACTION * (double)b->a_rays ||
                     (double)b->a_sdiffer > TL_MAX_DIFF_FRACTION * (double)b->a_srays)) {
        fprintf(stderr, "embree_bench: two-level scene: agreement outside the bounds (TL_MAX_DIFF_FRACTION %g): "
                        "%zu of %zu camera rays, %zu of %zu shadow rays differ\n", TL_MAX_DIFF_FRACTION, b->a_differ,
                b->a_rays, b->a_sdiffer, b->a_srays);
        g_fail = 1;
    }
}

static void run_twolevel(const Options *o)
{
    TwoLevel *b = calloc(1, sizeof *b);
    if (!b)
        die("out of memory");
    b->o = o;
    tl_setup(b);
    for (int ti = 0; ti < o->nthreads; ti++) tl_run(b, ti);
    b->load1 = load_average();
    tl_report(b);
    sheaf_context_destroy(b->ctx);
    free(b->rays); free(b->pix); free(b->hits); free(b->srays); free(b->socc); free(b->eocc);
    free(b->eprim); free(b->einst); free(b->et);
    for (int g = 0; g < NGEOM; g++) {
        free(b->g[g].verts); free(b->g[g].idx); free(b->g[g].frames);
    }
    free(b);
}

/* ---- main ---------------------------------------------------------------------------- */

static void usage(void)
{
    fprintf(stderr,
            "usage: embree_bench [--reps N] [--threads 1,2] [--size WxH] [--check] [--no-ray-check]\n"
            "                    [--bvh-reserve PERCENT] [--summary FILE] SCENE.scene...\n"
            "       embree_bench --twolevel ENV.scene ANIM.scene OBJ.scene [--frames N] [--reps N]\n"
            "                    [--threads 1,2] [--size WxH] [--check] [--summary FILE]\n"
            "  SCENE.scene  written by `sheaf export` (one named view, its light)\n"
            "  --reps N     median of N timed runs (default 3)\n"
            "  --threads L  thread counts, comma-separated (default 1,2)\n"
            "  --size WxH   image size, multiples of 32 (default: the one the file was framed for)\n"
            "  --check      exit 2 when sheaf and Embree disagree beyond the named bounds\n"
            "  --no-ray-check  skip checking the rays against sheaf's deferred frame\n"
            "  --bvh-reserve PERCENT  the BVH HIGH build's spatial-split reserve: max_bvh_refs =\n"
            "               triangles + PERCENT%% of them (default %d; 0: no reserve, no spatial splits)\n"
            "  --compact-shadows  pack the shadow rays (default: one slot per camera ray, the\n"
            "               renderer's packets, inactive slots for misses and unlit points)\n"
            "  --summary F  key=value agreement and ratio lines to F\n"
            "  --profile NAME  time one configuration alone on 1 thread (for perf): a sheaf\n"
            "               method by its table name (on the HIGH tree: high:NAME or NAME high), or\n"
            "               embree-1/4/8/16 (Embree LOW), embree-N-medium, embree-N-high\n"
            "  --profile-shadow  with --profile: the shadow rays instead of camera rays\n"
            "  --ab A,B,..     the named configurations (embree-N for Embree LOW, embree-N-medium,\n"
            "                  embree-N-high for its MEDIUM and HIGH trees) in interleaved\n"
            "                  rounds, camera and shadow rays, each thread count: Mrays/s and\n"
            "                  the median per-round speed over the last one's; cam:NAME traces the camera\n"
            "                  rays made in the kernel (sheaf_context_trace_camera, one 32x32 tile per\n"
            "                  call; shadow rows as NAME); soa:NAME traces sheaf's\n"
            "                  rays as a ray stream (sheaf_context_trace_stream / _occluded_stream); low:NAME\n"
            "                  traces sheaf's LOW tree (every sheaf configuration, or none); high:NAME or\n"
            "                  \"NAME high\" traces sheaf's HIGH tree (a context of its own; mixes with the\n"
            "                  others; its answers checked against the reference first)\n"
            "  --updates    the per-frame updates alone: sheaf's BVH LOW build against Embree's LOW\n"
            "               rebuild and sheaf's refit (SAH tree, width 4) against Embree's LOW + REFIT,\n"
            "               in interleaved rounds per thread count: medians and the median per-round ratio\n"
            "  --explain    print every disagreement no tie, edge or end explains\n"
            "  --twolevel ENV ANIM OBJ  the two-level scene instead: ENV static (one instance),\n"
            "               ANIM (`sheaf export builtin:animated --frames F`) refit every frame (4\n"
            "               instances), OBJ static in a ring of 16 instances turning every frame;\n"
            "               ENV's view and light; sheaf and Embree frame times (see the README)\n"
            "  --frames N   with --twolevel: frames per run (default 24; frame f shows the\n"
            "               animation's frame f mod F); --check: at most 0.01%% of the camera\n"
            "               and of the shadow rays may differ\n"
            "  --ppm FILE   with --twolevel: write frame 0 as sheaf traced it (binary PPM; env grey,\n"
            "               anim copies red, the ring green, darker in shadow)\n"
            "  --filter     with --twolevel: anim alpha-tested (a cut-out) by any-hit filters in both\n"
            "               libraries (sheaf_filter_fn; Embree's filter functions)\n",
            BVH_RESERVE_PERCENT);
    exit(1);
}

int main(int argc, char **argv)
{
    Options o;
    memset(&o, 0, sizeof o);
    o.reps = 3;
    o.threads[0] = 1;
    o.threads[1] = 2;
    o.nthreads = 2;
    o.check_rays = 1;
    o.frames = 24;
    o.bvh_reserve = BVH_RESERVE_PERCENT;
    int first = 0;
    {
        uint32_t probe = 1;
        unsigned char b;
        memcpy(&b, &probe, 1);
        if (b != 1)
            die("this program reads little-endian files on a little-endian host only");
    }
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--reps") && i + 1 < argc) {
            o.reps = atoi(argv[++i]);
            if (o.reps < 1 || o.reps > MAX_REPS) die("--reps: 1..%d", MAX_REPS);
        } else if (!strcmp(a, "--threads") && i + 1 < argc) {
            o.nthreads = 0;
            for (char *p = argv[++i]; *p;) {
                long t = strtol(p, &p, 10);
                if (t < 1 || t > MAX_THREADS || o.nthreads == 4) die("--threads: up to 4 counts in 1..%d", MAX_THREADS);
                o.threads[o.nthreads++] = (int)t;
                if (*p == ',') p++;
                else if (*p) die("--threads: comma-separated numbers");
            }
            if (o.nthreads == 0) die("--threads: at least one count");
        } else if (!strcmp(a, "--size") && i + 1 < argc) {
            if (sscanf(argv[++i], "%ux%u", &o.width, &o.height) != 2) die("--size WxH");
        } else if (!strcmp(a, "--check")) {
            o.check = 1;
        } else if (!strcmp(a, "--explain")) {
            g_explain = 1;
        } else if (!strcmp(a, "--compact-shadows")) {
            o.compact_shadows = 1;
        } else if (!strcmp(a, "--no-ray-check")) {
            o.check_rays = 0;
        } else if (!strcmp(a, "--summary") && i + 1 < argc) {
            o.summary = argv[++i];
        } else if (!strcmp(a, "--profile") && i + 1 < argc) {
            o.profile = argv[++i];
        } else if (!strcmp(a, "--ab") && i + 1 < argc) {
            o.ab = argv[++i];
        } else if (!strcmp(a, "--bvh-reserve") && i + 1 < argc) {
            char *end;
            long pc = strtol(argv[++i], &end, 10);
            if (*end || end == argv[i] || pc < 0 || pc > MAX_BVH_RESERVE_PERCENT)
                die("--bvh-reserve PERCENT: 0..%d", MAX_BVH_RESERVE_PERCENT);
            o.bvh_reserve = (int)pc;
        } else if (!strcmp(a, "--profile-shadow")) {
            o.profile_shadow = 1;
        } else if (!strcmp(a, "--updates")) {
            o.updates = 1;
        } else if (!strcmp(a, "--twolevel") && i + 3 < argc) {
            for (int k = 0; k < 3; k++) o.twolevel[k] = argv[++i];
        } else if (!strcmp(a, "--filter")) {
            o.filter = 1;
        } else if (!strcmp(a, "--ppm") && i + 1 < argc) {
            o.ppm = argv[++i];
        } else if (!strcmp(a, "--frames") && i + 1 < argc) {
            o.frames = atoi(argv[++i]);
            if (o.frames < 1 || o.frames > TL_MAX_FRAMES) die("--frames: 1..%d", TL_MAX_FRAMES);
        } else if (a[0] == '-') {
            usage();
        } else {
            if (!first) first = i;
        }
    }
    if (o.twolevel[0] && (first || o.profile))
        die("--twolevel takes its three scenes and no other scene or --profile");
    if (!first && !o.twolevel[0])
        usage();
    if (o.summary) {
        g_summary = fopen(o.summary, "w");
        if (!g_summary) die("cannot write %s", o.summary);
    }

    /* Machine and library facts. */
    RTCDevice dev = rtcNewDevice("threads=1");
    if (!dev)
        die("rtcNewDevice failed (error %d)", (int)rtcGetDeviceError(NULL));
    struct utsname un;
    uname(&un);
    char cpu[256] = "unknown CPU";
    FILE *f = fopen("/proc/cpuinfo", "r");
    if (f) {
        char line[512];
        while (fgets(line, sizeof line, f))
            if (!strncmp(line, "model name", 10)) {
                char *c = strchr(line, ':');
                if (c) {
                    snprintf(cpu, sizeof cpu, "%s", c + 2);
                    cpu[strcspn(cpu, "\n")] = 0;
                }
                break;
            }
        fclose(f);
    }
    __builtin_cpu_init();
    printf("Machine: %s, %ld online cores, %s %s; ISA: %s%s%s%s.\n", cpu, sysconf(_SC_NPROCESSORS_ONLN), un.sysname,
           un.release, __builtin_cpu_supports("avx512f") ? "AVX-512F " : "", __builtin_cpu_supports("avx2") ? "AVX2 " : "",
           __builtin_cpu_supports("avx") ? "AVX " : "", "SSE4.2");
    const char *isa_env = getenv("SHEAF_ISA");
    printf("sheaf %s (C ABI, static library; packet lanes: the CPU's widest%s%s%s), Embree %s (Debian's libembree3; "
           "tasking: %s; native rtcIntersect4/8/16: %s/%s/%s, which on this CPU run %s kernels).\n",
           sheaf_version_string(), isa_env ? ", capped by SHEAF_ISA=" : "", isa_env ? isa_env : "",
           isa_env ? "" : " (SHEAF_ISA unset)", RTC_VERSION_STRING,
           rtcGetDeviceProperty(dev, RTC_DEVICE_PROPERTY_TASKING_SYSTEM) == 1 ? "TBB" : "internal",
           rtcGetDeviceProperty(dev, RTC_DEVICE_PROPERTY_NATIVE_RAY4_SUPPORTED) ? "yes" : "no",
           rtcGetDeviceProperty(dev, RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED) ? "yes" : "no",
           rtcGetDeviceProperty(dev, RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED) ? "yes" : "no",
           __builtin_cpu_supports("avx512f") ? "AVX-512 (16-wide native)"
           : __builtin_cpu_supports("avx2") ? "AVX2 (16-wide emulated with two 8-wide)"
                                              : "SSE (8/16-wide emulated)");
    rtcReleaseDevice(dev);
    printf("Threads:");
    for (int t = 0; t < o.nthreads; t++) printf(" %d", o.threads[t]);
    printf("; median of %d runs; load average at start %.2f.\n", o.reps, load_average());
    fflush(stdout);

    if (o.twolevel[0])
        run_twolevel(&o);
    for (int i = first; first && i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--reps") || !strcmp(a, "--threads") || !strcmp(a, "--size") || !strcmp(a, "--summary") ||
            !strcmp(a, "--profile") || !strcmp(a, "--frames") || !strcmp(a, "--ppm") || !strcmp(a, "--ab") ||
            !strcmp(a, "--bvh-reserve")) {
            i++;
            continue;
        }
        if (a[0] == '-')
            continue;
        run_scene(a, &o);
    }
    if (g_nresults > 0) {
        printf("\n### Summary: sheaf / Embree\n\n"
               "Rays: sheaf's fastest method (any structure, the BVH at any quality) over Embree's fastest width and quality, Mrays/s ratio (below 1: "
               "sheaf slower). Dynamic frame: sheaf's fastest structure over Embree LOW + DYNAMIC, time ratio "
               "(above 1: sheaf slower). Build: sheaf's BVH LOW build (joined by the thread count) over Embree's LOW "
               "rebuild, refit: sheaf's BVH refit over Embree's, time ratios. Differing rays: against Embree "
               "MEDIUM (ties + edges, and shadow-ray ends); unexplained: every quality.\n\n| scene | triangles |");
        for (int ti = 0; ti < o.nthreads; ti++) printf(" primary %dT |", o.threads[ti]);
        for (int ti = 0; ti < o.nthreads; ti++) printf(" shadow %dT |", o.threads[ti]);
        for (int ti = 0; ti < o.nthreads; ti++) printf(" frame %dT |", o.threads[ti]);
        for (int ti = 0; ti < o.nthreads; ti++) printf(" build %dT |", o.threads[ti]);
        for (int ti = 0; ti < o.nthreads; ti++) printf(" refit %dT |", o.threads[ti]);
        printf(" camera rays differing | shadow rays differing | unexplained |\n|---|--:|");
        for (int ti = 0; ti < 5 * o.nthreads; ti++) printf("--:|");
        printf("--:|--:|--:|\n");
        for (int i = 0; i < g_nresults; i++) {
            SceneResult *r = &g_results[i];
            printf("| %s | %u |", r->name, r->triangles);
            for (int ti = 0; ti < o.nthreads; ti++) printf(" %.2f |", r->ratio_p[ti]);
            for (int ti = 0; ti < o.nthreads; ti++) printf(" %.2f |", r->ratio_s[ti]);
            for (int ti = 0; ti < o.nthreads; ti++) printf(" %.2f (%s) |", r->ratio_f[ti], r->frame_struct[ti]);
            for (int ti = 0; ti < o.nthreads; ti++) printf(" %.2f |", r->ratio_b[ti]);
            for (int ti = 0; ti < o.nthreads; ti++) printf(" %.2f |", r->ratio_r[ti]);
            printf(" %zu (%zu + %zu) | %zu (%zu + %zu) | %zu |\n", r->p_differ, r->p_ties, r->p_edges, r->s_differ,
                   r->s_edges, r->s_ends, r->unexplained);
        }
    }
    if (g_summary)
        fclose(g_summary);
    return g_fail ? 2 : 0;
}
