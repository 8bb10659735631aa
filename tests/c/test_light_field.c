/* Tests of the light-field part of Lacuna's C API, written in C: every function, every error
 * path. Built and run by tests/c_api.rs (plain, under AddressSanitizer and under valgrind).
 * argv[1] is a scratch directory. Prints "N passed, N failed" and exits non-zero on any
 * failure. */
#include "check.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define NODES 3
#define RES 4
#define FLOATS (3 * NODES * NODES * RES * RES)

static int close_to(float a, float b, float tolerance) { return fabsf(a - b) <= tolerance * fmaxf(1.0f, fabsf(b)); }

/* 3 x 3 tent functions 0.2 apart over [-0.2, 0.2]^2, images of 4 x 4 pixels over [-1, 1]^2 half
 * a metre away; every image a gradient in x. */
static lacuna_light_field_layout layout(void) {
    lacuna_light_field_layout l;
    memset(&l, 0, sizeof l);
    l.nodes_x = NODES;
    l.nodes_y = NODES;
    l.node_min[0] = l.node_min[1] = -0.2f;
    l.node_spacing[0] = l.node_spacing[1] = 0.2f;
    l.basis = LACUNA_LIGHT_FIELD_BASIS_LINEAR;
    l.plane_distance = 0.5f;
    l.image_min[0] = l.image_min[1] = -1.0f;
    l.image_max[0] = l.image_max[1] = 1.0f;
    l.resolution_x = RES;
    l.resolution_y = RES;
    return l;
}

static float pixels[FLOATS];

static void fill(void) {
    for (int i = 0; i < FLOATS / 3; i++) {
        float v = 1.0f + (float)(i % RES);
        pixels[3 * i] = v;
        pixels[3 * i + 1] = v;
        pixels[3 * i + 2] = 0.5f * v;
    }
}

static void test_loading(void) {
    lacuna_light_field *f = NULL;
    lacuna_light_field_layout l = layout();
    EXPECT(lacuna_light_field_new_from_buffer(NULL, pixels, FLOATS, &f), LACUNA_STATUS_NULL_POINTER, "layout");
    EXPECT(lacuna_light_field_new_from_buffer(&l, NULL, FLOATS, &f), LACUNA_STATUS_NULL_POINTER, "rgb");
    EXPECT(lacuna_light_field_new_from_buffer(&l, pixels, FLOATS, NULL), LACUNA_STATUS_NULL_POINTER, "out_field");
    EXPECT(lacuna_light_field_new_from_buffer(&l, pixels, FLOATS - 3, &f), LACUNA_STATUS_INVALID_ARGUMENT,
           "float_count");
    l.basis = 7;
    EXPECT(lacuna_light_field_new_from_buffer(&l, pixels, FLOATS, &f), LACUNA_STATUS_INVALID_ARGUMENT, "basis");
    l = layout();
    l.plane_distance = 0.0f;
    EXPECT(lacuna_light_field_new_from_buffer(&l, pixels, FLOATS, &f), LACUNA_STATUS_INVALID_ARGUMENT,
           "plane distance");
    l = layout();
    l.nodes_x = 0;
    EXPECT(lacuna_light_field_new_from_buffer(&l, pixels, 0, &f), LACUNA_STATUS_INVALID_ARGUMENT, "nodes");
    l = layout();
    pixels[5] = -1.0f;
    EXPECT(lacuna_light_field_new_from_buffer(&l, pixels, FLOATS, &f), LACUNA_STATUS_INVALID_ARGUMENT, ">= 0");
    fill();
    CHECK(f == NULL);
    EXPECT(lacuna_light_field_new_from_file(NULL, &f), LACUNA_STATUS_NULL_POINTER, "path");
    EXPECT(lacuna_light_field_new_from_file(path_in_dir("missing.exr"), &f), LACUNA_STATUS_IO, "missing.exr");
    /* A truncated EXR: the magic number and little else. */
    const char *cut = path_in_dir("cut.exr");
    FILE *file = fopen(cut, "wb");
    CHECK(file != NULL);
    if (file) {
        const unsigned char bytes[] = {0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0, 'c', 'h'};
        fwrite(bytes, 1, sizeof bytes, file);
        fclose(file);
    }
    EXPECT(lacuna_light_field_new_from_file(cut, &f), LACUNA_STATUS_PARSE, "cut.exr");
    CHECK(f == NULL);
}

static void test_queries(const lacuna_light_field *f) {
    lacuna_light_field_info info;
    EXPECT(lacuna_light_field_get_info(NULL, &info), LACUNA_STATUS_NULL_POINTER, "field");
    EXPECT(lacuna_light_field_get_info(f, NULL), LACUNA_STATUS_NULL_POINTER, "out_info");
    OK(lacuna_light_field_get_info(f, &info));
    CHECK(info.layout.nodes_x == NODES && info.layout.resolution_y == RES);
    CHECK(info.layout.basis == LACUNA_LIGHT_FIELD_BASIS_LINEAR);
    CHECK(info.power > 0.0f && info.memory_bytes > 0);

    /* Samples from a receiver 2 m away: their density is what `pdf` says, and positive. */
    lacuna_vec3 receiver = v3(0.1f, 0.0f, 2.0f), point;
    lacuna_rgb radiance;
    float pdf, again;
    int agree = 0, n = 0;
    for (int i = 0; i < 8; i++) {
        for (int j = 0; j < 8; j++) {
            OK(lacuna_light_field_sample(f, receiver, (i + 0.5f) / 8, (j + 0.5f) / 8, &point, &radiance, &pdf));
            CHECK(pdf > 0.0f && radiance.r > 0.0f && close_to(point.z, 0.5f, 1e-6f));
            OK(lacuna_light_field_pdf(f, receiver, point, &again));
            agree += close_to(again, pdf, 1e-4f);
            n++;
        }
    }
    CHECK(agree == n);
    /* A receiver between the planes is not lit: density 0, no error. */
    OK(lacuna_light_field_sample(f, v3(0, 0, 0.2f), 0.5f, 0.5f, &point, &radiance, &pdf));
    CHECK(pdf == 0.0f && radiance.r == 0.0f);
    EXPECT(lacuna_light_field_sample(f, receiver, 1.0f, 0.5f, &point, &radiance, &pdf), LACUNA_STATUS_OUT_OF_RANGE,
           "u0");
    EXPECT(lacuna_light_field_sample(f, v3(NAN, 0, 2), 0.5f, 0.5f, &point, &radiance, &pdf),
           LACUNA_STATUS_INVALID_ARGUMENT, "receiver");
    EXPECT(lacuna_light_field_sample(f, receiver, 0.5f, 0.5f, NULL, &radiance, &pdf), LACUNA_STATUS_NULL_POINTER,
           "out_point");
    EXPECT(lacuna_light_field_sample(f, receiver, 0.5f, 0.5f, &point, NULL, &pdf), LACUNA_STATUS_NULL_POINTER,
           "out_radiance");
    EXPECT(lacuna_light_field_sample(f, receiver, 0.5f, 0.5f, &point, &radiance, NULL), LACUNA_STATUS_NULL_POINTER,
           "out_pdf");
    EXPECT(lacuna_light_field_pdf(f, receiver, v3(0, 0, INFINITY), &pdf), LACUNA_STATUS_INVALID_ARGUMENT, "point");
    EXPECT(lacuna_light_field_pdf(f, receiver, point, NULL), LACUNA_STATUS_NULL_POINTER, "out_pdf");
    OK(lacuna_light_field_pdf(f, receiver, v3(5, 5, 0.5f), &pdf));
    CHECK(pdf == 0.0f); /* outside the images */
}

/* A floor at y = 0 lit by the field 1.5 m above it, facing down. */
static void test_light(lacuna_context *ctx, lacuna_light_field *held) {
    lacuna_scene_builder *b = NULL;
    OK(lacuna_scene_builder_new(ctx, &b));
    uint32_t mat = 99;
    OK(lacuna_scene_builder_add_material(b, LACUNA_MATERIAL_KIND_DIFFUSE, &mat));
    add_floor_quad(b, 2.0f, mat);
    lacuna_vec3 at = v3(0, 1.5f, 0), down = v3(0, -1, 0), x = v3(1, 0, 0);
    EXPECT(lacuna_scene_builder_add_light_field_light(NULL, held, at, down, x, rgb(1, 1, 1)),
           LACUNA_STATUS_NULL_POINTER, "builder");
    EXPECT(lacuna_scene_builder_add_light_field_light(b, NULL, at, down, x, rgb(1, 1, 1)),
           LACUNA_STATUS_NULL_POINTER, "field");
    EXPECT(lacuna_scene_builder_add_light_field_light(b, held, v3(INFINITY, 0, 0), down, x, rgb(1, 1, 1)),
           LACUNA_STATUS_INVALID_ARGUMENT, "position");
    EXPECT(lacuna_scene_builder_add_light_field_light(b, held, at, v3(0, 0, 0), x, rgb(1, 1, 1)),
           LACUNA_STATUS_INVALID_ARGUMENT, "direction");
    EXPECT(lacuna_scene_builder_add_light_field_light(b, held, at, down, v3(NAN, 0, 0), rgb(1, 1, 1)),
           LACUNA_STATUS_INVALID_ARGUMENT, "x_axis");
    EXPECT(lacuna_scene_builder_add_light_field_light(b, held, at, down, x, rgb(-1, 1, 1)),
           LACUNA_STATUS_INVALID_ARGUMENT, "scale");
    OK(lacuna_scene_builder_add_light_field_light(b, held, at, down, x, rgb(1, 1, 1)));
    lacuna_light_field_release(held); /* the builder keeps its own reference */
    OK(lacuna_scene_builder_set_camera(b, v3(0, 3, 0.01f), v3(0, 0, 0), v3(0, 1, 0), 60));
    lacuna_scene *scene = NULL;
    OK(lacuna_scene_builder_build(b, &scene));

    lacuna_light_sampler *ls = NULL;
    OK(lacuna_light_sampler_new(scene, LACUNA_TRIANGLE_STRATEGY_AREA, LACUNA_ENVIRONMENT_STRATEGY_LAT_LONG, &ls));
    lacuna_light_info info;
    OK(lacuna_light_sampler_get_light_info(ls, 0, &info));
    CHECK(info.kind == LACUNA_LIGHT_KIND_LIGHT_FIELD);
    CHECK(info.power > 0.0f && info.selection_probability == 1.0f);
    /* Emitted rays: the densities from their origin are the sample's own. */
    int checked = 0;
    for (int i = 0; i < 64; ++i) {
        const float u[4] = {(i + 0.5f) / 64.0f, (i * 37 % 64 + 0.5f) / 64.0f, (i * 11 % 64 + 0.5f) / 64.0f,
                            (i * 23 % 64 + 0.5f) / 64.0f};
        lacuna_emission_sample e;
        OK(lacuna_light_sampler_sample_emission(ls, u, &e));
        if (e.pdf_position == 0.0f) continue; /* no ray from these numbers */
        float pp = 0, pd = 0;
        OK(lacuna_light_sampler_emission_pdf_at(ls, 0, v3(e.origin[0], e.origin[1], e.origin[2]),
                                                v3(e.direction[0], e.direction[1], e.direction[2]), &pp, &pd));
        CHECK(fabsf(pp - e.pdf_position) <= 1e-3f * e.pdf_position);
        CHECK(fabsf(pd - e.pdf_direction) <= 3e-3f * e.pdf_direction);
        ++checked;
    }
    CHECK(checked > 32);
    float pp = 0, pd = 0;
    EXPECT(lacuna_light_sampler_emission_pdf_at(ls, 0, v3(NAN, 0, 0), v3(0, -1, 0), &pp, &pd),
           LACUNA_STATUS_INVALID_ARGUMENT, "origin");
    EXPECT(lacuna_light_sampler_emission_pdf_at(ls, 1, v3(0, 0, 0), v3(0, -1, 0), &pp, &pd),
           LACUNA_STATUS_OUT_OF_RANGE, "light 1");
    EXPECT(lacuna_light_sampler_emission_pdf_at(ls, 0, v3(0, 0, 0), v3(0, 0, 0), &pp, &pd),
           LACUNA_STATUS_INVALID_ARGUMENT, "non-zero");
    EXPECT(lacuna_light_sampler_emission_pdf_at(ls, 0, v3(0, 0, 0), v3(0, -1, 0), NULL, &pd),
           LACUNA_STATUS_NULL_POINTER, "out_pdf_position");
    lacuna_light_sampler_release(ls);

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
    /* bdpt renders it. */
    OK(lacuna_render_job_new(scene, "bdpt", &job));
    OK(lacuna_render_job_set_resolution(job, 8, 8));
    OK(lacuna_render_job_set_samples_per_pixel(job, 4));
    film = NULL;
    OK(lacuna_render_job_run(job, &film));
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, px, 8, 8, 0, 0));
    centre = px[(4 * 8 + 4) * 3];
    CHECK(centre > 0.0f && isfinite(centre));
    lacuna_film_release(film);
    lacuna_render_job_free(job);
    /* bdpt_ic renders it too (its resampled connections are verified with light fields). */
    OK(lacuna_render_job_new(scene, "bdpt_ic", &job));
    OK(lacuna_render_job_set_resolution(job, 8, 8));
    OK(lacuna_render_job_set_samples_per_pixel(job, 4));
    film = NULL;
    OK(lacuna_render_job_run(job, &film));
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, px, 8, 8, 0, 0));
    centre = px[(4 * 8 + 4) * 3];
    CHECK(centre > 0.0f && isfinite(centre));
    lacuna_film_release(film);
    lacuna_render_job_free(job);
    lacuna_scene_release(scene);
}

int main(int argc, char **argv) {
    if (argc > 1) snprintf(dir, sizeof dir, "%s", argv[1]);
    fill();
    lacuna_context *ctx = NULL;
    OK(lacuna_context_new(&ctx));
    test_loading();
    lacuna_light_field_layout l = layout();
    lacuna_light_field *f = NULL;
    OK(lacuna_light_field_new_from_buffer(&l, pixels, FLOATS, &f));
    test_queries(f);
    lacuna_light_field_retain(f);
    lacuna_light_field_release(f);
    lacuna_light_field_retain(NULL);
    lacuna_light_field_release(NULL);
    test_light(ctx, f);
    lacuna_context_release(ctx);
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
