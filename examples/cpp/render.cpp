// A C++ host of Lacuna through the RAII wrapper: loads an OBJ file, renders it with a progress
// bar, then starts a second, longer render and cancels it half-way from another thread, and
// writes both images as OpenEXR.
//   render_cpp scene.obj [out_dir]
#include <lacuna.hpp>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <string>
#include <thread>

int main(int argc, char **argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s scene.obj [out_dir]\n", argv[0]);
        return 2;
    }
    std::string out_dir = argc > 2 ? argv[2] : ".";
    try {
        lacuna::Context ctx = lacuna::Context::create();
        lacuna::SceneBuilder builder(ctx);
        size_t triangles = builder.load_obj(argv[1]);
        lacuna::Scene scene = builder.build();  // no camera in the file: one frames the scene
        std::printf("%zu triangles, %zu bytes\n", triangles, scene.memory().total);

        lacuna::RenderJob job(scene, "path");
        job.resolution(192, 192).samples_per_pixel(8);
        int shown = -1;
        job.on_progress([&](double f) {
            int percent = int(f * 100);
            if (percent / 10 != shown / 10) {
                std::fprintf(stderr, "\r%3d%%", percent);
                shown = percent;
            }
            return true;
        });
        lacuna::Film film = job.run();
        std::fprintf(stderr, "\n");
        film.write_exr(out_dir + "/render_cpp.exr");
        std::printf("first render: %u spp in %.2f s -> %s/render_cpp.exr\n", film.stats().spp,
                    film.stats().seconds, out_dir.c_str());

        // A second job, cancelled from another thread once it is half done.
        lacuna::RenderJob second(scene, "path");
        second.resolution(192, 192).samples_per_pixel(256);
        std::atomic<double> progress{0.0};
        std::atomic<bool> done{false};
        second.on_progress([&](double f) {
            progress = f;
            return true;
        });
        std::thread watcher([&] {
            while (progress < 0.5 && !done) std::this_thread::sleep_for(std::chrono::milliseconds(5));
            if (!done) second.cancel();
        });
        struct Join {
            std::thread &t;
            std::atomic<bool> &done;
            ~Join() {
                done = true;
                t.join();
            }
        } join{watcher, done};
        try {
            second.run();
            std::printf("the second render finished before it could be cancelled\n");
        } catch (const lacuna::Error &e) {
            if (e.status() != LACUNA_STATUS_CANCELLED) throw;
            lacuna::Film partial = second.take_partial_film();
            partial.write_exr(out_dir + "/render_cpp_cancelled.exr");
            std::printf("second render cancelled at %.0f%%: %u of 256 spp kept -> %s/render_cpp_cancelled.exr\n",
                        progress.load() * 100, partial.stats().spp, out_dir.c_str());
        }
    } catch (const lacuna::Error &e) {
        std::fprintf(stderr, "lacuna error (%s): %s\n", e.status_name(), e.what());
        return 1;
    }
    return 0;
}
