// lacuna.hpp: header-only C++17 RAII wrapper of Lacuna's C API (include/lacuna.h).
//
// - Refcounted C objects (Context, Scene, Film) are copyable: a copy retains, destruction
//   releases. Single-owner objects (Mesh, SceneBuilder, RenderJob, Environment) are move-only.
// - Every failing call throws lacuna::Error, which carries the status and the message of
//   lacuna_last_error_message().
// - Callbacks given as std::function run behind trampolines that catch every exception: an
//   exception thrown by a progress callback cancels the render and is rethrown from run().
// Thread safety is that of the C objects (see lacuna.h): a const Scene or Film may be used from
// any number of threads; RenderJob::cancel() may be called from any thread.
#ifndef LACUNA_HPP
#define LACUNA_HPP

#include "lacuna.h"

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace lacuna {

/// A failed Lacuna call: the status and the library's message.
class Error : public std::runtime_error {
public:
    Error(lacuna_status status, const std::string &message)
        : std::runtime_error(message), status_(status) {}
    lacuna_status status() const noexcept { return status_; }
    const char *status_name() const noexcept { return lacuna_status_string(status_); }

private:
    lacuna_status status_;
};

namespace detail {

inline void check(lacuna_status status) {
    if (status != LACUNA_STATUS_OK) throw Error(status, lacuna_last_error_message());
}

/// A refcounted handle: copy = retain, destruction = release.
template <class T, void (*Retain)(const T *), void (*Release)(const T *)>
class Shared {
public:
    Shared() noexcept = default;
    /// Takes over one reference.
    explicit Shared(T *owned) noexcept : p_(owned) {}
    Shared(const Shared &o) noexcept : p_(o.p_) { Retain(p_); }
    Shared(Shared &&o) noexcept : p_(std::exchange(o.p_, nullptr)) {}
    Shared &operator=(Shared o) noexcept {
        std::swap(p_, o.p_);
        return *this;
    }
    ~Shared() { Release(p_); }
    T *get() const noexcept { return p_; }
    explicit operator bool() const noexcept { return p_ != nullptr; }

protected:
    T *p_ = nullptr;
};

template <class T, void (*Free)(T *)>
struct Deleter {
    void operator()(T *p) const noexcept { Free(p); }
};

template <class T, void (*Free)(T *)>
using Owned = std::unique_ptr<T, Deleter<T, Free>>;

}  // namespace detail

inline uint32_t version() noexcept { return lacuna_version(); }
inline std::string version_string() { return lacuna_version_string(); }

inline lacuna_vec3 vec3(float x, float y, float z) noexcept { return lacuna_vec3{x, y, z}; }
inline lacuna_rgb rgb(float r, float g, float b) noexcept { return lacuna_rgb{r, g, b}; }

/// A ray with the C API's defaults (lacuna_ray_init), then the given origin and direction.
inline lacuna_ray make_ray(lacuna_vec3 origin, lacuna_vec3 direction,
                           float tmax = INFINITY) noexcept {
    lacuna_ray r;
    lacuna_ray_init(&r);
    r.origin[0] = origin.x;
    r.origin[1] = origin.y;
    r.origin[2] = origin.z;
    r.direction[0] = direction.x;
    r.direction[1] = direction.y;
    r.direction[2] = direction.z;
    r.tmax = tmax;
    return r;
}

class Context : public detail::Shared<lacuna_context, lacuna_context_retain, lacuna_context_release> {
public:
    using Shared::Shared;
    static Context create() {
        lacuna_context *c = nullptr;
        detail::check(lacuna_context_new(&c));
        return Context(c);
    }
    void set_thread_count(uint32_t n) const { detail::check(lacuna_context_set_thread_count(p_, n)); }
    uint32_t thread_count() const {
        uint32_t n = 0;
        detail::check(lacuna_context_get_thread_count(p_, &n));
        return n;
    }
    void set_memory_budget(uint64_t bytes) const {
        detail::check(lacuna_context_set_memory_budget(p_, bytes));
    }
};

class Mesh {
public:
    Mesh() {
        lacuna_mesh *m = nullptr;
        detail::check(lacuna_mesh_new(&m));
        m_.reset(m);
    }
    Mesh &name(const std::string &n) {
        detail::check(lacuna_mesh_set_name(m_.get(), n.c_str()));
        return *this;
    }
    Mesh &positions(const float *data, size_t count, size_t byte_stride = 0) {
        detail::check(lacuna_mesh_set_positions(m_.get(), data, byte_stride, count));
        return *this;
    }
    Mesh &normals(const float *data, size_t count, size_t byte_stride = 0) {
        detail::check(lacuna_mesh_set_normals(m_.get(), data, byte_stride, count));
        return *this;
    }
    Mesh &uvs(const float *data, size_t count, size_t byte_stride = 0) {
        detail::check(lacuna_mesh_set_uvs(m_.get(), data, byte_stride, count));
        return *this;
    }
    Mesh &indices(const uint32_t *data, size_t triangles, size_t byte_stride = 0) {
        detail::check(lacuna_mesh_set_indices(m_.get(), data, byte_stride, triangles));
        return *this;
    }
    Mesh &materials(const uint32_t *data, size_t count, size_t byte_stride = 0) {
        detail::check(lacuna_mesh_set_materials(m_.get(), data, byte_stride, count));
        return *this;
    }
    Mesh &material(uint32_t index) {
        detail::check(lacuna_mesh_set_material(m_.get(), index));
        return *this;
    }
    const lacuna_mesh *get() const noexcept { return m_.get(); }

private:
    detail::Owned<lacuna_mesh, lacuna_mesh_free> m_;
};

/// An environment map (move-only): from a file or a float buffer (copied), updated in place.
class Environment {
public:
    static Environment from_file(const std::string &path) {
        lacuna_environment *e = nullptr;
        detail::check(lacuna_environment_new_from_file(path.c_str(), &e));
        return Environment(e);
    }
    /// `width` x `height` RGB floats in `layout` (a lacuna_environment_layout value).
    static Environment from_buffer(const float *texels, size_t width, size_t height, uint32_t layout,
                                   size_t pixel_stride = 0, size_t row_stride = 0) {
        lacuna_environment *e = nullptr;
        detail::check(lacuna_environment_new_from_buffer(texels, width, height, pixel_stride, row_stride, layout, &e));
        return Environment(e);
    }
    /// Replaces the texels (same size and layout); returns the rebuild time in seconds.
    double update(const float *texels, size_t width, size_t height, uint32_t layout, size_t pixel_stride = 0,
                  size_t row_stride = 0) {
        double seconds = 0;
        detail::check(lacuna_environment_update(e_.get(), texels, width, height, pixel_stride, row_stride, layout,
                                                &seconds));
        return seconds;
    }
    Environment &placement(float scale, float rotate_degrees, uint32_t up_axis = LACUNA_UP_AXIS_Y) {
        detail::check(lacuna_environment_set_placement(e_.get(), scale, rotate_degrees, up_axis));
        return *this;
    }
    Environment &visible(bool v) {
        detail::check(lacuna_environment_set_visible(e_.get(), v));
        return *this;
    }
    Environment &prepare(uint32_t strategy) {
        detail::check(lacuna_environment_prepare(e_.get(), strategy));
        return *this;
    }
    lacuna_environment_info info() const {
        lacuna_environment_info i;
        detail::check(lacuna_environment_get_info(e_.get(), &i));
        return i;
    }
    lacuna_environment *get() const noexcept { return e_.get(); }

private:
    explicit Environment(lacuna_environment *e) : e_(e) {}
    detail::Owned<lacuna_environment, lacuna_environment_free> e_;
};

/// A measured luminaire's intensity distribution (IES LM-63 type C, or EULUMDAT). Copyable (copy =
/// retain); immutable and thread-safe.
class PhotometricProfile
    : public detail::Shared<lacuna_photometric_profile, lacuna_photometric_profile_retain,
                            lacuna_photometric_profile_release> {
public:
    using Shared::Shared;
    /// An IES file, or EULUMDAT when the name ends in .ldt.
    static PhotometricProfile from_file(const std::string &path) {
        lacuna_photometric_profile *p = nullptr;
        detail::check(lacuna_photometric_profile_new_from_file(path.c_str(), &p));
        return PhotometricProfile(p);
    }
    static PhotometricProfile from_ies_buffer(const void *data, size_t size) {
        lacuna_photometric_profile *p = nullptr;
        detail::check(lacuna_photometric_profile_new_from_ies_buffer(static_cast<const uint8_t *>(data), size, &p));
        return PhotometricProfile(p);
    }
    static PhotometricProfile from_ldt_buffer(const void *data, size_t size) {
        lacuna_photometric_profile *p = nullptr;
        detail::check(lacuna_photometric_profile_new_from_ldt_buffer(static_cast<const uint8_t *>(data), size, &p));
        return PhotometricProfile(p);
    }
    lacuna_photometric_profile_info info() const {
        lacuna_photometric_profile_info i;
        detail::check(lacuna_photometric_profile_get_info(p_, &i));
        return i;
    }
    /// Candela towards `local_direction` (+Z nadir, +X C0, +Y C90).
    float intensity(lacuna_vec3 local_direction) const {
        float c = 0;
        detail::check(lacuna_photometric_profile_intensity(p_, local_direction, &c));
        return c;
    }
    /// A direction in the profile's frame and its solid-angle density.
    std::pair<lacuna_vec3, float> sample(float u0, float u1) const {
        lacuna_vec3 d;
        float pdf = 0;
        detail::check(lacuna_photometric_profile_sample(p_, u0, u1, &d, &pdf));
        return {d, pdf};
    }
    float pdf(lacuna_vec3 local_direction) const {
        float pdf = 0;
        detail::check(lacuna_photometric_profile_pdf(p_, local_direction, &pdf));
        return pdf;
    }
};

/// A light-field luminaire (two planes of images; docs/light-field.md). Copyable (copy =
/// retain); immutable and thread-safe.
class LightField
    : public detail::Shared<lacuna_light_field, lacuna_light_field_retain, lacuna_light_field_release> {
public:
    using Shared::Shared;
    /// An EXR mosaic with `lacuna:light_field.*` attributes.
    static LightField from_file(const std::string &path) {
        lacuna_light_field *f = nullptr;
        detail::check(lacuna_light_field_new_from_file(path.c_str(), &f));
        return LightField(f);
    }
    /// `rgb`: 3 floats per pixel, image after image (see lacuna_light_field_new_from_buffer).
    static LightField from_buffer(const lacuna_light_field_layout &layout, const float *rgb, size_t float_count) {
        lacuna_light_field *f = nullptr;
        detail::check(lacuna_light_field_new_from_buffer(&layout, rgb, float_count, &f));
        return LightField(f);
    }
    lacuna_light_field_info info() const {
        lacuna_light_field_info i;
        detail::check(lacuna_light_field_get_info(p_, &i));
        return i;
    }
    struct Sample {
        lacuna_vec3 point;
        lacuna_rgb radiance;
        /// Solid angle at the receiver; 0 when the receiver is not lit.
        float pdf;
    };
    /// A point of the image plane toward `receiver` (the field's frame).
    Sample sample(lacuna_vec3 receiver, float u0, float u1) const {
        Sample s{};
        detail::check(lacuna_light_field_sample(p_, receiver, u0, u1, &s.point, &s.radiance, &s.pdf));
        return s;
    }
    float pdf(lacuna_vec3 receiver, lacuna_vec3 point) const {
        float pdf = 0;
        detail::check(lacuna_light_field_pdf(p_, receiver, point, &pdf));
        return pdf;
    }
};

class Scene : public detail::Shared<lacuna_scene, lacuna_scene_retain, lacuna_scene_release> {
public:
    using Shared::Shared;
    lacuna_hit intersect(const lacuna_ray &ray) const {
        lacuna_hit h;
        detail::check(lacuna_scene_intersect(p_, &ray, &h));
        return h;
    }
    bool occluded(const lacuna_ray &ray) const {
        bool o = false;
        detail::check(lacuna_scene_occluded(p_, &ray, &o));
        return o;
    }
    std::vector<lacuna_hit> intersect(const std::vector<lacuna_ray> &rays) const {
        std::vector<lacuna_hit> hits(rays.size());
        detail::check(lacuna_scene_intersect_batch(p_, rays.data(), 0, rays.size(), hits.data(), 0));
        return hits;
    }
    std::vector<bool> occluded(const std::vector<lacuna_ray> &rays) const {
        std::unique_ptr<bool[]> o(new bool[rays.size() ? rays.size() : 1]);
        detail::check(lacuna_scene_occluded_batch(p_, rays.data(), 0, rays.size(), o.get()));
        return std::vector<bool>(o.get(), o.get() + rays.size());
    }
    lacuna_memory_report memory() const {
        lacuna_memory_report r;
        detail::check(lacuna_scene_get_memory_report(p_, &r));
        return r;
    }
    lacuna_scene_stats stats() const {
        lacuna_scene_stats s;
        detail::check(lacuna_scene_get_stats(p_, &s));
        return s;
    }
    /// The same scene lit by (a snapshot of) `env` instead (nullptr: no environment).
    Scene with_environment(const Environment *env) const {
        lacuna_scene *s = nullptr;
        detail::check(lacuna_scene_new_with_environment(p_, env ? env->get() : nullptr, &s));
        return Scene(s);
    }
    /// The surface point and material at a hit of this scene.
    lacuna_surface surface(const lacuna_hit &hit) const {
        lacuna_surface s;
        detail::check(lacuna_scene_get_surface(p_, &hit, &s));
        return s;
    }
    /// The scene's camera (throws when it has none).
    lacuna_camera camera() const {
        lacuna_camera c;
        detail::check(lacuna_scene_get_camera(p_, &c));
        return c;
    }
};

/// Lacuna's light sampling at a host's own shading points (see `lacuna_light_sampler` in
/// lacuna.h for the MIS conventions). Copyable (copy = retain); thread-safe; no call allocates
/// except the vector-returning batch helpers.
class LightSampler
    : public detail::Shared<lacuna_light_sampler, lacuna_light_sampler_retain, lacuna_light_sampler_release> {
public:
    using Shared::Shared;
    explicit LightSampler(const Scene &scene, uint32_t triangle_strategy = LACUNA_TRIANGLE_STRATEGY_AREA,
                          uint32_t environment_strategy = LACUNA_ENVIRONMENT_STRATEGY_AUTO) {
        lacuna_light_sampler *s = nullptr;
        detail::check(lacuna_light_sampler_new(scene.get(), triangle_strategy, environment_strategy, &s));
        p_ = s;
    }
    lacuna_light_sampler_info info() const {
        lacuna_light_sampler_info i;
        detail::check(lacuna_light_sampler_get_info(p_, &i));
        return i;
    }
    lacuna_light_info light_info(uint32_t light) const {
        lacuna_light_info i;
        detail::check(lacuna_light_sampler_get_light_info(p_, light, &i));
        return i;
    }
    /// The light of an emissive triangle, or LACUNA_INVALID_INDEX.
    uint32_t triangle_light(uint32_t triangle) const {
        uint32_t l = 0;
        detail::check(lacuna_light_sampler_get_triangle_light(p_, triangle, &l));
        return l;
    }
    lacuna_light_sample sample(const lacuna_light_query &query) const {
        lacuna_light_sample s;
        detail::check(lacuna_light_sampler_sample(p_, &query, &s));
        return s;
    }
    lacuna_light_eval eval(const lacuna_light_query &query, const lacuna_light_hit &hit) const {
        lacuna_light_eval e;
        detail::check(lacuna_light_sampler_eval(p_, &query, &hit, &e));
        return e;
    }
    lacuna_emission_sample sample_emission(const float (&u)[4]) const {
        lacuna_emission_sample e;
        detail::check(lacuna_light_sampler_sample_emission(p_, u, &e));
        return e;
    }
    /// (pdf_position, pdf_direction) of light `light` emitting along `direction`.
    std::pair<float, float> emission_pdf(uint32_t light, lacuna_vec3 direction) const {
        float pos = 0, dir = 0;
        detail::check(lacuna_light_sampler_emission_pdf(p_, light, direction, &pos, &dir));
        return {pos, dir};
    }
    /// (pdf_position, pdf_direction) of light `light` emitting from `origin` along `direction`
    /// (a light field's densities depend on the origin).
    std::pair<float, float> emission_pdf_at(uint32_t light, lacuna_vec3 origin, lacuna_vec3 direction) const {
        float pos = 0, dir = 0;
        detail::check(lacuna_light_sampler_emission_pdf_at(p_, light, origin, direction, &pos, &dir));
        return {pos, dir};
    }
    std::vector<lacuna_light_sample> sample(const std::vector<lacuna_light_query> &queries) const {
        std::vector<lacuna_light_sample> out(queries.size());
        detail::check(lacuna_light_sampler_sample_batch(p_, queries.data(), 0, queries.size(), out.data(), 0));
        return out;
    }
    std::vector<lacuna_light_eval> eval(const std::vector<lacuna_light_query> &queries,
                                        const std::vector<lacuna_light_hit> &hits) const {
        if (queries.size() != hits.size()) throw Error(LACUNA_STATUS_INVALID_ARGUMENT, "queries and hits differ in size");
        std::vector<lacuna_light_eval> out(queries.size());
        detail::check(lacuna_light_sampler_eval_batch(p_, queries.data(), 0, hits.data(), 0, queries.size(), out.data(), 0));
        return out;
    }
};

class SceneBuilder {
public:
    explicit SceneBuilder(const Context &ctx) {
        lacuna_scene_builder *b = nullptr;
        detail::check(lacuna_scene_builder_new(ctx.get(), &b));
        b_.reset(b);
    }
    /// A builder filled from a JSON scene file.
    static SceneBuilder from_file(const Context &ctx, const std::string &path) {
        lacuna_scene_builder *b = nullptr;
        detail::check(lacuna_scene_builder_new_from_file(ctx.get(), path.c_str(), &b));
        return SceneBuilder(b);
    }
    /// A built-in scene ("two-rooms", "corridor").
    static SceneBuilder builtin(const Context &ctx, const std::string &name) {
        lacuna_scene_builder *b = nullptr;
        detail::check(lacuna_scene_builder_new_builtin(ctx.get(), name.c_str(), &b));
        return SceneBuilder(b);
    }
    uint32_t add_material(uint32_t kind) {
        uint32_t i = 0;
        detail::check(lacuna_scene_builder_add_material(b_.get(), kind, &i));
        return i;
    }
    SceneBuilder &set_material_rgb(uint32_t index, uint32_t param, lacuna_rgb value) {
        detail::check(lacuna_scene_builder_set_material_rgb(b_.get(), index, param, value));
        return *this;
    }
    SceneBuilder &set_material_float(uint32_t index, uint32_t param, float value) {
        detail::check(lacuna_scene_builder_set_material_float(b_.get(), index, param, value));
        return *this;
    }
    SceneBuilder &set_material_name(uint32_t index, const std::string &name) {
        detail::check(lacuna_scene_builder_set_material_name(b_.get(), index, name.c_str()));
        return *this;
    }
    uint32_t material_count() const {
        uint32_t n = 0;
        detail::check(lacuna_scene_builder_get_material_count(b_.get(), &n));
        return n;
    }
    uint32_t add_mesh(const Mesh &mesh) {
        uint32_t i = 0;
        detail::check(lacuna_scene_builder_add_mesh(b_.get(), mesh.get(), &i));
        return i;
    }
    SceneBuilder &add_point_light(lacuna_vec3 position, lacuna_rgb intensity) {
        detail::check(lacuna_scene_builder_add_point_light(b_.get(), position, intensity));
        return *this;
    }
    SceneBuilder &add_spot_light(lacuna_vec3 position, lacuna_vec3 direction, lacuna_rgb intensity,
                                 float inner_degrees, float outer_degrees) {
        detail::check(lacuna_scene_builder_add_spot_light(b_.get(), position, direction, intensity,
                                                          inner_degrees, outer_degrees));
        return *this;
    }
    SceneBuilder &add_photometric_light(const PhotometricProfile &profile, lacuna_vec3 position,
                                        lacuna_vec3 direction, lacuna_vec3 c0, lacuna_rgb intensity) {
        detail::check(lacuna_scene_builder_add_photometric_light(b_.get(), profile.get(), position, direction, c0,
                                                                 intensity));
        return *this;
    }
    SceneBuilder &add_light_field_light(const LightField &field, lacuna_vec3 position, lacuna_vec3 direction,
                                        lacuna_vec3 x_axis, lacuna_rgb scale) {
        detail::check(lacuna_scene_builder_add_light_field_light(b_.get(), field.get(), position, direction, x_axis,
                                                                 scale));
        return *this;
    }
    SceneBuilder &add_directional_light(lacuna_vec3 direction, lacuna_rgb irradiance) {
        detail::check(lacuna_scene_builder_add_directional_light(b_.get(), direction, irradiance));
        return *this;
    }
    SceneBuilder &set_camera(lacuna_vec3 eye, lacuna_vec3 target, lacuna_vec3 up, float vfov_degrees) {
        detail::check(lacuna_scene_builder_set_camera(b_.get(), eye, target, up, vfov_degrees));
        return *this;
    }
    SceneBuilder &set_camera_lens(float lens_radius, float focus_distance) {
        detail::check(lacuna_scene_builder_set_camera_lens(b_.get(), lens_radius, focus_distance));
        return *this;
    }
    SceneBuilder &set_degenerate_policy(uint32_t policy) {
        detail::check(lacuna_scene_builder_set_degenerate_policy(b_.get(), policy));
        return *this;
    }
    SceneBuilder &set_bvh_quality(uint32_t quality) {
        detail::check(lacuna_scene_builder_set_bvh_quality(b_.get(), quality));
        return *this;
    }
    /// Loads an OBJ file; `transform` is NULL or 16 floats (column-major). Returns the
    /// triangles added.
    size_t load_obj(const std::string &path, const float *transform = nullptr) {
        size_t n = 0;
        detail::check(lacuna_scene_builder_load_obj(b_.get(), path.c_str(), transform, &n));
        return n;
    }
    /// Lights the scene with (a snapshot of) `env`; nullptr removes the environment.
    SceneBuilder &set_environment(const Environment *env) {
        detail::check(lacuna_scene_builder_set_environment(b_.get(), env ? env->get() : nullptr));
        return *this;
    }
    /// Builds the scene; the builder is consumed (empty afterwards) whatever the outcome.
    Scene build() {
        lacuna_scene *s = nullptr;
        detail::check(lacuna_scene_builder_build(b_.release(), &s));
        return Scene(s);
    }
    explicit operator bool() const noexcept { return b_ != nullptr; }

private:
    explicit SceneBuilder(lacuna_scene_builder *b) : b_(b) {}
    detail::Owned<lacuna_scene_builder, lacuna_scene_builder_free> b_;
};

class Film : public detail::Shared<lacuna_film, lacuna_film_retain, lacuna_film_release> {
public:
    using Shared::Shared;
    static Film load_exr(const Context &ctx, const std::string &path) {
        lacuna_film *f = nullptr;
        detail::check(lacuna_film_load_exr(ctx.get(), path.c_str(), &f));
        return Film(f);
    }
    uint32_t width() const { return size().first; }
    uint32_t height() const { return size().second; }
    std::pair<uint32_t, uint32_t> size() const {
        uint32_t w = 0, h = 0;
        detail::check(lacuna_film_get_size(p_, &w, &h));
        return {w, h};
    }
    /// A channel, packed: 3 floats per pixel (radiance, albedo, normal) or 1 (depth, samples).
    std::vector<float> read(uint32_t channel = LACUNA_FILM_CHANNEL_RADIANCE) const {
        auto [w, h] = size();
        size_t comps = (channel == LACUNA_FILM_CHANNEL_DEPTH || channel == LACUNA_FILM_CHANNEL_SAMPLE_COUNT) ? 1 : 3;
        std::vector<float> v(size_t(w) * h * comps);
        detail::check(lacuna_film_read(p_, channel, v.data(), w, h, 0, 0));
        return v;
    }
    void read(uint32_t channel, float *dst, size_t width, size_t height, size_t pixel_stride,
              size_t row_stride) const {
        detail::check(lacuna_film_read(p_, channel, dst, width, height, pixel_stride, row_stride));
    }
    /// The image of bdpt strategy (s, t), weighted or not, packed RGB (films of jobs with
    /// strategy_images()).
    std::vector<float> read_strategy_image(uint32_t s, uint32_t t, bool weighted) const {
        auto [w, h] = size();
        std::vector<float> v(size_t(w) * h * 3);
        detail::check(lacuna_film_read_strategy_image(p_, s, t, weighted, v.data(), w, h, 0, 0));
        return v;
    }
    void write_exr(const std::string &path) const { detail::check(lacuna_film_write_exr(p_, path.c_str())); }
    void write_png(const std::string &path, float exposure = 0) const {
        detail::check(lacuna_film_write_png(p_, path.c_str(), exposure));
    }
    lacuna_render_stats stats() const {
        lacuna_render_stats s;
        detail::check(lacuna_film_get_stats(p_, &s));
        return s;
    }
    size_t memory_bytes() const {
        size_t b = 0;
        detail::check(lacuna_film_get_memory_bytes(p_, &b));
        return b;
    }
};

class RenderJob {
public:
    /// A job rendering `scene` with the integrator named `integrator` (nullptr: the scene
    /// file's or "path").
    explicit RenderJob(const Scene &scene, const char *integrator = "path")
        : progress_(new ProgressState) {
        lacuna_render_job *j = nullptr;
        detail::check(lacuna_render_job_new(scene.get(), integrator, &j));
        j_.reset(j);
    }
    RenderJob &samples_per_pixel(uint32_t spp) { return set(lacuna_render_job_set_samples_per_pixel(j_.get(), spp)); }
    RenderJob &time_budget(double seconds) { return set(lacuna_render_job_set_time_budget(j_.get(), seconds)); }
    RenderJob &seed(uint64_t seed) { return set(lacuna_render_job_set_seed(j_.get(), seed)); }
    RenderJob &max_depth(uint32_t depth) { return set(lacuna_render_job_set_max_depth(j_.get(), depth)); }
    RenderJob &resolution(uint32_t w, uint32_t h) { return set(lacuna_render_job_set_resolution(j_.get(), w, h)); }
    RenderJob &threads(uint32_t n) { return set(lacuna_render_job_set_thread_count(j_.get(), n)); }
    RenderJob &mis_heuristic(uint32_t h) { return set(lacuna_render_job_set_mis_heuristic(j_.get(), h)); }
    /// The heuristic the job renders with (set, or the integrator's default).
    uint32_t mis_heuristic() const {
        uint32_t h = 0;
        detail::check(lacuna_render_job_get_mis_heuristic(j_.get(), &h));
        return h;
    }
    RenderJob &environment_strategy(uint32_t s) {
        return set(lacuna_render_job_set_environment_strategy(j_.get(), s));
    }
    RenderJob &environment_samples(uint32_t light, uint32_t bsdf) {
        return set(lacuna_render_job_set_environment_samples(j_.get(), light, bsdf));
    }
    RenderJob &camera(lacuna_vec3 eye, lacuna_vec3 target, lacuna_vec3 up, float vfov_degrees) {
        return set(lacuna_render_job_set_camera(j_.get(), eye, target, up, vfov_degrees));
    }
    RenderJob &thin_lens(float lens_radius, float focus_distance) {
        return set(lacuna_render_job_set_thin_lens(j_.get(), lens_radius, focus_distance));
    }
    /// bdpt: light subpaths per iteration (0 = one per pixel).
    RenderJob &light_paths(uint32_t count) { return set(lacuna_render_job_set_light_paths(j_.get(), count)); }
    /// bdpt_skeleton and bdpt_ic: resample from the first `subset` light subpaths (N).
    RenderJob &resampling_subset(uint32_t subset) {
        return set(lacuna_render_job_set_resampling_subset(j_.get(), subset));
    }
    /// bdpt_skeleton: node acceptance alpha_accept (>= 0).
    RenderJob &resampling_accept(float accept) {
        return set(lacuna_render_job_set_resampling_accept(j_.get(), accept));
    }
    /// bdpt_skeleton and bdpt_ic: one image per resampling distribution (002 Figure 10).
    RenderJob &resampling_images(bool enabled) {
        return set(lacuna_render_job_set_resampling_images(j_.get(), enabled));
    }
    /// bdpt_ic: importance-record density d in (0, 1].
    RenderJob &record_density(float density) {
        return set(lacuna_render_job_set_record_density(j_.get(), density));
    }
    uint32_t resampling_subset() const {
        uint32_t v = 0;
        detail::check(lacuna_render_job_get_resampling_subset(j_.get(), &v));
        return v;
    }
    float resampling_accept() const {
        float v = 0;
        detail::check(lacuna_render_job_get_resampling_accept(j_.get(), &v));
        return v;
    }
    bool resampling_images() const {
        bool v = false;
        detail::check(lacuna_render_job_get_resampling_images(j_.get(), &v));
        return v;
    }
    float record_density() const {
        float v = 0;
        detail::check(lacuna_render_job_get_record_density(j_.get(), &v));
        return v;
    }
    /// bdpt: render only strategy (s, t); clear_strategy_filter() renders all again.
    RenderJob &strategy_filter(uint32_t s, uint32_t t, bool unweighted) {
        return set(lacuna_render_job_set_strategy_filter(j_.get(), s, t, unweighted));
    }
    RenderJob &clear_strategy_filter() { return set(lacuna_render_job_clear_strategy_filter(j_.get())); }
    /// bdpt: also render every strategy's image for paths up to max_length segments (0 = off).
    RenderJob &strategy_images(uint32_t max_length) {
        return set(lacuna_render_job_set_strategy_images(j_.get(), max_length));
    }
    /// Progress callback: runs on worker threads (one call at a time); return false to
    /// cancel. An exception it throws cancels the render and is rethrown by run().
    RenderJob &on_progress(std::function<bool(double)> fn) {
        progress_->fn = std::move(fn);
        if (progress_->fn)
            return set(lacuna_render_job_set_progress_callback(j_.get(), &trampoline, progress_.get()));
        return set(lacuna_render_job_set_progress_callback(j_.get(), nullptr, nullptr));
    }
    /// Asks a run to stop; callable from any thread.
    void cancel() const noexcept { (void)lacuna_render_job_cancel(j_.get()); }
    /// Renders; throws Error with LACUNA_STATUS_CANCELLED when cancelled.
    Film run() {
        lacuna_film *f = nullptr;
        finish(lacuna_render_job_run(j_.get(), &f));
        return Film(f);
    }
    /// After a cancelled run: the passes completed before the cancellation.
    Film take_partial_film() {
        lacuna_film *f = nullptr;
        detail::check(lacuna_render_job_take_partial_film(j_.get(), &f));
        return Film(f);
    }
    Film run_reference(lacuna_image_errors *noise = nullptr) {
        lacuna_film *f = nullptr;
        finish(lacuna_render_job_run_reference(j_.get(), &f, noise));
        return Film(f);
    }
    /// How `compare` runs its contenders: a `lacuna_compare_schedule` value.
    RenderJob &compare_schedule(uint32_t s) { return set(lacuna_render_job_set_compare_schedule(j_.get(), s)); }
    uint32_t compare_schedule() const {
        uint32_t s = 0;
        detail::check(lacuna_render_job_get_compare_schedule(j_.get(), &s));
        return s;
    }
    void compare(const std::vector<std::string> &integrators, const Film &reference, double seconds_per_run,
                 uint32_t runs, const std::string &out_dir) {
        std::vector<const char *> names;
        for (const auto &n : integrators) names.push_back(n.c_str());
        finish(lacuna_render_job_compare(j_.get(), names.data(), names.size(), reference.get(), seconds_per_run,
                                         runs, out_dir.c_str()));
    }
    lacuna_render_stats stats() const {
        lacuna_render_stats s;
        detail::check(lacuna_render_job_get_stats(j_.get(), &s));
        return s;
    }
    lacuna_render_job *get() const noexcept { return j_.get(); }

private:
    struct ProgressState {
        std::function<bool(double)> fn;
        std::exception_ptr error;
    };
    static bool trampoline(void *user, double fraction) noexcept {
        auto *s = static_cast<ProgressState *>(user);
        try {
            return s->fn(fraction);
        } catch (...) {
            s->error = std::current_exception();
            return false;
        }
    }
    RenderJob &set(lacuna_status s) {
        detail::check(s);
        return *this;
    }
    void finish(lacuna_status s) {
        if (progress_->error) {
            std::exception_ptr e = std::exchange(progress_->error, nullptr);
            std::rethrow_exception(e);
        }
        detail::check(s);
    }
    std::unique_ptr<ProgressState> progress_;
    detail::Owned<lacuna_render_job, lacuna_render_job_free> j_;
};

}  // namespace lacuna

#endif  // LACUNA_HPP
