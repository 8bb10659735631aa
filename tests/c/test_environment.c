/* Tests of the environment-map part of Lacuna's C API, written in C: every function, every
 * error path. Built and run by tests/c_api.rs (plain, under AddressSanitizer and under
 * valgrind) next to test_capi.c. argv[1] is a scratch directory. Prints "N passed, N failed"
 * and exits non-zero on any failure. */
#include "check.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { W = 16, H = 8 };

/* A constant lat-long map of `value`, packed RGB. */
static void fill(float *texels, int count, float value) {
    for (int i = 0; i < 3 * count; i++) texels[i] = value;
}

/* A diffuse floor quad (albedo 0.5) at y = 0 under a camera looking down at it from above,
 * its corners showing the sky. */
static lacuna_scene *floor_scene(lacuna_context *ctx, const lacuna_environment *env) {
    lacuna_scene_builder *b = NULL;
    OK(lacuna_scene_builder_new(ctx, &b));
    uint32_t mat = 99;
    OK(lacuna_scene_builder_add_material(b, LACUNA_MATERIAL_KIND_DIFFUSE, &mat));
    OK(lacuna_scene_builder_set_material_rgb(b, mat, LACUNA_MATERIAL_RGB_DIFFUSE, rgb(0.5f, 0.5f, 0.5f)));
    add_floor_quad(b, 1.0f, mat);
    OK(lacuna_scene_builder_set_camera(b, v3(0, 3, 0), v3(0, 0, 0), v3(0, 0, -1), 60));
    EXPECT(lacuna_scene_builder_set_environment(NULL, env), LACUNA_STATUS_NULL_POINTER, "builder");
    OK(lacuna_scene_builder_set_environment(b, env));
    lacuna_scene *scene = NULL;
    OK(lacuna_scene_builder_build(b, &scene));
    return scene;
}

/* Renders `scene` with `integrator` (16 x 16, `spp` samples) and returns the mean radiance
 * (red) of the central 4 x 4 pixels (floor) and of the corner pixel (sky). */
static void render_floor(lacuna_scene *scene, const char *integrator, uint32_t strategy, uint32_t spp,
                         double *floor_mean, double *sky) {
    lacuna_render_job *job = NULL;
    OK(lacuna_render_job_new(scene, integrator, &job));
    OK(lacuna_render_job_set_resolution(job, 16, 16));
    OK(lacuna_render_job_set_samples_per_pixel(job, spp));
    OK(lacuna_render_job_set_max_depth(job, 2));
    OK(lacuna_render_job_set_environment_strategy(job, strategy));
    lacuna_film *film = NULL;
    OK(lacuna_render_job_run(job, &film));
    float px[16 * 16 * 3];
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, px, 16, 16, 0, 0));
    double sum = 0;
    for (int y = 6; y < 10; y++)
        for (int x = 6; x < 10; x++) sum += px[3 * (y * 16 + x)];
    *floor_mean = sum / 16.0;
    *sky = px[0];
    lacuna_film_release(film);
    lacuna_render_job_free(job);
}

/* Writes a flat (uncompressed) Radiance RGBE file of a constant colour. */
static void write_hdr(const char *path, int w, int h, unsigned char mantissa, unsigned char exponent) {
    FILE *f = fopen(path, "wb");
    if (!f) {
        perror(path);
        exit(2);
    }
    fprintf(f, "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n", h, w);
    for (int i = 0; i < w * h; i++) {
        unsigned char px[4] = {mantissa, mantissa, mantissa, exponent};
        fwrite(px, 1, 4, f);
    }
    fclose(f);
}

static void test_creation(void) {
    float texels[W * H * 3];
    fill(texels, W * H, 1.0f);
    lacuna_environment *env = NULL;
    EXPECT(lacuna_environment_new_from_buffer(NULL, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &env),
           LACUNA_STATUS_NULL_POINTER, "texels");
    EXPECT(lacuna_environment_new_from_buffer(texels, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, NULL),
           LACUNA_STATUS_NULL_POINTER, "out_env");
    EXPECT(lacuna_environment_new_from_buffer(texels, W, H, 0, 0, 7, &env), LACUNA_STATUS_INVALID_ARGUMENT,
           "layout");
    EXPECT(lacuna_environment_new_from_buffer(texels, W, H - 1, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &env),
           LACUNA_STATUS_INVALID_ARGUMENT, "lat-long");
    EXPECT(lacuna_environment_new_from_buffer(texels, 8, 6, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &env),
           LACUNA_STATUS_INVALID_ARGUMENT, "lat-long");
    EXPECT(lacuna_environment_new_from_buffer(texels, 8, 4, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_CUBE_CROSS, &env),
           LACUNA_STATUS_INVALID_ARGUMENT, "cross");
    EXPECT(lacuna_environment_new_from_buffer(texels, W, H, 4, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &env),
           LACUNA_STATUS_INVALID_ARGUMENT, "pixel_stride");
    EXPECT(lacuna_environment_new_from_buffer(texels, W, H, 0, 12, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &env),
           LACUNA_STATUS_INVALID_ARGUMENT, "row_stride");
    EXPECT(lacuna_environment_new_from_buffer(texels, (size_t)1 << 40, (size_t)1 << 39, 0, 0,
                                              LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &env),
           LACUNA_STATUS_OUT_OF_RANGE, "2^28");
    texels[3 * 21 + 1] = NAN;
    EXPECT(lacuna_environment_new_from_buffer(texels, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &env),
           LACUNA_STATUS_INVALID_ARGUMENT, "(x 5, y 1)");
    texels[3 * 21 + 1] = INFINITY;
    EXPECT(lacuna_environment_new_from_buffer(texels, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &env),
           LACUNA_STATUS_INVALID_ARGUMENT, "infinite");
    CHECK(env == NULL);
    /* Negative values are clamped and counted. */
    texels[3 * 21 + 1] = -0.25f;
    texels[3 * 22] = -1.0f;
    OK(lacuna_environment_new_from_buffer(texels, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &env));
    lacuna_environment_info info;
    EXPECT(lacuna_environment_get_info(NULL, &info), LACUNA_STATUS_NULL_POINTER, "env");
    EXPECT(lacuna_environment_get_info(env, NULL), LACUNA_STATUS_NULL_POINTER, "out_info");
    OK(lacuna_environment_get_info(env, &info));
    CHECK(info.width == W && info.height == H && info.layout == LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG);
    CHECK(info.clamped_values == 2);
    CHECK(info.memory_bytes >= W * H * 12);
    CHECK(info.latlong_build_seconds == 0 && info.cube_build_seconds == 0);
    /* Preparing builds and times the structures. */
    EXPECT(lacuna_environment_prepare(env, 9), LACUNA_STATUS_INVALID_ARGUMENT, "strategy");
    EXPECT(lacuna_environment_prepare(NULL, LACUNA_ENVIRONMENT_STRATEGY_LAT_LONG), LACUNA_STATUS_NULL_POINTER,
           "env");
    OK(lacuna_environment_prepare(env, LACUNA_ENVIRONMENT_STRATEGY_CUBE_DYNAMIC));
    OK(lacuna_environment_prepare(env, LACUNA_ENVIRONMENT_STRATEGY_LAT_LONG));
    lacuna_environment_info after;
    OK(lacuna_environment_get_info(env, &after));
    CHECK(after.memory_bytes > info.memory_bytes);
    CHECK(after.latlong_build_seconds >= 0 && after.cube_build_seconds > 0);
    lacuna_environment_free(env);
    lacuna_environment_free(NULL);

    /* A strided buffer with padding reads the same texels. */
    float padded[H][W][4];
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            padded[y][x][0] = padded[y][x][1] = padded[y][x][2] = 0.5f;
            padded[y][x][3] = NAN; /* padding, never read */
        }
    OK(lacuna_environment_new_from_buffer(&padded[0][0][0], W, H, 16, 16 * W, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG,
                                          &env));
    OK(lacuna_environment_get_info(env, &info));
    CHECK(info.clamped_values == 0);
    lacuna_environment_free(env);

    /* A horizontal cross of faces of 2 texels. */
    float cross[6 * 8 * 3];
    fill(cross, 6 * 8, 1.0f);
    OK(lacuna_environment_new_from_buffer(cross, 8, 6, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_CUBE_CROSS, &env));
    OK(lacuna_environment_get_info(env, &info));
    CHECK(info.width == 8 && info.height == 6 && info.layout == LACUNA_ENVIRONMENT_LAYOUT_CUBE_CROSS);
    lacuna_environment_free(env);

    /* Files. */
    env = NULL;
    EXPECT(lacuna_environment_new_from_file(NULL, &env), LACUNA_STATUS_NULL_POINTER, "path");
    EXPECT(lacuna_environment_new_from_file(path_in_dir("none.hdr"), NULL), LACUNA_STATUS_NULL_POINTER,
           "out_env");
    EXPECT(lacuna_environment_new_from_file(path_in_dir("missing.hdr"), &env), LACUNA_STATUS_IO, "missing.hdr");
    EXPECT(lacuna_environment_new_from_file(path_in_dir("map.png"), &env), LACUNA_STATUS_INVALID_ARGUMENT,
           ".exr or .hdr");
    FILE *g = fopen(path_in_dir("garbage.exr"), "wb");
    fputs("not an exr", g);
    fclose(g);
    EXPECT(lacuna_environment_new_from_file(path_in_dir("garbage.exr"), &env), LACUNA_STATUS_PARSE, "garbage.exr");
    write_hdr(path_in_dir("wide.hdr"), 12, 4, 128, 129); /* 3:1 */
    EXPECT(lacuna_environment_new_from_file(path_in_dir("wide.hdr"), &env), LACUNA_STATUS_PARSE, "2:1");
    CHECK(env == NULL);
    write_hdr(path_in_dir("sky.hdr"), 8, 4, 128, 129); /* 128 * 2^(129-136) = 1.0 */
    OK(lacuna_environment_new_from_file(path_in_dir("sky.hdr"), &env));
    OK(lacuna_environment_get_info(env, &info));
    CHECK(info.width == 8 && info.height == 4 && info.layout == LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG);
    lacuna_environment_free(env);
}

static void test_rendering(lacuna_context *ctx) {
    float texels[W * H * 3];
    fill(texels, W * H, 1.0f);
    lacuna_environment *env = NULL;
    OK(lacuna_environment_new_from_buffer(texels, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &env));
    /* Placement and visibility. */
    EXPECT(lacuna_environment_set_placement(NULL, 1, 0, LACUNA_UP_AXIS_Y), LACUNA_STATUS_NULL_POINTER, "env");
    EXPECT(lacuna_environment_set_placement(env, NAN, 0, LACUNA_UP_AXIS_Y), LACUNA_STATUS_INVALID_ARGUMENT,
           "scale");
    EXPECT(lacuna_environment_set_placement(env, -1, 0, LACUNA_UP_AXIS_Y), LACUNA_STATUS_INVALID_ARGUMENT,
           "scale");
    EXPECT(lacuna_environment_set_placement(env, 1, INFINITY, LACUNA_UP_AXIS_Y), LACUNA_STATUS_INVALID_ARGUMENT,
           "rotate_degrees");
    EXPECT(lacuna_environment_set_placement(env, 1, 0, 5), LACUNA_STATUS_INVALID_ARGUMENT, "up_axis");
    OK(lacuna_environment_set_placement(env, 1, 30, LACUNA_UP_AXIS_Z));
    OK(lacuna_environment_set_placement(env, 1, 0, LACUNA_UP_AXIS_Y));
    EXPECT(lacuna_environment_set_visible(NULL, true), LACUNA_STATUS_NULL_POINTER, "env");

    /* A uniform sky of 1 over a diffuse floor of albedo 0.5: the floor reflects 0.5 (it sees
     * the whole upper hemisphere), the sky pixels are 1, whatever the strategy and integrator
     * (bdpt included, so that valgrind covers it: see the `filtered` field of Bdpt). */
    lacuna_scene *scene = floor_scene(ctx, env);
    const uint32_t strategies[6] = {LACUNA_ENVIRONMENT_STRATEGY_LAT_LONG, LACUNA_ENVIRONMENT_STRATEGY_CUBE_UNIFORM,
                                    LACUNA_ENVIRONMENT_STRATEGY_CUBE_POWER, LACUNA_ENVIRONMENT_STRATEGY_CUBE_DYNAMIC,
                                    LACUNA_ENVIRONMENT_STRATEGY_BSDF,     LACUNA_ENVIRONMENT_STRATEGY_AUTO};
    double floor_mean = 0, sky = 0;
    const char *integrators[2] = {"path", "bdpt"};
    for (int k = 0; k < 2; k++)
        for (int i = 0; i < 6; i++) {
            render_floor(scene, integrators[k], strategies[i], 128, &floor_mean, &sky);
            CHECK(fabs(floor_mean - 0.5) < 0.05);
            CHECK(sky == 1.0);
        }

    /* Job settings. */
    lacuna_render_job *job = NULL;
    OK(lacuna_render_job_new(scene, "env_direct", &job));
    EXPECT(lacuna_render_job_set_environment_strategy(job, 7), LACUNA_STATUS_INVALID_ARGUMENT, "strategy");
    EXPECT(lacuna_render_job_set_environment_strategy(NULL, 0), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_environment_samples(job, 0, 0), LACUNA_STATUS_INVALID_ARGUMENT, "both 0");
    EXPECT(lacuna_render_job_set_environment_samples(NULL, 1, 1), LACUNA_STATUS_NULL_POINTER, "job");
    OK(lacuna_render_job_set_environment_samples(job, 6, 2));
    OK(lacuna_render_job_set_resolution(job, 16, 16));
    OK(lacuna_render_job_set_samples_per_pixel(job, 8));
    /* Every MIS weighting env_direct takes gives the same floor (auto and optimal included). */
    EXPECT(lacuna_render_job_set_mis_heuristic(job, 4), LACUNA_STATUS_INVALID_ARGUMENT, "heuristic");
    const uint32_t heuristics[4] = {LACUNA_MIS_HEURISTIC_BALANCE, LACUNA_MIS_HEURISTIC_POWER, LACUNA_MIS_HEURISTIC_AUTO,
                                    LACUNA_MIS_HEURISTIC_OPTIMAL};
    for (int k = 0; k < 4; k++) {
        OK(lacuna_render_job_set_mis_heuristic(job, heuristics[k]));
        lacuna_film *film = NULL;
        OK(lacuna_render_job_run(job, &film));
        float px[16 * 16 * 3];
        OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, px, 16, 16, 0, 0));
        double sum = 0;
        for (int y = 6; y < 10; y++)
            for (int x = 6; x < 10; x++) sum += px[3 * (y * 16 + x)];
        CHECK(fabs(sum / 16.0 - 0.5) < 0.06);
        lacuna_film_release(film);
    }
    lacuna_render_job_free(job);

    /* Update in place: a sky of 2, the same size. */
    double seconds = -1;
    fill(texels, W * H, 2.0f);
    EXPECT(lacuna_environment_update(NULL, texels, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &seconds),
           LACUNA_STATUS_NULL_POINTER, "env");
    EXPECT(lacuna_environment_update(env, texels, W / 2, H / 2, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &seconds),
           LACUNA_STATUS_INVALID_ARGUMENT, "make a new environment");
    EXPECT(lacuna_environment_update(env, NULL, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &seconds),
           LACUNA_STATUS_NULL_POINTER, "texels");
    texels[5] = NAN;
    EXPECT(lacuna_environment_update(env, texels, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &seconds),
           LACUNA_STATUS_INVALID_ARGUMENT, "NaN");
    CHECK(seconds == -1);
    texels[5] = 2.0f;
    OK(lacuna_environment_update(env, texels, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, &seconds));
    CHECK(seconds >= 0);
    OK(lacuna_environment_update(env, texels, W, H, 0, 0, LACUNA_ENVIRONMENT_LAYOUT_LAT_LONG, NULL));
    /* The old scene keeps its snapshot; a derived scene sees the new sky. */
    render_floor(scene, "path", LACUNA_ENVIRONMENT_STRATEGY_CUBE_DYNAMIC, 16, &floor_mean, &sky);
    CHECK(sky == 1.0);
    lacuna_scene *brighter = NULL;
    EXPECT(lacuna_scene_new_with_environment(NULL, env, &brighter), LACUNA_STATUS_NULL_POINTER, "scene");
    EXPECT(lacuna_scene_new_with_environment(scene, env, NULL), LACUNA_STATUS_NULL_POINTER, "out_scene");
    OK(lacuna_scene_new_with_environment(scene, env, &brighter));
    render_floor(brighter, "path", LACUNA_ENVIRONMENT_STRATEGY_CUBE_DYNAMIC, 128, &floor_mean, &sky);
    CHECK(sky == 2.0 && fabs(floor_mean - 1.0) < 0.1);
    lacuna_scene_release(brighter);
    /* Hidden: lights the floor, not seen by the camera. */
    OK(lacuna_environment_set_visible(env, false));
    OK(lacuna_scene_new_with_environment(scene, env, &brighter));
    render_floor(brighter, "path", LACUNA_ENVIRONMENT_STRATEGY_CUBE_DYNAMIC, 16, &floor_mean, &sky);
    CHECK(sky == 0.0 && floor_mean > 0.8);
    lacuna_scene_release(brighter);
    /* Without an environment: black. */
    OK(lacuna_scene_new_with_environment(scene, NULL, &brighter));
    render_floor(brighter, "path", LACUNA_ENVIRONMENT_STRATEGY_CUBE_DYNAMIC, 4, &floor_mean, &sky);
    CHECK(sky == 0.0 && floor_mean == 0.0);
    lacuna_scene_release(brighter);
    /* Freeing the environment leaves the scene's snapshot alive. */
    lacuna_environment_free(env);
    render_floor(scene, "path", LACUNA_ENVIRONMENT_STRATEGY_LAT_LONG, 4, &floor_mean, &sky);
    CHECK(sky == 1.0);
    lacuna_scene_release(scene);
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s SCRATCH_DIR\n", argv[0]);
        return 2;
    }
    snprintf(dir, sizeof dir, "%s", argv[1]);
    test_creation();
    lacuna_context *ctx = NULL;
    OK(lacuna_context_new(&ctx));
    OK(lacuna_context_set_thread_count(ctx, 2));
    test_rendering(ctx);
    lacuna_context_release(ctx);
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
