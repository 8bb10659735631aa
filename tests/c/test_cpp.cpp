// Tests of the C++ wrapper bindings/cpp/lacuna.hpp: RAII and refcounting, exceptions with the
// library's message, callback trampolines that catch exceptions, cancellation from another
// thread. Built and run by tests/c_api.rs (plain, under AddressSanitizer and valgrind).
#include "lacuna.hpp"
#include "lacuna.hpp"  // twice: include guards

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>
#include <type_traits>

static int passed, failed;

#define CHECK(cond)                                                                      \
    do {                                                                                 \
        if (cond) {                                                                      \
            passed++;                                                                    \
        } else {                                                                         \
            failed++;                                                                    \
            std::fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
        }                                                                                \
    } while (0)

// Runs `f`, expecting lacuna::Error with `status` and a message containing `needle`.
template <class F>
static void expect_error(F &&f, lacuna_status status, const char *needle, int line) {
    try {
        f();
        failed++;
        std::fprintf(stderr, "%s:%d: no exception\n", __FILE__, line);
    } catch (const lacuna::Error &e) {
        bool ok = e.status() == status && std::strstr(e.what(), needle) != nullptr;
        if (ok) {
            passed++;
        } else {
            failed++;
            std::fprintf(stderr, "%s:%d: got %s \"%s\"\n", __FILE__, line, e.status_name(), e.what());
        }
    }
}
#define EXPECT_ERROR(expr, status, needle) expect_error([&] { expr; }, status, needle, __LINE__)

static_assert(std::is_copy_constructible_v<lacuna::Context>, "refcounted handles copy");
static_assert(std::is_copy_constructible_v<lacuna::Scene>, "refcounted handles copy");
static_assert(std::is_copy_constructible_v<lacuna::Film>, "refcounted handles copy");
static_assert(!std::is_copy_constructible_v<lacuna::SceneBuilder>, "owners are move-only");
static_assert(!std::is_copy_constructible_v<lacuna::RenderJob>, "owners are move-only");
static_assert(!std::is_copy_constructible_v<lacuna::Mesh>, "owners are move-only");
static_assert(!std::is_copy_constructible_v<lacuna::Environment>, "owners are move-only");
static_assert(std::is_nothrow_move_constructible_v<lacuna::Scene>, "moves do not throw");

static lacuna::Scene box(const lacuna::Context &ctx) {
    static const float p[8][3] = {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1},
                                  {-1, -1, 1},  {1, -1, 1},  {1, 1, 1},  {-1, 1, 1}};
    static const uint32_t i[12][3] = {{0, 2, 1}, {0, 3, 2}, {4, 5, 6}, {4, 6, 7}, {0, 1, 5}, {0, 5, 4},
                                      {3, 6, 2}, {3, 7, 6}, {0, 4, 7}, {0, 7, 3}, {1, 2, 6}, {1, 6, 5}};
    lacuna::SceneBuilder b(ctx);
    uint32_t white = b.add_material(LACUNA_MATERIAL_KIND_DIFFUSE);
    lacuna::Mesh m;
    m.positions(&p[0][0], 8).indices(&i[0][0], 12).material(white).name("box");
    b.add_mesh(m);
    b.add_point_light(lacuna::vec3(0, 0.5f, 0), lacuna::rgb(2, 2, 2));
    b.set_camera(lacuna::vec3(0, 0, 0.9f), lacuna::vec3(0, 0, -1), lacuna::vec3(0, 1, 0), 70);
    lacuna::Scene s = b.build();
    CHECK(!b);  // consumed
    return s;
}

// Environment maps: buffers, errors as exceptions, snapshots in scenes, updates.
static void test_environment(const lacuna::Context &ctx) {
    std::vector<float> sky(8 * 4 * 3, 1.0f);
    lacuna::Environment env = lacuna::Environment::from_buffer(sky.data(), 8, 4, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG);
    CHECK(env.info().width == 8 && env.info().height == 4);
    EXPECT_ERROR(lacuna::Environment::from_buffer(sky.data(), 8, 3, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG),
                 LACUNA_STATUS_INVALID_ARGUMENT, "lat-long");
    EXPECT_ERROR(env.placement(-1, 0), LACUNA_STATUS_INVALID_ARGUMENT, "scale");
    EXPECT_ERROR(lacuna::Environment::from_file("/nonexistent/sky.hdr"), LACUNA_STATUS_IO, "sky.hdr");
    env.placement(1, 45, LACUNA_UP_AXIS_Z).prepare(LACUNA_ENVIRONMENT_STRATEGY_CUBE_DYNAMIC);
    CHECK(env.info().cube_build_seconds > 0);
    lacuna::SceneBuilder b(ctx);
    b.set_camera(lacuna::vec3(0, 0, 0), lacuna::vec3(0, 0, -1), lacuna::vec3(0, 1, 0), 40).set_environment(&env);
    lacuna::Scene scene = b.build();
    lacuna::RenderJob job(scene, "path");
    job.resolution(4, 4).samples_per_pixel(1).environment_strategy(LACUNA_ENVIRONMENT_STRATEGY_LAT_LONG);
    EXPECT_ERROR(job.environment_strategy(99), LACUNA_STATUS_INVALID_ARGUMENT, "strategy");
    EXPECT_ERROR(job.environment_samples(0, 0), LACUNA_STATUS_INVALID_ARGUMENT, "both 0");
    CHECK(job.run().read()[0] == 1.0f);
    std::fill(sky.begin(), sky.end(), 3.0f);
    CHECK(env.update(sky.data(), 8, 4, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG) >= 0);
    EXPECT_ERROR(env.update(sky.data(), 4, 2, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG), LACUNA_STATUS_INVALID_ARGUMENT,
                 "new environment");
    lacuna::Scene brighter = scene.with_environment(&env);
    CHECK(lacuna::RenderJob(brighter, "path").resolution(4, 4).samples_per_pixel(1).run().read()[0] == 3.0f);
    CHECK(lacuna::RenderJob(scene.with_environment(nullptr), "path").resolution(4, 4).samples_per_pixel(1).run().read()[0] == 0.0f);
}

// Photometric profiles: loading from memory, errors as exceptions, queries, a light in a scene.
static void test_photometric(const lacuna::Context &ctx) {
    static const char ies[] =
        "IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 3 1 1 2 0 0 0\n1 1 10\n0 45 90\n0\n100 50 0\n";
    lacuna::PhotometricProfile p = lacuna::PhotometricProfile::from_ies_buffer(ies, sizeof ies - 1);
    lacuna::PhotometricProfile copy = p;
    CHECK(copy.get() == p.get());
    CHECK(p.info().symmetry == LACUNA_PHOTOMETRIC_SYMMETRY_ROTATIONAL && p.info().peak_candela == 100.0f);
    CHECK(p.intensity(lacuna::vec3(0, 0, 1)) == 100.0f);
    auto [d, pdf] = p.sample(0.25f, 0.5f);
    CHECK(pdf > 0 && std::fabs(p.pdf(d) - pdf) <= 1e-3f * pdf);
    EXPECT_ERROR(lacuna::PhotometricProfile::from_ies_buffer(ies, 28), LACUNA_STATUS_PARSE, "ends before the lumens");
    EXPECT_ERROR(lacuna::PhotometricProfile::from_file("/nonexistent/lamp.ies"), LACUNA_STATUS_IO, "lamp.ies");
    EXPECT_ERROR(p.sample(1.5f, 0), LACUNA_STATUS_OUT_OF_RANGE, "u0");
    EXPECT_ERROR(lacuna::PhotometricProfile::from_ldt_buffer(ies, sizeof ies - 1), LACUNA_STATUS_PARSE, "line");
    lacuna::SceneBuilder b(ctx);
    EXPECT_ERROR(b.add_photometric_light(p, lacuna::vec3(0, 0, 0), lacuna::vec3(0, 0, 0), lacuna::vec3(1, 0, 0),
                                         lacuna::rgb(1, 1, 1)),
                 LACUNA_STATUS_INVALID_ARGUMENT, "direction");
    b.add_photometric_light(p, lacuna::vec3(0, 1, 0), lacuna::vec3(0, -1, 0), lacuna::vec3(1, 0, 0),
                            lacuna::rgb(1, 1, 1));
    b.set_camera(lacuna::vec3(0, 0, 2), lacuna::vec3(0, 0, 0), lacuna::vec3(0, 1, 0), 40);
    lacuna::LightSampler lights(b.build());
    CHECK(lights.info().light_count == 1);
}

// Light fields: built from a host buffer, errors as exceptions, sampling, a light in a scene.
static void test_light_field(const lacuna::Context &ctx) {
    lacuna_light_field_layout l{};
    l.nodes_x = l.nodes_y = 2;
    l.node_min[0] = l.node_min[1] = -0.1f;
    l.node_spacing[0] = l.node_spacing[1] = 0.2f;
    l.basis = LACUNA_LIGHT_FIELD_BASIS_QUADRATIC;
    l.plane_distance = 0.5f;
    l.image_min[0] = l.image_min[1] = -1.0f;
    l.image_max[0] = l.image_max[1] = 1.0f;
    l.resolution_x = l.resolution_y = 2;
    std::vector<float> rgb(3 * 2 * 2 * 2 * 2, 1.0f);
    lacuna::LightField f = lacuna::LightField::from_buffer(l, rgb.data(), rgb.size());
    lacuna::LightField copy = f;
    CHECK(copy.get() == f.get());
    CHECK(f.info().layout.nodes_x == 2 && f.info().power > 0.0f);
    lacuna::LightField::Sample s = f.sample(lacuna::vec3(0, 0, 2), 0.3f, 0.6f);
    CHECK(s.pdf > 0 && std::fabs(f.pdf(lacuna::vec3(0, 0, 2), s.point) - s.pdf) <= 1e-4f * s.pdf);
    EXPECT_ERROR(lacuna::LightField::from_buffer(l, rgb.data(), rgb.size() - 1), LACUNA_STATUS_INVALID_ARGUMENT,
                 "float_count");
    EXPECT_ERROR(lacuna::LightField::from_file("/nonexistent/lamp.exr"), LACUNA_STATUS_IO, "lamp.exr");
    EXPECT_ERROR(f.sample(lacuna::vec3(0, 0, 2), 1.5f, 0), LACUNA_STATUS_OUT_OF_RANGE, "u0");
    lacuna::SceneBuilder b(ctx);
    EXPECT_ERROR(b.add_light_field_light(f, lacuna::vec3(0, 0, 0), lacuna::vec3(0, 0, 0), lacuna::vec3(1, 0, 0),
                                         lacuna::rgb(1, 1, 1)),
                 LACUNA_STATUS_INVALID_ARGUMENT, "direction");
    b.add_light_field_light(f, lacuna::vec3(0, 1, 0), lacuna::vec3(0, -1, 0), lacuna::vec3(1, 0, 0),
                            lacuna::rgb(1, 1, 1));
    b.set_camera(lacuna::vec3(0, 0, 2), lacuna::vec3(0, 0, 0), lacuna::vec3(0, 1, 0), 40);
    lacuna::LightSampler lights(b.build());
    CHECK(lights.info().light_count == 1);
}

// The light sampler's wrapper on the built-in two-room scene (area lights only).
static void test_light_sampler(const lacuna::Context &ctx) {
    lacuna::Scene scene = lacuna::SceneBuilder::builtin(ctx, "two-rooms").build();
    lacuna::LightSampler lights(scene);
    lacuna::LightSampler copy = lights;
    CHECK(copy.get() == lights.get());
    lacuna_light_sampler_info info = lights.info();
    CHECK(info.light_count > 0 && info.area_light_count == info.light_count);
    CHECK(info.environment_light == LACUNA_INVALID_INDEX);
    CHECK(lights.light_info(0).kind == LACUNA_LIGHT_KIND_AREA);
    uint32_t tri = lights.light_info(0).triangle;
    CHECK(lights.triangle_light(tri) == 0);
    lacuna_camera cam = scene.camera();
    lacuna_light_query q;
    lacuna_light_query_init(&q);
    for (int k = 0; k < 3; k++) q.position[k] = cam.eye[k];
    q.u[0] = 0.3f;
    q.u[1] = 0.6f;
    lacuna_light_sample s = lights.sample(q);
    CHECK(s.light < info.light_count && s.pdf > 0);
    lacuna_light_hit hit = {s.light, {s.direction[0], s.direction[1], s.direction[2]}, s.distance};
    CHECK(std::fabs(lights.eval(q, hit).pdf - s.pdf) <= 1e-3f * s.pdf);
    std::vector<lacuna_light_sample> batch = lights.sample(std::vector<lacuna_light_query>(4, q));
    CHECK(batch.size() == 4 && batch[3].light == s.light);
    CHECK(lights.eval(std::vector<lacuna_light_query>(2, q), std::vector<lacuna_light_hit>(2, hit)).size() == 2);
    const float u[4] = {0.1f, 0.2f, 0.3f, 0.4f};
    lacuna_emission_sample e = lights.sample_emission(u);
    CHECK(lights.emission_pdf(e.light, lacuna::vec3(e.direction[0], e.direction[1], e.direction[2])).second > 0);
    {
        const lacuna_vec3 o = lacuna::vec3(e.origin[0], e.origin[1], e.origin[2]);
        const lacuna_vec3 d = lacuna::vec3(e.direction[0], e.direction[1], e.direction[2]);
        /* Not a light field: the origin changes nothing. */
        CHECK(lights.emission_pdf_at(e.light, o, d) == lights.emission_pdf(e.light, d));
    }
    q.u[0] = 1.5f;
    EXPECT_ERROR(lights.sample(q), LACUNA_STATUS_OUT_OF_RANGE, "u[0]");
    EXPECT_ERROR(lights.light_info(info.light_count), LACUNA_STATUS_OUT_OF_RANGE, "light");
    EXPECT_ERROR(lacuna::SceneBuilder::builtin(ctx, "attic"), LACUNA_STATUS_INVALID_ARGUMENT, "attic");
    lacuna_hit h = scene.intersect(lacuna::make_ray(lacuna::vec3(cam.eye[0], cam.eye[1], cam.eye[2]),
                                                    lacuna::vec3(cam.target[0] - cam.eye[0], cam.target[1] - cam.eye[1],
                                                                 cam.target[2] - cam.eye[2])));
    CHECK(scene.surface(h).triangle == h.triangle);
}

int main(int argc, char **argv) {
    if (argc < 2) return 2;
    std::string dir = argv[1];
    CHECK(lacuna::version() == LACUNA_VERSION);
    CHECK(lacuna::version_string() == LACUNA_VERSION_STRING);

    lacuna::Context ctx = lacuna::Context::create();
    test_light_sampler(ctx);
    test_photometric(ctx);
    test_light_field(ctx);
    ctx.set_thread_count(2);
    CHECK(ctx.thread_count() == 2);
    EXPECT_ERROR(ctx.set_thread_count(1u << 20), LACUNA_STATUS_OUT_OF_RANGE, "thread_count");
    EXPECT_ERROR(ctx.set_memory_budget(0), LACUNA_STATUS_INVALID_ARGUMENT, "budget");

    // Copies retain: the scene outlives every other handle.
    lacuna::Scene scene;
    {
        lacuna::Context copy = ctx;
        lacuna::Scene first = box(copy);
        scene = first;
        lacuna::Scene moved = std::move(first);
        CHECK(!first && moved && scene.get() == moved.get());
    }
    lacuna_hit h = scene.intersect(lacuna::make_ray(lacuna::vec3(0, 0, 0), lacuna::vec3(0, 0, -1)));
    CHECK(std::fabs(h.t - 1) < 1e-6f && h.mesh == 0);
    CHECK(scene.occluded(lacuna::make_ray(lacuna::vec3(0, 0, 0), lacuna::vec3(1, 0, 0))));
    std::vector<lacuna_ray> rays;
    for (int k = 0; k < 64; k++)
        rays.push_back(lacuna::make_ray(lacuna::vec3(0, 0, 0), lacuna::vec3(std::cos(k * 0.1f), 0.3f, std::sin(k * 0.1f))));
    auto hits = scene.intersect(rays);
    auto occ = scene.occluded(rays);
    CHECK(hits.size() == 64 && occ.size() == 64 && occ[5] && hits[5].triangle != LACUNA_INVALID_INDEX);
    CHECK(scene.intersect(std::vector<lacuna_ray>{}).empty());
    CHECK(scene.memory().total > 0 && scene.stats().triangles == 12);
    lacuna_ray bad = lacuna::make_ray(lacuna::vec3(0, 0, 0), lacuna::vec3(0, 0, 0));
    EXPECT_ERROR(scene.intersect(bad), LACUNA_STATUS_INVALID_ARGUMENT, "non-zero");
    EXPECT_ERROR(lacuna::Scene().intersect(bad), LACUNA_STATUS_NULL_POINTER, "scene");

    // Builder errors as exceptions; a failed build consumes the builder too.
    {
        lacuna::SceneBuilder b(ctx);
        EXPECT_ERROR(b.add_material(42), LACUNA_STATUS_INVALID_ARGUMENT, "kind");
        EXPECT_ERROR(b.load_obj(dir + "/missing.obj"), LACUNA_STATUS_IO, "missing.obj");
        EXPECT_ERROR(b.set_material_rgb(3, LACUNA_MATERIAL_RGB_DIFFUSE, lacuna::rgb(1, 1, 1)),
                     LACUNA_STATUS_OUT_OF_RANGE, "material index 3");
        {
            std::ofstream obj(dir + "/quad.obj");
            obj << "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";
        }
        CHECK(b.load_obj(dir + "/quad.obj") == 2);
        lacuna::SceneBuilder moved = std::move(b);
        CHECK(!b && moved);
        lacuna::Scene q = moved.build();
        CHECK(q.stats().triangles == 2);
        EXPECT_ERROR(moved.build(), LACUNA_STATUS_NULL_POINTER, "builder");
    }

    // Render with a progress callback.
    lacuna::RenderJob job(scene);
    job.mis_heuristic(LACUNA_MIS_HEURISTIC_AUTO).mis_heuristic(LACUNA_MIS_HEURISTIC_OPTIMAL);
    CHECK(job.mis_heuristic() == LACUNA_MIS_HEURISTIC_OPTIMAL);
    EXPECT_ERROR(job.mis_heuristic(4), LACUNA_STATUS_INVALID_ARGUMENT, "heuristic");
    CHECK(job.compare_schedule() == LACUNA_COMPARE_SCHEDULE_SEQUENTIAL);
    CHECK(job.compare_schedule(LACUNA_COMPARE_SCHEDULE_CONCURRENT).compare_schedule() ==
          LACUNA_COMPARE_SCHEDULE_CONCURRENT);
    EXPECT_ERROR(job.compare_schedule(2), LACUNA_STATUS_INVALID_ARGUMENT, "schedule");
    job.resolution(12, 8).samples_per_pixel(2).seed(3).max_depth(2).threads(2).mis_heuristic(LACUNA_MIS_HEURISTIC_POWER);
    std::atomic<int> calls{0};
    double last = 0;
    job.on_progress([&](double f) {
        calls++;
        CHECK(f >= last);
        last = f;
        return true;
    });
    lacuna::Film film = job.run();
    CHECK(calls > 0 && last == 1.0);
    CHECK(film.width() == 12 && film.height() == 8 && film.stats().spp == 2);
    auto radiance = film.read();
    auto depth = film.read(LACUNA_FILM_CHANNEL_DEPTH);
    CHECK(radiance.size() == 12 * 8 * 3 && depth.size() == 12 * 8);
    double sum = 0;
    for (float v : radiance) sum += v;
    CHECK(sum > 0);
    film.write_exr(dir + "/cpp.exr");
    CHECK(lacuna::Film::load_exr(ctx, dir + "/cpp.exr").width() == 12);
    EXPECT_ERROR(film.write_png(dir + "/x.png", NAN), LACUNA_STATUS_INVALID_ARGUMENT, "exposure");
    EXPECT_ERROR(job.resolution(0, 1), LACUNA_STATUS_OUT_OF_RANGE, "resolution");
    EXPECT_ERROR(lacuna::RenderJob(scene, "nonesuch"), LACUNA_STATUS_INVALID_ARGUMENT, "nonesuch");

    // Bidirectional path tracing: strategy images sum to the image.
    {
        lacuna::RenderJob bdpt(scene, "bdpt");
        bdpt.resolution(8, 6).samples_per_pixel(2).max_depth(2).light_paths(20).strategy_images(3).thin_lens(0.02f, 1);
        lacuna::Film f = bdpt.run();
        auto image = f.read();
        std::vector<float> total(image.size(), 0.0f);
        for (uint32_t k = 1; k <= 3; k++)
            for (uint32_t s = 0; s <= k; s++) {
                if (k == 1 && s == 1) continue;
                auto layer = f.read_strategy_image(s, k + 1 - s, true);
                for (size_t i = 0; i < layer.size(); i++) total[i] += layer[i];
            }
        bool close = true;
        for (size_t i = 0; i < image.size(); i++) close &= std::fabs(total[i] - image[i]) <= 1e-4f * std::fmax(image[i], 1e-3f);
        CHECK(close);
        EXPECT_ERROR(f.read_strategy_image(1, 1, true), LACUNA_STATUS_OUT_OF_RANGE, "(1, 1)");
        EXPECT_ERROR(bdpt.strategy_filter(1, 1, false), LACUNA_STATUS_INVALID_ARGUMENT, "(1, 1)");
        bdpt.strategy_filter(1, 2, true).clear_strategy_filter();
        EXPECT_ERROR(job.light_paths(3), LACUNA_STATUS_INVALID_OPERATION, "bdpt");
    }

    // Resampling options: set, read back, invalid values rejected.
    {
        lacuna::RenderJob skel(scene, "bdpt_skeleton:subset=64");
        CHECK(skel.resampling_subset() == 64 && skel.resampling_accept() == 1.0f);
        skel.resampling_subset(256).resampling_accept(0.5f).resampling_images(true);
        CHECK(skel.resampling_subset() == 256 && skel.resampling_accept() == 0.5f && skel.resampling_images());
        EXPECT_ERROR(skel.resampling_subset(0), LACUNA_STATUS_INVALID_ARGUMENT, "subset");
        EXPECT_ERROR(skel.resampling_accept(-2), LACUNA_STATUS_INVALID_ARGUMENT, "accept");
        EXPECT_ERROR(skel.record_density(0.1f), LACUNA_STATUS_INVALID_OPERATION, "bdpt_ic");
        CHECK(skel.resampling_subset() == 256);
        lacuna::RenderJob ic(scene, "bdpt_ic");
        CHECK(ic.record_density() == 0.001f && ic.resampling_subset() == 1024);
        ic.record_density(0.25f).resampling_subset(8);
        CHECK(ic.record_density() == 0.25f && ic.resampling_subset() == 8);
        EXPECT_ERROR(ic.record_density(2), LACUNA_STATUS_INVALID_ARGUMENT, "density");
        EXPECT_ERROR(job.resampling_subset(4), LACUNA_STATUS_INVALID_OPERATION, "bdpt_skeleton");
        EXPECT_ERROR(job.resampling_images(), LACUNA_STATUS_INVALID_OPERATION, "bdpt_ic");
        ic.resolution(8, 6).samples_per_pixel(2).max_depth(3);
        auto image = ic.run().read();
        double total = 0;
        for (float v : image) total += v;
        CHECK(std::isfinite(total) && total > 0);
    }

    // A throwing callback cancels the render; run() rethrows its exception.
    job.on_progress([](double f) -> bool {
        if (f >= 0.0) throw std::runtime_error("callback failed on purpose");
        return true;
    });
    try {
        job.run();
        CHECK(false);
    } catch (const std::runtime_error &e) {
        CHECK(std::strcmp(e.what(), "callback failed on purpose") == 0);
        CHECK(dynamic_cast<const lacuna::Error *>(&e) == nullptr);
    }
    // Returning false cancels with LACUNA_STATUS_CANCELLED; the partial film is kept.
    job.samples_per_pixel(16).on_progress([](double f) { return f < 0.5; });
    EXPECT_ERROR(job.run(), LACUNA_STATUS_CANCELLED, "cancelled");
    CHECK(job.stats().cancelled && job.take_partial_film().stats().spp < 16);
    job.on_progress(nullptr);

    // Cancel from another thread.
    lacuna::RenderJob slow(scene);
    slow.resolution(16, 16).time_budget(60);
    auto t0 = std::chrono::steady_clock::now();
    std::thread canceller([&] {
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
        slow.cancel();
    });
    EXPECT_ERROR(slow.run(), LACUNA_STATUS_CANCELLED, "cancelled");
    canceller.join();
    CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(30));
    lacuna::RenderJob moved_job = std::move(slow);
    moved_job.time_budget(0).samples_per_pixel(1);
    CHECK(moved_job.run().stats().spp == 1);

    test_environment(ctx);

    std::printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
