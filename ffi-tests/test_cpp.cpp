// The header as C++ (g++ -std=c++11 -Wall -Wextra -Werror -pedantic): the
// extern "C" guards, the fixed-width enums (sheaf_status, sheaf_method and
// sheaf_tri_test are real enum types in C++), and a few calls.
#include "sheaf.h"
#include "cpp_check.h"

#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <vector>

static_assert(sizeof(sheaf_ray) == 32, "sheaf_ray is 32 bytes");
static_assert(sizeof(sheaf_hit) == 16, "sheaf_hit is 16 bytes");
static_assert(sizeof(sheaf_status) == 4, "sheaf_status is a uint32_t");
static_assert(sizeof(sheaf_method) == 4, "sheaf_method is a uint32_t");
static_assert(SHEAF_STATUS_OK == 0 && SHEAF_STATUS_PANIC == 900, "status codes are never renumbered");
static_assert(SHEAF_STATUS_CAPACITY_PGRID_CELLS == 206 && SHEAF_STATUS_CAPACITY_PGRID_REFS == 207,
              "status codes are never renumbered");
static_assert(sizeof(sheaf_pgrid_params) == 40, "sheaf_pgrid_params is 40 bytes");

namespace {

// RAII owner of a context, as a C++ engine would write it.
class Context {
  public:
    explicit Context(uint32_t max_triangles) {
        sheaf_limits limits;
        if (sheaf_limits_default(max_triangles, &limits) == SHEAF_STATUS_OK) {
            status_ = sheaf_context_create(&limits, &ctx_);
        }
    }
    ~Context() { sheaf_context_destroy(ctx_); }
    Context(const Context &) = delete;
    Context &operator=(const Context &) = delete;
    sheaf_context *get() const { return ctx_; }
    sheaf_status status() const { return status_; }

  private:
    sheaf_context *ctx_ = nullptr;
    sheaf_status status_ = SHEAF_STATUS_INVALID_ARGUMENT;
};

bool test_trace_a_quad() {
    const std::vector<float> vertices = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
    const std::vector<uint32_t> indices = {0, 1, 2, 0, 2, 3};
    Context ctx(2);
    CHECK(ctx.status() == SHEAF_STATUS_OK);
    CHECK(sheaf_context_set_geometry(ctx.get(), vertices.data(), 3 * sizeof(float), 4, indices.data(), 2) ==
          SHEAF_STATUS_OK);
    sheaf_grid_params params;
    CHECK(sheaf_grid_params_default(&params) == SHEAF_STATUS_OK);
    params.test = SHEAF_TRI_TEST_WATERTIGHT;
    CHECK(sheaf_context_build_grid(ctx.get(), &params) == SHEAF_STATUS_OK);

    const float inf = std::numeric_limits<float>::infinity();
    std::vector<sheaf_ray> rays(2);
    rays[0] = sheaf_ray{{0.75f, 0.25f, 1.0f}, 0.0f, {0.0f, 0.0f, -1.0f}, inf};
    rays[1] = sheaf_ray{{2.0f, 2.0f, 1.0f}, 0.0f, {0.0f, 0.0f, -1.0f}, inf};
    std::vector<sheaf_hit> hits(rays.size());
    CHECK(sheaf_context_trace(ctx.get(), SHEAF_METHOD_GRID_DDA, rays.data(), hits.data(), rays.size()) ==
          SHEAF_STATUS_OK);
    CHECK(hits[0].prim == 0 && std::fabs(hits[0].t - 1.0f) < 1e-6f);
    CHECK(hits[1].prim == SHEAF_INVALID_ID && std::isinf(hits[1].t));

    std::vector<uint8_t> occluded(rays.size(), 7);
    CHECK(sheaf_context_occluded(ctx.get(), SHEAF_METHOD_GRID_DDA, rays.data(), occluded.data(), rays.size()) ==
          SHEAF_STATUS_OK);
    CHECK(occluded[0] == 1 && occluded[1] == 0);

    sheaf_stats stats;
    CHECK(sheaf_context_stats(ctx.get(), &stats) == SHEAF_STATUS_OK);
    CHECK(stats.triangles == 2 && stats.test == SHEAF_TRI_TEST_WATERTIGHT);
    return true;
}

// A deferred frame through the perspective grid and a light grid, as a C++
// engine would set it up (value-initialised structs, then fields).
bool test_deferred_frame() {
    // A ground quad and a floating triangle that shadows it.
    const std::vector<float> vertices = {-4, -4, 0, 4, -4, 0, 4, 4, 0, -4, 4, 0, -1, -1, 1, 1, -1, 1, 0, 1, 1};
    const std::vector<uint32_t> indices = {0, 1, 2, 0, 2, 3, 4, 5, 6};
    const uint32_t w = 16, h = 12;
    sheaf_limits limits;
    CHECK(sheaf_limits_default(3, &limits) == SHEAF_STATUS_OK);
    limits.max_image_width = w;
    limits.max_image_height = h;
    limits.structures = SHEAF_STRUCTURE_GRID | SHEAF_STRUCTURE_PGRID;
    sheaf_context *raw = nullptr;
    CHECK(sheaf_context_create(&limits, &raw) == SHEAF_STATUS_OK);
    std::unique_ptr<sheaf_context, void (*)(sheaf_context *)> ctx(raw, sheaf_context_destroy);
    CHECK(sheaf_context_set_geometry(ctx.get(), vertices.data(), 3 * sizeof(float), 7, indices.data(), 3) ==
          SHEAF_STATUS_OK);
    sheaf_pgrid_params params;
    CHECK(sheaf_pgrid_params_default(&params) == SHEAF_STATUS_OK);
    params.tile = 4;
    CHECK(sheaf_context_build_pgrid(ctx.get(), &params) == SHEAF_STATUS_OK);
    CHECK(sheaf_context_build_grid(ctx.get(), nullptr) == SHEAF_STATUS_OK);

    sheaf_deferred_job job = sheaf_deferred_job();
    job.frame.camera.eye[1] = -6.0f;
    job.frame.camera.eye[2] = 5.0f;
    job.frame.camera.look_at[2] = 1.0f;  // the floating triangle's centre
    job.frame.camera.up[2] = 1.0f;
    job.frame.camera.fov_y_deg = 60.0f;
    CHECK(sheaf_shading_default(&job.frame.shading) == SHEAF_STATUS_OK);
    job.frame.width = w;
    job.frame.height = h;
    sheaf_light lights[2] = {sheaf_light(), sheaf_light()};
    lights[0].position[2] = 10.0f;
    lights[0].color[0] = lights[0].color[1] = lights[0].color[2] = 1.0f;
    lights[1] = lights[0];
    lights[1].position[0] = 3.0f;
    lights[1].spot_direction[2] = -1.0f;
    lights[1].spot_angle_deg = 30.0f;
    job.lights = lights;
    job.light_count = 2;
    job.primary_pgrid = true;
    job.shadow_light_grid = true;
    std::vector<uint8_t> rgba(w * h * 4), traced(w * h * 4);
    CHECK(sheaf_context_render_deferred(ctx.get(), &job, rgba.data(), w * 4, rgba.size()) == SHEAF_STATUS_OK);
    job.primary_pgrid = false;
    job.shadow_light_grid = false;
    sheaf_trace_params tp;
    CHECK(sheaf_trace_params_default(&tp) == SHEAF_STATUS_OK);
    job.primary = &tp;
    job.shadow = &tp;
    CHECK(sheaf_context_render_deferred(ctx.get(), &job, traced.data(), w * 4, traced.size()) == SHEAF_STATUS_OK);
    CHECK(rgba == traced);

    sheaf_hit hit;
    uint8_t bits = 0xFF;
    CHECK(sheaf_context_deferred_pixel(ctx.get(), w / 2, h / 2, &hit, &bits) == SHEAF_STATUS_OK);
    CHECK(hit.prim == 2 && bits == 0);  // the floating triangle, lit by both lights
    sheaf_stats stats;
    CHECK(sheaf_context_stats(ctx.get(), &stats) == SHEAF_STATUS_OK);
    CHECK(stats.pgrid_triangles == 3 && stats.shade_ns > 0 && stats.hits > 0);
    job.light_count = SHEAF_DEFERRED_MAX_LIGHTS + 1;
    CHECK(sheaf_context_render_deferred(ctx.get(), &job, rgba.data(), w * 4, rgba.size()) ==
          SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(sheaf_context_render_deferred(ctx.get(), nullptr, rgba.data(), w * 4, rgba.size()) ==
          SHEAF_STATUS_NULL_POINTER);
    return true;
}

bool test_errors_and_strings() {
    Context ctx(4);
    CHECK(ctx.status() == SHEAF_STATUS_OK);
    CHECK(sheaf_context_build_grid(ctx.get(), nullptr) == SHEAF_STATUS_NO_GEOMETRY);
    char msg[SHEAF_ERROR_MESSAGE_MAX];
    size_t written = 0;
    CHECK(sheaf_context_last_error(ctx.get(), msg, sizeof msg, &written) == SHEAF_STATUS_OK);
    CHECK(std::strcmp(msg, "no geometry set") == 0 && written == std::strlen(msg));
    CHECK(sheaf_context_trace(ctx.get(), static_cast<sheaf_method>(42), nullptr, nullptr, 0) ==
          SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(std::strcmp(sheaf_status_string(SHEAF_STATUS_OK), "ok") == 0);
    CHECK(sheaf_status_string(static_cast<sheaf_status>(4242)) != nullptr);
    CHECK(sheaf_version_string() != nullptr);
    sheaf_context_destroy(nullptr);
    return true;
}

}  // namespace

int main() {
    const NamedTest tests[] = {
        {"test_trace_a_quad", test_trace_a_quad},
        {"test_errors_and_strings", test_errors_and_strings},
        {"test_deferred_frame", test_deferred_frame},
    };
    return run_tests(tests);
}
