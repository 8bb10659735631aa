/* Tests of the photometric (IES) part of Lacuna's C API, written in C: every function, every
 * error path. Built and run by tests/c_api.rs (plain, under AddressSanitizer and under
 * valgrind) next to test_capi.c. argv[1] is a scratch directory. Prints "N passed, N failed"
 * and exits non-zero on any failure. */
#include "check.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A downlight: gamma 0-90, quadrant symmetric, peak 200 cd at the nadir (multiplier 2). */
static const char IES[] =
    "IESNA:LM-63-2002\n"
    "[TEST] C API test\n"
    "TILT=NONE\n"
    "1 1000 2.0 4 3 1 2 0.1 0.1 0.0\n"
    "1.0 1.0 20\n"
    "0 30 60 90\n"
    "0 45 90\n"
    "100 80 20 0\n"
    "100 60 10 0\n"
    "100 40 5 0\n";

/* A rotationally symmetric EULUMDAT file: 100, 50, 0 cd/klm at gamma 0, 45, 90, 1000 lm. */
static const char LDT[] =
    "C test\n1\n1\n1\n0\n3\n45\nreport\nname\nnumber\nfile.ldt\ndate\n"
    "0\n0\n0\n0\n0\n0\n0\n0\n0\n"
    "100\n100\n1\n0\n1\n1\nLED\n1000\n3000\n80\n10\n"
    "0.5\n0.5\n0.5\n0.5\n0.5\n0.5\n0.5\n0.5\n0.5\n0.5\n"
    "0\n0\n45\n90\n100\n50\n0\n";

static int close_to(float a, float b, float tolerance) { return fabsf(a - b) <= tolerance * fmaxf(1.0f, fabsf(b)); }

static void test_loading(void) {
    lacuna_photometric_profile *p = NULL;
    EXPECT(lacuna_photometric_profile_new_from_ies_buffer(NULL, 10, &p), LACUNA_STATUS_NULL_POINTER, "data");
    EXPECT(lacuna_photometric_profile_new_from_ies_buffer((const uint8_t *)IES, strlen(IES), NULL),
           LACUNA_STATUS_NULL_POINTER, "out_profile");
    EXPECT(lacuna_photometric_profile_new_from_ies_buffer((const uint8_t *)IES, (size_t)1 << 40, &p),
           LACUNA_STATUS_OUT_OF_RANGE, "limit");
    /* Truncated: the candela table stops early. */
    EXPECT(lacuna_photometric_profile_new_from_ies_buffer((const uint8_t *)IES, strlen(IES) - 12, &p),
           LACUNA_STATUS_PARSE, "ends before the candela value");
    EXPECT(lacuna_photometric_profile_new_from_ies_buffer((const uint8_t *)"hello", 5, &p), LACUNA_STATUS_PARSE,
           "TILT");
    CHECK(p == NULL);
    EXPECT(lacuna_photometric_profile_new_from_file(NULL, &p), LACUNA_STATUS_NULL_POINTER, "path");
    EXPECT(lacuna_photometric_profile_new_from_file(path_in_dir("missing.ies"), &p), LACUNA_STATUS_IO,
           "missing.ies");
    /* A type B file, written to disk: the error names the file and the line. */
    const char *bad_path = path_in_dir("typeb.ies");
    FILE *f = fopen(bad_path, "wb");
    CHECK(f != NULL);
    if (f) {
        const char *bad = "IESNA:LM-63-2002\nTILT=NONE\n1 1000 1 2 1 2 2 0 0 0\n1 1 0\n0 90\n0\n1 1\n";
        fwrite(bad, 1, strlen(bad), f);
        fclose(f);
    }
    EXPECT(lacuna_photometric_profile_new_from_file(bad_path, &p), LACUNA_STATUS_PARSE, "typeb.ies:line 3");
    CHECK(p == NULL);

    /* The good file from disk and from memory give the same profile. */
    const char *good_path = path_in_dir("downlight.ies");
    f = fopen(good_path, "wb");
    CHECK(f != NULL);
    if (f) {
        fwrite(IES, 1, strlen(IES), f);
        fclose(f);
    }
    lacuna_photometric_profile *from_file = NULL;
    OK(lacuna_photometric_profile_new_from_file(good_path, &from_file));
    OK(lacuna_photometric_profile_new_from_ies_buffer((const uint8_t *)IES, strlen(IES), &p));
    lacuna_photometric_profile_info a, b;
    OK(lacuna_photometric_profile_get_info(p, &a));
    OK(lacuna_photometric_profile_get_info(from_file, &b));
    CHECK(a.peak_candela == 200.0f && b.peak_candela == 200.0f);
    CHECK(a.flux_lumen == b.flux_lumen && a.flux_lumen > 0.0f);
    CHECK(a.symmetry == LACUNA_PHOTOMETRIC_SYMMETRY_QUADRANT);
    CHECK(a.memory_bytes > 0);
    EXPECT(lacuna_photometric_profile_get_info(NULL, &a), LACUNA_STATUS_NULL_POINTER, "profile");
    EXPECT(lacuna_photometric_profile_get_info(p, NULL), LACUNA_STATUS_NULL_POINTER, "out_info");
    lacuna_photometric_profile_release(from_file);

    /* EULUMDAT from memory, and its errors. */
    lacuna_photometric_profile *ldt = NULL;
    OK(lacuna_photometric_profile_new_from_ldt_buffer((const uint8_t *)LDT, strlen(LDT), &ldt));
    OK(lacuna_photometric_profile_get_info(ldt, &b));
    CHECK(b.symmetry == LACUNA_PHOTOMETRIC_SYMMETRY_ROTATIONAL && b.peak_candela == 100.0f);
    lacuna_photometric_profile_release(ldt);
    EXPECT(lacuna_photometric_profile_new_from_ldt_buffer(NULL, 3, &ldt), LACUNA_STATUS_NULL_POINTER, "data");
    EXPECT(lacuna_photometric_profile_new_from_ldt_buffer((const uint8_t *)LDT, strlen(LDT) - 4, &ldt),
           LACUNA_STATUS_PARSE, "ends before");
    EXPECT(lacuna_photometric_profile_new_from_ldt_buffer((const uint8_t *)LDT, 10, NULL), LACUNA_STATUS_NULL_POINTER,
           "out_profile");
    lacuna_photometric_profile_retain(NULL);
    lacuna_photometric_profile_release(NULL);
    lacuna_photometric_profile_release(p);
}

static void test_queries(const lacuna_photometric_profile *p) {
    float candela = -1.0f;
    OK(lacuna_photometric_profile_intensity(p, v3(0, 0, 2), &candela)); /* normalised here */
    CHECK(close_to(candela, 200.0f, 1e-4f));
    OK(lacuna_photometric_profile_intensity(p, v3(0, 0, -1), &candela));
    CHECK(candela == 0.0f); /* above gamma 90: dark */
    EXPECT(lacuna_photometric_profile_intensity(p, v3(0, 0, 0), &candela), LACUNA_STATUS_INVALID_ARGUMENT,
           "non-zero");
    EXPECT(lacuna_photometric_profile_intensity(p, v3(NAN, 0, 1), &candela), LACUNA_STATUS_INVALID_ARGUMENT,
           "finite");
    EXPECT(lacuna_photometric_profile_intensity(NULL, v3(0, 0, 1), &candela), LACUNA_STATUS_NULL_POINTER,
           "profile");
    EXPECT(lacuna_photometric_profile_intensity(p, v3(0, 0, 1), NULL), LACUNA_STATUS_NULL_POINTER, "out_candela");

    /* Samples are unit directions below the horizon whose pdf the pdf call reproduces. */
    int agree = 0, n = 0;
    for (int i = 0; i < 16; i++) {
        for (int j = 0; j < 16; j++) {
            lacuna_vec3 d;
            float pdf = 0, again = 0;
            OK(lacuna_photometric_profile_sample(p, (i + 0.5f) / 16, (j + 0.5f) / 16, &d, &pdf));
            CHECK(close_to(d.x * d.x + d.y * d.y + d.z * d.z, 1.0f, 1e-4f));
            CHECK(d.z >= -1e-3f && pdf > 0.0f);
            OK(lacuna_photometric_profile_pdf(p, d, &again));
            agree += close_to(again, pdf, 1e-3f);
            n++;
        }
    }
    CHECK(agree >= n - 2);
    lacuna_vec3 d;
    float pdf;
    EXPECT(lacuna_photometric_profile_sample(p, 1.0f, 0.5f, &d, &pdf), LACUNA_STATUS_OUT_OF_RANGE, "u0");
    EXPECT(lacuna_photometric_profile_sample(p, 0.5f, -0.1f, &d, &pdf), LACUNA_STATUS_OUT_OF_RANGE, "u1");
    EXPECT(lacuna_photometric_profile_sample(p, 0.5f, 0.5f, NULL, &pdf), LACUNA_STATUS_NULL_POINTER,
           "out_local_direction");
    EXPECT(lacuna_photometric_profile_sample(p, 0.5f, 0.5f, &d, NULL), LACUNA_STATUS_NULL_POINTER, "out_pdf");
    EXPECT(lacuna_photometric_profile_sample(NULL, 0.5f, 0.5f, &d, &pdf), LACUNA_STATUS_NULL_POINTER, "profile");
    EXPECT(lacuna_photometric_profile_pdf(p, v3(0, 0, 0), &pdf), LACUNA_STATUS_INVALID_ARGUMENT, "non-zero");
    EXPECT(lacuna_photometric_profile_pdf(p, v3(0, 0, 1), NULL), LACUNA_STATUS_NULL_POINTER, "out_pdf");
    OK(lacuna_photometric_profile_pdf(p, v3(0, 0, -1), &pdf));
    CHECK(pdf == 0.0f); /* nothing is emitted upwards, so nothing is sampled there */
}

/* A floor at y = 0 lit by the downlight 2 units above it, pointing down; the light sampler
 * reports the light's kind and its radiance at the floor's centre. */
static void test_light(lacuna_context *ctx, lacuna_photometric_profile *held, const lacuna_photometric_profile *p) {
    lacuna_scene_builder *b = NULL;
    OK(lacuna_scene_builder_new(ctx, &b));
    uint32_t mat = 99;
    OK(lacuna_scene_builder_add_material(b, LACUNA_MATERIAL_KIND_DIFFUSE, &mat));
    add_floor_quad(b, 1.0f, mat);
    lacuna_vec3 at = v3(0, 2, 0), down = v3(0, -1, 0), c0 = v3(1, 0, 0);
    EXPECT(lacuna_scene_builder_add_photometric_light(NULL, p, at, down, c0, rgb(1, 1, 1)),
           LACUNA_STATUS_NULL_POINTER, "builder");
    EXPECT(lacuna_scene_builder_add_photometric_light(b, NULL, at, down, c0, rgb(1, 1, 1)),
           LACUNA_STATUS_NULL_POINTER, "profile");
    EXPECT(lacuna_scene_builder_add_photometric_light(b, p, v3(INFINITY, 0, 0), down, c0, rgb(1, 1, 1)),
           LACUNA_STATUS_INVALID_ARGUMENT, "position");
    EXPECT(lacuna_scene_builder_add_photometric_light(b, p, at, v3(0, 0, 0), c0, rgb(1, 1, 1)),
           LACUNA_STATUS_INVALID_ARGUMENT, "direction");
    EXPECT(lacuna_scene_builder_add_photometric_light(b, p, at, down, v3(NAN, 0, 0), rgb(1, 1, 1)),
           LACUNA_STATUS_INVALID_ARGUMENT, "c0");
    EXPECT(lacuna_scene_builder_add_photometric_light(b, p, at, down, c0, rgb(-1, 1, 1)),
           LACUNA_STATUS_INVALID_ARGUMENT, "intensity");
    OK(lacuna_scene_builder_add_photometric_light(b, held, at, down, c0, rgb(0.5f, 0.5f, 0.5f)));
    lacuna_photometric_profile_release(held);
    OK(lacuna_scene_builder_set_camera(b, v3(0, 3, 0.01f), v3(0, 0, 0), v3(0, 1, 0), 60));
    lacuna_scene *scene = NULL;
    OK(lacuna_scene_builder_build(b, &scene));

    lacuna_light_sampler *ls = NULL;
    OK(lacuna_light_sampler_new(scene, LACUNA_TRIANGLE_STRATEGY_AREA, LACUNA_ENVIRONMENT_STRATEGY_LAT_LONG, &ls));
    lacuna_light_info info;
    OK(lacuna_light_sampler_get_light_info(ls, 0, &info));
    CHECK(info.kind == LACUNA_LIGHT_KIND_PHOTOMETRIC);
    CHECK(info.power > 0.0f && info.selection_probability == 1.0f);
    lacuna_light_query q;
    lacuna_light_query_init(&q);
    q.u[0] = 0.5f;
    q.u[1] = 0.5f;
    lacuna_light_sample s;
    OK(lacuna_light_sampler_sample(ls, &q, &s));
    /* 0.5 x 200 cd at the nadir over a distance of 2. */
    CHECK(s.light == 0 && close_to(s.radiance.r, 0.5f * 200.0f / 4.0f, 1e-4f));
    CHECK((s.flags & LACUNA_LIGHT_SAMPLE_DELTA) != 0);
    lacuna_light_sampler_release(ls);

    /* A render lights the floor under the lamp. */
    lacuna_render_job *job = NULL;
    OK(lacuna_render_job_new(scene, "path", &job));
    OK(lacuna_render_job_set_resolution(job, 8, 8));
    OK(lacuna_render_job_set_samples_per_pixel(job, 4));
    lacuna_film *film = NULL;
    OK(lacuna_render_job_run(job, &film));
    float px[8 * 8 * 3];
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, px, 8, 8, 0, 0));
    float centre = px[(4 * 8 + 4) * 3];
    CHECK(centre > 0.0f && isfinite(centre));
    lacuna_film_release(film);
    lacuna_render_job_free(job);
    lacuna_scene_release(scene);
}

int main(int argc, char **argv) {
    if (argc > 1) snprintf(dir, sizeof dir, "%s", argv[1]);
    lacuna_context *ctx = NULL;
    OK(lacuna_context_new(&ctx));
    test_loading();
    lacuna_photometric_profile *p = NULL;
    OK(lacuna_photometric_profile_new_from_ies_buffer((const uint8_t *)IES, strlen(IES), &p));
    test_queries(p);
    /* Scenes keep their own reference: a light made from a second profile outlives it. */
    lacuna_photometric_profile *held = NULL;
    OK(lacuna_photometric_profile_new_from_ies_buffer((const uint8_t *)IES, strlen(IES), &held));
    test_light(ctx, held, p);
    lacuna_photometric_profile_release(p);
    lacuna_context_release(ctx);
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
