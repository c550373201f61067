// include/sheaf.hpp under g++ -std=c++17 and -std=c++20 (-Wall -Wextra
// -Werror -pedantic): the owners, both error policies, error messages
// that say the failure once, the ray overloads (spans with C++20), owners
// released while an exception unwinds or destroyed in any order, and
// filters as C functions and as lambdas.
#include "sheaf.hpp"
#include "cpp_check.h"

#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace {

const std::vector<float> kVertices = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
const std::vector<uint32_t> kIndices = {0, 1, 2, 0, 2, 3};

std::vector<sheaf_ray> rays() {
    const float inf = std::numeric_limits<float>::infinity();
    return {sheaf_ray{{0.75f, 0.25f, 1.0f}, 0.0f, {0.0f, 0.0f, -1.0f}, inf},
            sheaf_ray{{2.0f, 2.0f, 1.0f}, 0.0f, {0.0f, 0.0f, -1.0f}, inf}};
}

bool test_trace_through_the_owner() {
    sheaf::Context ctx;
    ctx.create(2);
    CHECK(ctx);
    ctx.set_geometry(kVertices, kIndices);
    ctx.build_bvh();
    const std::vector<sheaf_ray> r = rays();
    std::vector<sheaf_hit> hits;
    ctx.trace(SHEAF_METHOD_BVH_SINGLE, r, hits);
    CHECK(hits.size() == 2 && hits[0].prim == 0 && std::fabs(hits[0].t - 1.0f) < 1e-6f);
    CHECK(hits[1].prim == SHEAF_INVALID_ID);
    // The (pointer, count) form and the C call give the same bits.
    std::vector<sheaf_hit> raw(r.size()), c(r.size());
    ctx.trace(SHEAF_METHOD_BVH_SINGLE, r.data(), r.size(), raw.data());
    CHECK(sheaf_context_trace(ctx.get(), SHEAF_METHOD_BVH_SINGLE, r.data(), c.data(), r.size()) == SHEAF_STATUS_OK);
    CHECK(std::memcmp(raw.data(), c.data(), sizeof(sheaf_hit) * c.size()) == 0);
    std::vector<uint8_t> occ;
    ctx.occluded(SHEAF_METHOD_BVH_SINGLE, r, occ);
    CHECK(occ.size() == 2 && occ[0] == 1 && occ[1] == 0);
#ifdef SHEAF_HPP_SPAN
    std::vector<sheaf_hit> spanned(r.size());
    ctx.trace(SHEAF_METHOD_BVH_SINGLE, std::span<const sheaf_ray>(r), std::span<sheaf_hit>(spanned));
    CHECK(std::memcmp(spanned.data(), c.data(), sizeof(sheaf_hit) * c.size()) == 0);
    bool threw = false;
    try {
        ctx.trace(SHEAF_METHOD_BVH_SINGLE, std::span<const sheaf_ray>(r), std::span<sheaf_hit>(spanned).first(1));
    } catch (const sheaf::Error &e) {
        threw = e.status() == SHEAF_STATUS_INVALID_ARGUMENT;
    }
    CHECK(threw);
#endif
    // Moved: the new owner holds the context, the old one nothing.
    sheaf::Context moved = std::move(ctx);
    CHECK(moved && !ctx);
    sheaf_stats st;
    moved.stats(st);
    CHECK(st.bvh_triangles == 2);
    return true;
}

bool test_error_policies() {
    // Throw: the status and the context's message.
    sheaf::Context ctx;
    ctx.create(2);
    bool threw = false;
    try {
        ctx.build_bvh();  // no geometry yet
    } catch (const sheaf::Error &e) {
        threw = e.status() == SHEAF_STATUS_NO_GEOMETRY && std::strlen(e.what()) > 0;
    }
    CHECK(threw);
    // Return: the same status, nothing thrown.
    sheaf::ContextNoThrow quiet;
    CHECK(quiet.create(2) == SHEAF_STATUS_OK);
    CHECK(quiet.build_bvh() == SHEAF_STATUS_NO_GEOMETRY);
    sheaf_kd_params bad;
    CHECK(sheaf_kd_params_default(&bad) == SHEAF_STATUS_OK);
    bad.bins = 1;
    CHECK(quiet.set_geometry(kVertices, kIndices) == SHEAF_STATUS_OK);
    CHECK(quiet.build_kd(&bad) == SHEAF_STATUS_INVALID_ARGUMENT);
    sheaf_limits l;
    CHECK(sheaf_limits_default(2, &l) == SHEAF_STATUS_OK);
    l.structures = 0x80000000u;  // no such structure
    sheaf::ContextNoThrow none;
    CHECK(none.create(l) != SHEAF_STATUS_OK && !none);
    return true;
}

// How often `needle` occurs in `text`.
size_t occurrences(const std::string &text, const std::string &needle) {
    size_t n = 0;
    for (size_t at = text.find(needle); at != std::string::npos; at = text.find(needle, at + needle.size())) ++n;
    return n;
}

// The failure `call` throws, as (status, what()).
template <class F> std::pair<sheaf_status, std::string> thrown(F call) {
    try {
        call();
    } catch (const sheaf::Error &e) {
        return {e.status(), e.what()};
    }
    return {SHEAF_STATUS_OK, ""};
}

bool test_error_says_it_once() {
    // The last error message already starts with the status's text; what()
    // is that message, not the status's text and it again.
    sheaf::Context ctx;
    ctx.create(2);
    ctx.set_geometry(kVertices, kIndices);
    sheaf_kd_params bad;
    CHECK(sheaf_kd_params_default(&bad) == SHEAF_STATUS_OK);
    bad.bins = 1;
    const auto invalid = thrown([&] { ctx.build_kd(&bad); });
    CHECK(invalid.first == SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(occurrences(invalid.second, sheaf_status_string(invalid.first)) == 1);
    char buf[SHEAF_ERROR_MESSAGE_MAX];
    size_t written = 0;
    CHECK(sheaf_context_last_error(ctx.get(), buf, sizeof buf, &written) == SHEAF_STATUS_OK);
    CHECK(invalid.second == std::string(buf, written));  // the detail is kept
    // A message that is the status's text alone.
    sheaf::Context empty;
    empty.create(2);
    const auto no_geometry = thrown([&] { empty.build_bvh(); });
    CHECK(no_geometry.first == SHEAF_STATUS_NO_GEOMETRY);
    CHECK(occurrences(no_geometry.second, sheaf_status_string(no_geometry.first)) == 1);
    // No context: the status's text.
    sheaf::Context none;
    const auto null = thrown([&] { none.build_bvh(); });
    CHECK(null.first == SHEAF_STATUS_NULL_POINTER && null.second == sheaf_status_string(SHEAF_STATUS_NULL_POINTER));
#ifdef SHEAF_HPP_SPAN
    // Checked in sheaf.hpp: not the kd failure's message, which is still
    // the context's last error.
    const std::vector<sheaf_ray> r = rays();
    std::vector<sheaf_hit> one(1);
    const auto lengths = thrown([&] {
        ctx.trace(SHEAF_METHOD_BVH_SINGLE, std::span<const sheaf_ray>(r), std::span<sheaf_hit>(one));
    });
    CHECK(lengths.first == SHEAF_STATUS_INVALID_ARGUMENT);
    CHECK(lengths.second == sheaf_status_string(SHEAF_STATUS_INVALID_ARGUMENT));
#endif
    return true;
}

sheaf_scene_info committed(sheaf::Context &ctx) {
    sheaf_scene_info info;
    ctx.commit_scene(&info);
    return info;
}

// Limits of a BVH-only context with a two-level scene of `n` geometries
// and `n` instances.
sheaf_limits scene_limits(uint32_t n) {
    sheaf_limits l;
    sheaf_limits_default(16, &l);
    l.structures = SHEAF_STRUCTURE_BVH;
    l.max_geometries = n;
    l.max_instances = n;
    l.max_scene_triangles = 16;
    return l;
}

bool test_scene_owners_and_unwinding() {
    sheaf::Context ctx;
    ctx.create(scene_limits(2));
    const sheaf_mesh mesh = {kVertices.data(), 3 * sizeof(float), 4, kIndices.data(), 2};
    const float xf[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    sheaf::Context::SceneGeometry geometry;
    sheaf::Context::Instance instance;
    ctx.set_scene_geometry(0, mesh, nullptr, geometry);
    ctx.set_instance(0, 0, xf, ~0u, instance);
    CHECK(geometry && instance && geometry.id() == 0);
    sheaf_scene_info info = committed(ctx);
    CHECK(info.geometries == 1 && info.instances == 1);
    // Owners made in a scope that throws remove their ids as it unwinds.
    try {
        sheaf::Context::SceneGeometry g1;
        sheaf::Context::Instance i1;
        ctx.set_scene_geometry(1, mesh, nullptr, g1);
        ctx.set_instance(1, 1, xf, ~0u, i1);
        throw std::runtime_error("unwind");
    } catch (const std::runtime_error &) {
    }
    info = committed(ctx);
    CHECK(info.geometries == 1 && info.instances == 1);
    // A refused call leaves the owner as it was.
    sheaf::Context::Instance other;
    bool threw = false;
    try {
        ctx.set_instance(1, 7, xf, ~0u, other);  // no geometry 7
    } catch (const sheaf::Error &) {
        threw = true;
    }
    CHECK(threw && !other);
    instance.reset();
    geometry.reset();
    info = committed(ctx);
    CHECK(info.geometries == 0 && info.instances == 0);
    return true;
}

// The scene as sheaf has it, through the C API (ctx.commit_scene would
// itself remove orphaned geometries).
sheaf_scene_info c_committed(sheaf_context *ctx) {
    sheaf_scene_info info;
    std::memset(&info, 0xff, sizeof info);
    (void)sheaf_context_commit_scene(ctx, &info);
    return info;
}

bool test_scene_owners_in_any_order() {
    sheaf::Context ctx;
    ctx.create(scene_limits(2));
    const sheaf_mesh mesh = {kVertices.data(), 3 * sizeof(float), 4, kIndices.data(), 2};
    const float xf[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    const std::vector<sheaf_ray> r = rays();
    {
        // The instances are declared first, so the geometry's owner is
        // destroyed while they still place it: sheaf refuses that removal.
        sheaf::Context::Instance first, second;
        {
            sheaf::Context::SceneGeometry geometry;
            ctx.set_scene_geometry(0, mesh, nullptr, geometry);
            ctx.set_instance(0, 0, xf, ~0u, first);
            ctx.set_instance(1, 0, xf, ~0u, second);
        }
        // The instances still place it and still hit it.
        sheaf_scene_info info = c_committed(ctx.get());
        CHECK(info.geometries == 1 && info.instances == 2);
        std::vector<sheaf_scene_hit> hits(r.size());
        ctx.trace_scene(nullptr, r.data(), r.size(), hits.data());
        CHECK(hits[0].geometry == 0 && hits[0].prim == 0);
        first.reset();
        info = c_committed(ctx.get());
        CHECK(info.geometries == 1 && info.instances == 1);
    }
    // The last instance took the geometry with it: its id is free again.
    sheaf_scene_info info = c_committed(ctx.get());
    CHECK(info.geometries == 0 && info.instances == 0);
    CHECK(sheaf_context_remove_scene_geometry(ctx.get(), 0) == SHEAF_STATUS_INVALID_ARGUMENT);  // not set

    // An orphan set again has an owner again: its instance's removal keeps it.
    {
        sheaf::Context::Instance placed;
        sheaf::Context::SceneGeometry again;
        {
            sheaf::Context::SceneGeometry geometry;
            ctx.set_scene_geometry(0, mesh, nullptr, geometry);
            ctx.set_instance(0, 0, xf, ~0u, placed);
        }
        ctx.set_scene_geometry(0, mesh, nullptr, again);
        placed.reset();
        info = c_committed(ctx.get());
        CHECK(info.geometries == 1 && info.instances == 0);
    }
    CHECK(c_committed(ctx.get()).geometries == 0);

    // An orphan whose last instance was removed through the C API goes at
    // the next commit_scene.
    {
        sheaf::Context::Instance placed;
        {
            sheaf::Context::SceneGeometry geometry;
            ctx.set_scene_geometry(1, mesh, nullptr, geometry);
            ctx.set_instance(0, 1, xf, ~0u, placed);
        }
        CHECK(sheaf_context_remove_instance(ctx.get(), placed.release()) == SHEAF_STATUS_OK);
        CHECK(c_committed(ctx.get()).geometries == 1);
        CHECK(committed(ctx).geometries == 0);
    }

    // An instance that placed an orphan and now places another geometry
    // lets the orphan go.
    {
        sheaf::Context::SceneGeometry kept;
        sheaf::Context::Instance placed;
        {
            sheaf::Context::SceneGeometry geometry;
            ctx.set_scene_geometry(0, mesh, nullptr, geometry);
            ctx.set_scene_geometry(1, mesh, nullptr, kept);
            ctx.set_instance(0, 0, xf, ~0u, placed);
        }
        CHECK(c_committed(ctx.get()).geometries == 2);
        ctx.set_instance(0, 1, xf, ~0u, placed);
        info = c_committed(ctx.get());
        CHECK(info.geometries == 1 && info.instances == 1);
        CHECK(sheaf_context_remove_scene_geometry(ctx.get(), 0) == SHEAF_STATUS_INVALID_ARGUMENT);  // 0 is gone
    }
    CHECK(c_committed(ctx.get()).geometries == 0);
    return true;
}

// A checkerboard cut-out of the (u, v) cells, as a C function.
bool checker(void *calls, const sheaf_candidate *c) {
    if (calls != nullptr) ++*static_cast<unsigned *>(calls);
    return (static_cast<int>(c->u * 4.0f) + static_cast<int>(c->v * 4.0f)) % 2 == 0;
}

bool test_filters() {
    sheaf::Context ctx;
    ctx.create(2);
    ctx.set_geometry(kVertices, kIndices);
    ctx.build_bvh();
    const float inf = std::numeric_limits<float>::infinity();
    std::vector<sheaf_ray> r;
    for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x)
            r.push_back(sheaf_ray{{(x + 0.5f) / 16, (y + 0.5f) / 16, 1.0f}, 0.0f, {0.0f, 0.0f, -1.0f}, inf});
    // A lambda the context refers to, and the same cut-out as a C function.
    unsigned lambda_calls = 0, c_calls = 0;
    auto cut = [&lambda_calls](const sheaf_candidate &c) {
        return checker(&lambda_calls, &c);
    };
    std::vector<sheaf_hit> by_lambda, by_c, open;
    ctx.trace(SHEAF_METHOD_BVH_SINGLE, r, open);
    ctx.set_filter(cut);
    ctx.trace(SHEAF_METHOD_BVH_SINGLE, r, by_lambda);
    ctx.set_filter(checker, &c_calls);
    ctx.trace(SHEAF_METHOD_BVH_SINGLE, r, by_c);
    CHECK(lambda_calls > 0 && lambda_calls == c_calls);
    CHECK(std::memcmp(by_lambda.data(), by_c.data(), sizeof(sheaf_hit) * r.size()) == 0);
    size_t misses = 0;
    for (const sheaf_hit &h : by_c) misses += h.prim == SHEAF_INVALID_ID;
    CHECK(misses > 0 && misses < r.size());
    ctx.set_filter(nullptr);
    std::vector<sheaf_hit> again;
    ctx.trace(SHEAF_METHOD_BVH_SINGLE, r, again);
    CHECK(std::memcmp(again.data(), open.data(), sizeof(sheaf_hit) * r.size()) == 0);
    // A const callable works too.
    const auto const_cut = [](const sheaf_candidate &c) { return checker(nullptr, &c); };
    ctx.set_filter(const_cut);
    std::vector<sheaf_hit> by_const;
    ctx.trace(SHEAF_METHOD_BVH_SINGLE, r, by_const);
    CHECK(std::memcmp(by_const.data(), by_c.data(), sizeof(sheaf_hit) * r.size()) == 0);
    // A scene geometry's filter; an id not set is refused.
    sheaf::ContextNoThrow scene;
    CHECK(scene.create(scene_limits(1)) == SHEAF_STATUS_OK);
    const sheaf_mesh mesh = {kVertices.data(), 3 * sizeof(float), 4, kIndices.data(), 2};
    const float xf[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    sheaf::ContextNoThrow::SceneGeometry geometry;
    sheaf::ContextNoThrow::Instance instance;
    CHECK(scene.set_scene_geometry(0, mesh, nullptr, geometry) == SHEAF_STATUS_OK);
    CHECK(scene.set_instance(0, 0, xf, ~0u, instance) == SHEAF_STATUS_OK);
    CHECK(scene.commit_scene() == SHEAF_STATUS_OK);
    CHECK(scene.set_scene_geometry_filter(0, cut) == SHEAF_STATUS_OK);
    CHECK(scene.set_scene_geometry_filter(5, cut) == SHEAF_STATUS_INVALID_ARGUMENT);
    std::vector<sheaf_scene_hit> sh(r.size());
    CHECK(scene.trace_scene(nullptr, r.data(), r.size(), sh.data()) == SHEAF_STATUS_OK);
    for (size_t i = 0; i < r.size(); ++i) CHECK(sh[i].prim == by_c[i].prim);
    return true;
}

}  // namespace

int main() {
    const NamedTest tests[] = {
        {"test_trace_through_the_owner", test_trace_through_the_owner},
        {"test_error_policies", test_error_policies},
        {"test_error_says_it_once", test_error_says_it_once},
        {"test_scene_owners_and_unwinding", test_scene_owners_and_unwinding},
        {"test_scene_owners_in_any_order", test_scene_owners_in_any_order},
        {"test_filters", test_filters},
    };
    return run_tests(tests);
}
