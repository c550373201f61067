// sheaf.hpp: C++17 owners over the C ABI of sheaf.h (header only).
//
// - sheaf::BasicContext<Policy> owns one sheaf_context (move-only; the
//   destructor destroys it), sheaf::BasicSceneGeometry and
//   sheaf::BasicInstance own one two-level scene geometry or instance id
//   (the destructor removes it). An owner of an id must be destroyed or
//   released before its context, but the id owners of one context may be
//   destroyed in any order: instances keep their geometry as shared_ptrs
//   would. A geometry whose owner goes while instances still place it
//   stays set until the last of them is removed through its owner or
//   replaced by set_instance (removed through the C API: until the next
//   commit_scene), and is removed then.
// - Policy picks how a status other than SHEAF_STATUS_OK is reported:
//   sheaf::Throw (the default: `sheaf::Context`) throws sheaf::Error with
//   the status and a message saying what failed once (the context's last
//   error message, else the status's text); sheaf::Return
//   (`sheaf::ContextNoThrow`) returns the sheaf_status and never throws.
// - Rays and hits are taken as (pointer, count), as std::vector, and as
//   std::span where the standard library has it (C++20).
// - Any-hit filters are set as a C function and pointer or as a callable
//   the context refers to (set_filter, set_scene_geometry_filter).
//
// Every call forwards to the C function of the same name; its contract
// (thread safety, what a failed call leaves unchanged) is the C one.
// Parameter structs are only ever made by their *_default macros (the
// size-carrying rule of docs/c-api.md, "Upgrading"), so an engine built
// with this header runs against later libraries of the same soname.
#ifndef SHEAF_HPP
#define SHEAF_HPP

#include "sheaf.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#if defined(__has_include)
#if __has_include(<version>)
#include <version>
#endif
#endif
#if defined(__cpp_lib_span) && __cpp_lib_span >= 202002L
#include <span>
#define SHEAF_HPP_SPAN 1
#endif

namespace sheaf {

/// A failed call under the Throw policy.
class Error : public std::runtime_error {
public:
    Error(sheaf_status status, const std::string &what) : std::runtime_error(what), status_(status) {}
    sheaf_status status() const noexcept { return status_; }

private:
    sheaf_status status_;
};

namespace detail {
/// What failed, said once. The context's last error message is a whole
/// sentence that already names the kind of failure ("invalid argument:
/// kd bins must be in 2..=64", "no geometry set"), so it is the message
/// alone: prefixing the status's text would say it twice. The status's
/// text is the message when the last error is not this failure's: no
/// context (`ctx` NULL, also for checks made in this header), or a
/// refusal sheaf does not record (busy, poisoned, reentrant).
inline std::string message(sheaf_status s, const sheaf_context *ctx) {
    const bool recorded =
        s != SHEAF_STATUS_CONTEXT_BUSY && s != SHEAF_STATUS_POISONED && s != SHEAF_STATUS_REENTRANT;
    if (ctx != nullptr && recorded) {
        char buf[SHEAF_ERROR_MESSAGE_MAX];
        size_t written = 0;
        if (sheaf_context_last_error(ctx, buf, sizeof buf, &written) == SHEAF_STATUS_OK && written > 0)
            return std::string(buf, written);
    }
    return sheaf_status_string(s);
}

/// What the id owners of one context share: the scene geometries whose
/// owner went while instances still placed them ("orphans"). sheaf
/// refuses to remove such a geometry (SHEAF_STATUS_INVALID_ARGUMENT,
/// nothing changes) and a destructor can neither throw nor return that,
/// so instead of leaving it set for good it is kept here and removed when
/// an instance that placed it goes and nothing places it any more. Used
/// only by calls that need exclusive access to the context, like them.
/// An orphan's id still belongs to this header: set it again through
/// set_scene_geometry (which adopts it), not through the C API alone.
struct Scene {
    std::vector<uint32_t> orphans;

    /// An instance placing `geometry` went: remove it if it is an orphan
    /// nothing places now. (One C call at most, however many orphans.)
    void unplaced(sheaf_context *ctx, uint32_t geometry) noexcept {
        const auto it = std::find(orphans.begin(), orphans.end(), geometry);
        if (it != orphans.end() && sheaf_context_remove_scene_geometry(ctx, geometry) == SHEAF_STATUS_OK)
            orphans.erase(it);
    }
    /// Remove every orphan nothing places any more (also those whose last
    /// instance was removed through the C API).
    void sweep(sheaf_context *ctx) noexcept {
        size_t kept = 0;
        for (uint32_t id : orphans)
            if (sheaf_context_remove_scene_geometry(ctx, id) != SHEAF_STATUS_OK) orphans[kept++] = id;
        orphans.erase(orphans.begin() + static_cast<std::ptrdiff_t>(kept), orphans.end());
    }
    /// Geometry `id` was set again: it has an owner, it is no orphan.
    void adopt(uint32_t id) noexcept { orphans.erase(std::remove(orphans.begin(), orphans.end(), id), orphans.end()); }
};

// How each owner removes its id (`geometry`: what an instance places).
inline void remove_geometry(Scene &scene, sheaf_context *ctx, uint32_t id, uint32_t) noexcept {
    if (sheaf_context_remove_scene_geometry(ctx, id) == SHEAF_STATUS_OK) return;
    try {
        scene.orphans.push_back(id); // refused: instances still place it
    } catch (...) {
        // Out of memory: the geometry stays set until the context goes.
    }
}
inline void remove_instance(Scene &scene, sheaf_context *ctx, uint32_t id, uint32_t geometry) noexcept {
    // Refused only when the id is no longer set, or on misuse (a busy or
    // poisoned context): nothing to keep then.
    if (sheaf_context_remove_instance(ctx, id) == SHEAF_STATUS_OK) scene.unplaced(ctx, geometry);
}
} // namespace detail

/// Throw sheaf::Error on failure; calls return void.
struct Throw {
    using Result = void;
    static void check(sheaf_status s, const sheaf_context *ctx) {
        if (s != SHEAF_STATUS_OK) throw Error(s, detail::message(s, ctx));
    }
};

/// Return the sheaf_status; never throw.
struct Return {
    using Result = sheaf_status;
    static sheaf_status check(sheaf_status s, const sheaf_context *) noexcept { return s; }
};

template <class Policy> class BasicContext;

/// Owner of a two-level scene object id (`Remove` removes it).
template <class Policy, void (*Remove)(detail::Scene &, sheaf_context *, uint32_t, uint32_t) noexcept>
class BasicOwnedId {
public:
    BasicOwnedId() noexcept = default;
    BasicOwnedId(const BasicOwnedId &) = delete;
    BasicOwnedId &operator=(const BasicOwnedId &) = delete;
    BasicOwnedId(BasicOwnedId &&o) noexcept
        : ctx_(std::exchange(o.ctx_, nullptr)), id_(o.id_), geometry_(o.geometry_), scene_(std::move(o.scene_)) {}
    BasicOwnedId &operator=(BasicOwnedId &&o) noexcept {
        if (this != &o) {
            reset();
            ctx_ = std::exchange(o.ctx_, nullptr);
            id_ = o.id_;
            geometry_ = o.geometry_;
            scene_ = std::move(o.scene_);
        }
        return *this;
    }
    ~BasicOwnedId() { reset(); }
    /// Whether it owns an id.
    explicit operator bool() const noexcept { return ctx_ != nullptr; }
    uint32_t id() const noexcept { return id_; }
    /// Remove the id now, as the destructor does: never throws; a geometry
    /// still placed by instances is removed with the last of them.
    void reset() noexcept {
        if (ctx_ != nullptr) Remove(*scene_, std::exchange(ctx_, nullptr), id_, geometry_);
        scene_.reset();
    }
    /// Stop owning the id without removing it.
    uint32_t release() noexcept {
        ctx_ = nullptr;
        scene_.reset();
        return id_;
    }

private:
    friend class BasicContext<Policy>;
    BasicOwnedId(sheaf_context *ctx, uint32_t id, uint32_t geometry, std::shared_ptr<detail::Scene> scene) noexcept
        : ctx_(ctx), id_(id), geometry_(geometry), scene_(std::move(scene)) {}
    sheaf_context *ctx_ = nullptr;
    uint32_t id_ = 0;
    // An instance's geometry, whose removal its own removal may complete.
    uint32_t geometry_ = SHEAF_INVALID_ID;
    // Shared with the context's owner and its other id owners; it outlives
    // a BasicContext that released its context.
    std::shared_ptr<detail::Scene> scene_;
};

template <class Policy> using BasicSceneGeometry = BasicOwnedId<Policy, detail::remove_geometry>;
template <class Policy> using BasicInstance = BasicOwnedId<Policy, detail::remove_instance>;

/// Owner of a sheaf_context.
template <class Policy = Throw> class BasicContext {
public:
    using Result = typename Policy::Result;
    using SceneGeometry = BasicSceneGeometry<Policy>;
    using Instance = BasicInstance<Policy>;

    BasicContext() noexcept = default;
    BasicContext(const BasicContext &) = delete;
    BasicContext &operator=(const BasicContext &) = delete;
    BasicContext(BasicContext &&o) noexcept : ctx_(std::exchange(o.ctx_, nullptr)), scene_(std::move(o.scene_)) {}
    BasicContext &operator=(BasicContext &&o) noexcept {
        if (this != &o) {
            reset();
            ctx_ = std::exchange(o.ctx_, nullptr);
            scene_ = std::move(o.scene_);
        }
        return *this;
    }
    ~BasicContext() { reset(); }

    /// Create the context for `limits` (destroying the one held, if any).
    Result create(const sheaf_limits &limits) {
        reset();
        return Policy::check(sheaf_context_create(&limits, &ctx_), nullptr);
    }
    /// `create` with the default limits for `max_triangles`.
    Result create(uint32_t max_triangles) {
        sheaf_limits l;
        sheaf_status s = sheaf_limits_default(max_triangles, &l);
        if (s != SHEAF_STATUS_OK) return Policy::check(s, nullptr);
        return create(l);
    }
    void reset() noexcept {
        if (ctx_ != nullptr) sheaf_context_destroy(std::exchange(ctx_, nullptr));
        scene_.reset();
    }
    sheaf_context *get() const noexcept { return ctx_; }
    sheaf_context *release() noexcept {
        scene_.reset();
        return std::exchange(ctx_, nullptr);
    }
    explicit operator bool() const noexcept { return ctx_ != nullptr; }

    // Single mesh.
    Result set_geometry(const float *vertices, size_t vertex_stride_bytes, uint32_t vertex_count,
                        const uint32_t *indices, uint32_t triangle_count) {
        return check(sheaf_context_set_geometry(ctx_, vertices, vertex_stride_bytes, vertex_count, indices,
                                                triangle_count));
    }
    /// Packed xyz vertices and three indices per triangle.
    Result set_geometry(const std::vector<float> &vertices, const std::vector<uint32_t> &indices) {
        return set_geometry(vertices.data(), 3 * sizeof(float), static_cast<uint32_t>(vertices.size() / 3),
                            indices.data(), static_cast<uint32_t>(indices.size() / 3));
    }
    Result build_grid(const sheaf_grid_params *p = nullptr) { return check(sheaf_context_build_grid(ctx_, p)); }
    Result build_bvh(const sheaf_bvh_params *p = nullptr) { return check(sheaf_context_build_bvh(ctx_, p)); }
    Result build_kd(const sheaf_kd_params *p = nullptr) { return check(sheaf_context_build_kd(ctx_, p)); }
    /// One of `count` threads joining a kd build (`sheaf_context_build_kd_joined`).
    Result build_kd_joined(const sheaf_kd_params *p, uint32_t index, uint32_t count) {
        return check(sheaf_context_build_kd_joined(ctx_, p, index, count));
    }
    Result refit_bvh(const sheaf_refit_params *p = nullptr, sheaf_refit_info *out = nullptr) {
        return check(sheaf_context_refit_bvh(ctx_, p, out));
    }

    // Rays: (pointer, count), vectors, spans.
    Result trace(sheaf_method m, const sheaf_ray *rays, size_t count, sheaf_hit *hits) const {
        return check(sheaf_context_trace(ctx_, m, rays, hits, count));
    }
    Result trace(sheaf_method m, const std::vector<sheaf_ray> &rays, std::vector<sheaf_hit> &hits) const {
        hits.resize(rays.size());
        return trace(m, rays.data(), rays.size(), hits.data());
    }
    Result trace_with(const sheaf_trace_params &p, const sheaf_ray *rays, size_t count, sheaf_hit *hits) const {
        return check(sheaf_context_trace_with(ctx_, &p, rays, hits, count));
    }
    Result occluded(sheaf_method m, const sheaf_ray *rays, size_t count, uint8_t *occluded) const {
        return check(sheaf_context_occluded(ctx_, m, rays, occluded, count));
    }
    Result occluded(sheaf_method m, const std::vector<sheaf_ray> &rays, std::vector<uint8_t> &occluded) const {
        occluded.resize(rays.size());
        return this->occluded(m, rays.data(), rays.size(), occluded.data());
    }
#ifdef SHEAF_HPP_SPAN
    /// `rays` and `hits` must have the same length; otherwise the call
    /// reports SHEAF_STATUS_INVALID_ARGUMENT and traces nothing.
    /// (Checked here, so no context message: the last one is another call's.)
    Result trace(sheaf_method m, std::span<const sheaf_ray> rays, std::span<sheaf_hit> hits) const {
        if (rays.size() != hits.size()) return Policy::check(SHEAF_STATUS_INVALID_ARGUMENT, nullptr);
        return trace(m, rays.data(), rays.size(), hits.data());
    }
    Result occluded(sheaf_method m, std::span<const sheaf_ray> rays, std::span<uint8_t> occluded) const {
        if (rays.size() != occluded.size()) return Policy::check(SHEAF_STATUS_INVALID_ARGUMENT, nullptr);
        return this->occluded(m, rays.data(), rays.size(), occluded.data());
    }
#endif

    // Two-level scenes: the owners remove their ids when destroyed, in any
    // order (a geometry still placed by instances goes with the last of
    // them: see detail::Scene). On success `owner` takes the id (removing
    // another id it held); on failure it is left as it was.
    Result set_scene_geometry(uint32_t id, const sheaf_mesh &mesh, const sheaf_geometry_params *p,
                              SceneGeometry &owner) {
        std::shared_ptr<detail::Scene> scene = shared_scene(); // may throw std::bad_alloc: nothing set yet
        sheaf_status s = sheaf_context_set_scene_geometry(ctx_, id, &mesh, p);
        if (s == SHEAF_STATUS_OK) {
            scene->adopt(id); // an orphan set again is owned again: keep it
            if (!owns(owner, id)) owner = SceneGeometry(ctx_, id, SHEAF_INVALID_ID, scene);
        }
        return check(s);
    }
    /// `transform`: 12 floats, row-major 3x4.
    Result set_instance(uint32_t id, uint32_t geometry, const float *transform, uint32_t mask, Instance &owner) {
        std::shared_ptr<detail::Scene> scene = shared_scene();
        sheaf_status s = sheaf_context_set_instance(ctx_, id, geometry, transform, mask);
        if (s == SHEAF_STATUS_OK) {
            if (owns(owner, id)) {
                // Replaced in place: it may have been the last to place an orphan.
                scene->unplaced(ctx_, std::exchange(owner.geometry_, geometry));
            } else {
                owner = Instance(ctx_, id, geometry, scene);
            }
        }
        return check(s);
    }
    /// Also removes the orphans whose last instance was removed or
    /// replaced other than through its owner (through the C API).
    Result commit_scene(sheaf_scene_info *out = nullptr) {
        if (scene_) scene_->sweep(ctx_);
        return check(sheaf_context_commit_scene(ctx_, out));
    }
    Result trace_scene(const sheaf_trace_params *p, const sheaf_ray *rays, size_t count, sheaf_scene_hit *hits,
                       uint32_t mask = ~0u, uint32_t flags = 0) const {
        return check(sheaf_context_trace_scene(ctx_, p, rays, hits, count, mask, flags));
    }

    // Any-hit filters (sheaf_filter_fn): a C function and its pointer, or a
    // callable `bool(const sheaf_candidate &)` the context refers to (it
    // must outlive its use, be thread-safe and pure, and not throw: an
    // exception escaping it calls std::terminate). nullptr removes it.
    Result set_filter(sheaf_filter_fn f, void *user = nullptr) {
        return check(sheaf_context_set_filter(ctx_, f, user));
    }
    template <class F> Result set_filter(F &filter) { return set_filter(&call<F>, pointer(filter)); }
    Result set_scene_geometry_filter(uint32_t id, sheaf_filter_fn f, void *user = nullptr) {
        return check(sheaf_context_set_scene_geometry_filter(ctx_, id, f, user));
    }
    template <class F> Result set_scene_geometry_filter(uint32_t id, F &filter) {
        return set_scene_geometry_filter(id, &call<F>, pointer(filter));
    }

    Result stats(sheaf_stats &out) const { return check(sheaf_context_stats(ctx_, &out)); }

private:
    Result check(sheaf_status s) const { return Policy::check(s, ctx_); }
    template <class F> static bool call(void *user, const sheaf_candidate *c) noexcept {
        return (*static_cast<F *>(user))(*c);
    }
    // The callable's address as the C user pointer (const callables too:
    // `call<const F>` casts it back to `const F *`).
    template <class F> static void *pointer(F &filter) noexcept {
        return const_cast<void *>(static_cast<const void *>(&filter));
    }
    template <class Owner> bool owns(const Owner &owner, uint32_t id) const noexcept {
        return owner && owner.id() == id && owner.ctx_ == ctx_;
    }
    /// The state this context's id owners share, made with the first.
    const std::shared_ptr<detail::Scene> &shared_scene() {
        if (!scene_) scene_ = std::make_shared<detail::Scene>();
        return scene_;
    }
    sheaf_context *ctx_ = nullptr;
    std::shared_ptr<detail::Scene> scene_;
};

using Context = BasicContext<Throw>;
using ContextNoThrow = BasicContext<Return>;

} // namespace sheaf

#endif // SHEAF_HPP
