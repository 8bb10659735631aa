/* Tests of Lacuna's C API, written in C: every function, every error path. Built and run by
 * tests/c_api.rs (plain, under AddressSanitizer and under valgrind). argv[1] is a scratch
 * directory. Prints "N passed, N failed" and exits non-zero on any failure. */
#include "check.h"

#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

static void write_file(const char *name, const char *text) {
    FILE *f = fopen(path_in_dir(name), "w");
    if (!f) {
        perror(name);
        exit(2);
    }
    fputs(text, f);
    fclose(f);
}

static bool file_exists(const char *path) { return access(path, F_OK) == 0; }

/* Whether the text file at `path` contains `needle` (files of this test are small). */
static bool file_contains(const char *path, const char *needle) {
    FILE *f = fopen(path, "r");
    if (!f) return false;
    static char text[1 << 16];
    size_t n = fread(text, 1, sizeof text - 1, f);
    fclose(f);
    text[n] = 0;
    return strstr(text, needle) != NULL;
}

/* ---------------------------------------------------------------------------------------- */

static void test_version_and_status(void) {
    CHECK(strcmp(lacuna_last_error_message(), "") == 0);
    CHECK(lacuna_version() == LACUNA_VERSION);
    CHECK(LACUNA_VERSION ==
          ((LACUNA_VERSION_MAJOR << 16) | (LACUNA_VERSION_MINOR << 8) | LACUNA_VERSION_PATCH));
    CHECK(strcmp(lacuna_version_string(), LACUNA_VERSION_STRING) == 0);
    CHECK(strcmp(lacuna_status_string(LACUNA_STATUS_OK), "LACUNA_STATUS_OK") == 0);
    CHECK(strcmp(lacuna_status_string(LACUNA_STATUS_NULL_POINTER), "LACUNA_STATUS_NULL_POINTER") == 0);
    CHECK(strcmp(lacuna_status_string(LACUNA_STATUS_INVALID_OPERATION),
                 "LACUNA_STATUS_INVALID_OPERATION") == 0);
    CHECK(strcmp(lacuna_status_string(12345), "LACUNA_STATUS_UNKNOWN") == 0);
    for (uint32_t s = 0; s <= LACUNA_STATUS_INVALID_OPERATION; s++)
        CHECK(strncmp(lacuna_status_string(s), "LACUNA_STATUS_", 14) == 0 &&
              strcmp(lacuna_status_string(s), "LACUNA_STATUS_UNKNOWN") != 0);
    /* The panic boundary. */
    EXPECT(lacuna_debug_trigger_panic(), LACUNA_STATUS_PANIC, "internal panic");
    CHECK(strstr(lacuna_last_error_message(), "lacuna_debug_trigger_panic") != NULL);
    /* Successful calls leave the message alone. */
    CHECK(lacuna_version() == LACUNA_VERSION);
    CHECK(strstr(lacuna_last_error_message(), "internal panic") != NULL);
}

/* Error callback: counts calls and keeps the last status. */
static int callback_calls;
static lacuna_status callback_status;
static char callback_message[512];
static void on_error(void *user, lacuna_status status, const char *message) {
    CHECK(user == (void *)&callback_calls);
    callback_calls++;
    callback_status = status;
    snprintf(callback_message, sizeof callback_message, "%s", message);
}

static void test_context(void) {
    lacuna_context *ctx = NULL;
    EXPECT(lacuna_context_new(NULL), LACUNA_STATUS_NULL_POINTER, "out_context");
    OK(lacuna_context_new(&ctx));
    CHECK(ctx != NULL);
    uint32_t n = 99;
    OK(lacuna_context_get_thread_count(ctx, &n));
    CHECK(n == 0);
    OK(lacuna_context_set_thread_count(ctx, 2));
    OK(lacuna_context_get_thread_count(ctx, &n));
    CHECK(n == 2);
    EXPECT(lacuna_context_set_thread_count(ctx, LACUNA_MAX_THREADS + 1), LACUNA_STATUS_OUT_OF_RANGE,
           "thread_count");
    EXPECT(lacuna_context_set_thread_count(NULL, 1), LACUNA_STATUS_NULL_POINTER, "context");
    EXPECT(lacuna_context_get_thread_count(ctx, NULL), LACUNA_STATUS_NULL_POINTER, "out_thread_count");
    EXPECT(lacuna_context_get_thread_count(NULL, &n), LACUNA_STATUS_NULL_POINTER, "context");
    EXPECT(lacuna_context_set_memory_budget(ctx, 0), LACUNA_STATUS_INVALID_ARGUMENT, "budget");
    EXPECT(lacuna_context_set_memory_budget(NULL, 10), LACUNA_STATUS_NULL_POINTER, "context");
    OK(lacuna_context_set_memory_budget(ctx, LACUNA_DEFAULT_MEMORY_BUDGET));
    EXPECT(lacuna_context_set_error_callback(NULL, on_error, NULL), LACUNA_STATUS_NULL_POINTER, "context");
    OK(lacuna_context_set_error_callback(ctx, on_error, &callback_calls));
    EXPECT(lacuna_context_set_thread_count(ctx, 100000), LACUNA_STATUS_OUT_OF_RANGE, "100000");
    CHECK(callback_calls == 1);
    CHECK(callback_status == LACUNA_STATUS_OUT_OF_RANGE);
    CHECK(strstr(callback_message, "lacuna_context_set_thread_count") != NULL);
    CHECK(strcmp(callback_message, lacuna_last_error_message()) == 0);
    OK(lacuna_context_set_error_callback(ctx, NULL, NULL));
    EXPECT(lacuna_context_set_thread_count(ctx, 100000), LACUNA_STATUS_OUT_OF_RANGE, NULL);
    CHECK(callback_calls == 1);
    lacuna_context_retain(ctx);
    lacuna_context_release(ctx);
    lacuna_context_retain(NULL);
    lacuna_context_release(NULL);
    lacuna_context_release(ctx);
}

/* Interleaved vertex layout: exercises strides. */
typedef struct vertex {
    float p[3];
    float n[3];
    float uv[2];
} vertex;

static void test_mesh(void) {
    lacuna_mesh *m = NULL;
    EXPECT(lacuna_mesh_new(NULL), LACUNA_STATUS_NULL_POINTER, "out_mesh");
    OK(lacuna_mesh_new(&m));
    vertex v[4] = {{{0, 0, 0}, {0, 0, 1}, {0, 0}},
                   {{1, 0, 0}, {0, 0, 1}, {1, 0}},
                   {{1, 1, 0}, {0, 0, 1}, {1, 1}},
                   {{0, 1, 0}, {0, 0, 1}, {0, 1}}};
    OK(lacuna_mesh_set_positions(m, v[0].p, sizeof(vertex), 4));
    OK(lacuna_mesh_set_normals(m, v[0].n, sizeof(vertex), 4));
    OK(lacuna_mesh_set_uvs(m, v[0].uv, sizeof(vertex), 4));
    uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    OK(lacuna_mesh_set_indices(m, idx, 0, 2));
    uint32_t mats[2] = {0, 0};
    OK(lacuna_mesh_set_materials(m, mats, 0, 2));
    OK(lacuna_mesh_set_material(m, 0));
    OK(lacuna_mesh_set_name(m, "quad"));
    size_t nv = 0, nt = 0;
    OK(lacuna_mesh_get_counts(m, &nv, &nt));
    CHECK(nv == 4 && nt == 2);
    /* Errors. */
    EXPECT(lacuna_mesh_set_positions(m, v[0].p, 8, 4), LACUNA_STATUS_INVALID_ARGUMENT, "stride 8");
    EXPECT(lacuna_mesh_set_positions(m, NULL, 0, 4), LACUNA_STATUS_NULL_POINTER, "positions");
    EXPECT(lacuna_mesh_set_positions(m, v[0].p, SIZE_MAX / 2, 4), LACUNA_STATUS_OUT_OF_RANGE,
           "positions");
    EXPECT(lacuna_mesh_set_positions(NULL, v[0].p, 0, 4), LACUNA_STATUS_NULL_POINTER, "mesh");
    EXPECT(lacuna_mesh_set_uvs(m, v[0].uv, 4, 4), LACUNA_STATUS_INVALID_ARGUMENT, "uvs");
    EXPECT(lacuna_mesh_set_indices(m, idx, 11, 2), LACUNA_STATUS_INVALID_ARGUMENT, "indices");
    EXPECT(lacuna_mesh_set_materials(m, mats, 0, 0), LACUNA_STATUS_INVALID_ARGUMENT, "material count 0");
    EXPECT(lacuna_mesh_set_name(m, NULL), LACUNA_STATUS_NULL_POINTER, "name");
    EXPECT(lacuna_mesh_set_name(m, "\xff\xfe"), LACUNA_STATUS_INVALID_ARGUMENT, "UTF-8");
    EXPECT(lacuna_mesh_set_material(NULL, 0), LACUNA_STATUS_NULL_POINTER, "mesh");
    EXPECT(lacuna_mesh_get_counts(m, NULL, &nt), LACUNA_STATUS_NULL_POINTER, "out_vertex_count");
    EXPECT(lacuna_mesh_get_counts(NULL, &nv, &nt), LACUNA_STATUS_NULL_POINTER, "mesh");
    /* Failed calls kept the data; a count of 0 with NULL clears optional attributes. */
    OK(lacuna_mesh_get_counts(m, &nv, &nt));
    CHECK(nv == 4 && nt == 2);
    OK(lacuna_mesh_set_normals(m, NULL, 0, 0));
    OK(lacuna_mesh_set_uvs(m, NULL, 0, 0));
    lacuna_mesh_free(m);
    lacuna_mesh_free(NULL);
}

/* A closed box [-1,1]^3 seen from inside plus an emissive quad under its ceiling. */
static const float box_p[8][3] = {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1},
                                  {-1, -1, 1},  {1, -1, 1},  {1, 1, 1},  {-1, 1, 1}};
static const uint32_t box_i[12][3] = {{0, 2, 1}, {0, 3, 2}, {4, 5, 6}, {4, 6, 7}, {0, 1, 5}, {0, 5, 4},
                                      {3, 6, 2}, {3, 7, 6}, {0, 4, 7}, {0, 7, 3}, {1, 2, 6}, {1, 6, 5}};

static lacuna_scene *build_box_scene(lacuna_context *ctx) {
    lacuna_scene_builder *b = NULL;
    OK(lacuna_scene_builder_new(ctx, &b));
    uint32_t white = 99, light = 99;
    OK(lacuna_scene_builder_add_material(b, LACUNA_MATERIAL_KIND_DIFFUSE, &white));
    OK(lacuna_scene_builder_add_material(b, LACUNA_MATERIAL_KIND_DIFFUSE, &light));
    CHECK(white == 0 && light == 1);
    OK(lacuna_scene_builder_set_material_rgb(b, light, LACUNA_MATERIAL_RGB_DIFFUSE, rgb(0, 0, 0)));
    OK(lacuna_scene_builder_set_material_rgb(b, light, LACUNA_MATERIAL_RGB_EMISSION, rgb(5, 5, 5)));
    lacuna_mesh *m = NULL;
    OK(lacuna_mesh_new(&m));
    OK(lacuna_mesh_set_positions(m, &box_p[0][0], 0, 8));
    OK(lacuna_mesh_set_indices(m, &box_i[0][0], 0, 12));
    OK(lacuna_mesh_set_material(m, white));
    uint32_t mesh_index = 99;
    OK(lacuna_scene_builder_add_mesh(b, m, &mesh_index));
    CHECK(mesh_index == 0);
    const float lp[4][3] = {{-0.3f, 0.99f, -0.3f}, {0.3f, 0.99f, -0.3f}, {0.3f, 0.99f, 0.3f}, {-0.3f, 0.99f, 0.3f}};
    const uint32_t li[2][3] = {{0, 1, 2}, {0, 2, 3}};
    OK(lacuna_mesh_set_positions(m, &lp[0][0], 0, 4));
    OK(lacuna_mesh_set_indices(m, &li[0][0], 0, 2));
    OK(lacuna_mesh_set_material(m, light));
    OK(lacuna_scene_builder_add_mesh(b, m, &mesh_index));
    CHECK(mesh_index == 1);
    lacuna_mesh_free(m);
    OK(lacuna_scene_builder_set_camera(b, v3(0, 0, 0.9f), v3(0, 0, -1), v3(0, 1, 0), 70));
    lacuna_scene *scene = NULL;
    OK(lacuna_scene_builder_build(b, &scene));
    CHECK(scene != NULL);
    return scene;
}

static void test_builder(lacuna_context *ctx) {
    lacuna_scene_builder *b = NULL;
    EXPECT(lacuna_scene_builder_new(NULL, &b), LACUNA_STATUS_NULL_POINTER, "context");
    EXPECT(lacuna_scene_builder_new(ctx, NULL), LACUNA_STATUS_NULL_POINTER, "out_builder");
    OK(lacuna_scene_builder_new(ctx, &b));
    uint32_t mat = 99, count = 99;
    /* Materials. */
    EXPECT(lacuna_scene_builder_add_material(b, 7, &mat), LACUNA_STATUS_INVALID_ARGUMENT, "`kind` = 7");
    EXPECT(lacuna_scene_builder_add_material(b, LACUNA_MATERIAL_KIND_DIFFUSE, NULL),
           LACUNA_STATUS_NULL_POINTER, "out_index");
    EXPECT(lacuna_scene_builder_add_material(NULL, LACUNA_MATERIAL_KIND_DIFFUSE, &mat),
           LACUNA_STATUS_NULL_POINTER, "builder");
    CHECK(mat == 99); /* out-parameters untouched on failure */
    OK(lacuna_scene_builder_add_material(b, LACUNA_MATERIAL_KIND_GLOSSY, &mat));
    CHECK(mat == 0);
    uint32_t kinds[3] = {LACUNA_MATERIAL_KIND_DIFFUSE, LACUNA_MATERIAL_KIND_MIRROR,
                         LACUNA_MATERIAL_KIND_DIELECTRIC};
    for (int i = 0; i < 3; i++) OK(lacuna_scene_builder_add_material(b, kinds[i], &mat));
    OK(lacuna_scene_builder_get_material_count(b, &count));
    CHECK(count == 4);
    EXPECT(lacuna_scene_builder_get_material_count(b, NULL), LACUNA_STATUS_NULL_POINTER, "out_count");
    EXPECT(lacuna_scene_builder_get_material_count(NULL, &count), LACUNA_STATUS_NULL_POINTER, "builder");
    EXPECT(lacuna_scene_builder_set_material_rgb(b, 4, LACUNA_MATERIAL_RGB_DIFFUSE, rgb(1, 1, 1)),
           LACUNA_STATUS_OUT_OF_RANGE, "material index 4");
    EXPECT(lacuna_scene_builder_set_material_rgb(b, 0, 3, rgb(1, 1, 1)), LACUNA_STATUS_INVALID_ARGUMENT,
           "`param` = 3");
    EXPECT(lacuna_scene_builder_set_material_rgb(b, 0, LACUNA_MATERIAL_RGB_DIFFUSE, rgb(NAN, 0, 0)),
           LACUNA_STATUS_INVALID_ARGUMENT, "finite");
    EXPECT(lacuna_scene_builder_set_material_rgb(b, 2, LACUNA_MATERIAL_RGB_DIFFUSE, rgb(2, 0, 0)),
           LACUNA_STATUS_INVALID_ARGUMENT, "diffuse");
    EXPECT(lacuna_scene_builder_set_material_rgb(b, 0, LACUNA_MATERIAL_RGB_SPECULAR, rgb(0.9f, 0.9f, 0.9f)),
           LACUNA_STATUS_INVALID_ARGUMENT, "exceeds 1");
    EXPECT(lacuna_scene_builder_set_material_rgb(b, 0, LACUNA_MATERIAL_RGB_EMISSION, rgb(-1, 0, 0)),
           LACUNA_STATUS_INVALID_ARGUMENT, "emission");
    OK(lacuna_scene_builder_set_material_rgb(b, 0, LACUNA_MATERIAL_RGB_DIFFUSE, rgb(0.1f, 0.2f, 0.3f)));
    OK(lacuna_scene_builder_set_material_rgb(b, 0, LACUNA_MATERIAL_RGB_SPECULAR, rgb(0.5f, 0.5f, 0.5f)));
    OK(lacuna_scene_builder_set_material_float(b, 0, LACUNA_MATERIAL_FLOAT_EXPONENT, 50));
    OK(lacuna_scene_builder_set_material_float(b, 3, LACUNA_MATERIAL_FLOAT_IOR, 1.33f));
    EXPECT(lacuna_scene_builder_set_material_float(b, 3, LACUNA_MATERIAL_FLOAT_IOR, -1),
           LACUNA_STATUS_INVALID_ARGUMENT, "ior");
    EXPECT(lacuna_scene_builder_set_material_float(b, 0, LACUNA_MATERIAL_FLOAT_EXPONENT, INFINITY),
           LACUNA_STATUS_INVALID_ARGUMENT, "value");
    OK(lacuna_scene_builder_set_material_float(b, 3, LACUNA_MATERIAL_FLOAT_ROUGHNESS, 0.4f));
    EXPECT(lacuna_scene_builder_set_material_float(b, 3, LACUNA_MATERIAL_FLOAT_ROUGHNESS, 2),
           LACUNA_STATUS_INVALID_ARGUMENT, "roughness");
    EXPECT(lacuna_scene_builder_set_material_float(b, 0, 3, 1), LACUNA_STATUS_INVALID_ARGUMENT, "param");
    EXPECT(lacuna_scene_builder_set_material_float(b, 9, LACUNA_MATERIAL_FLOAT_IOR, 1.5f),
           LACUNA_STATUS_OUT_OF_RANGE, "9");
    OK(lacuna_scene_builder_set_material_name(b, 0, "varnish"));
    EXPECT(lacuna_scene_builder_set_material_name(b, 0, NULL), LACUNA_STATUS_NULL_POINTER, "name");
    EXPECT(lacuna_scene_builder_set_material_name(b, 5, "x"), LACUNA_STATUS_OUT_OF_RANGE, "5");
    /* Meshes. */
    lacuna_mesh *m = NULL;
    OK(lacuna_mesh_new(&m));
    float p[4][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}};
    uint32_t tri[3] = {0, 1, 2};
    OK(lacuna_mesh_set_positions(m, &p[0][0], 0, 4));
    OK(lacuna_mesh_set_indices(m, tri, 0, 1));
    uint32_t mi = 99;
    EXPECT(lacuna_scene_builder_add_mesh(b, NULL, &mi), LACUNA_STATUS_NULL_POINTER, "mesh");
    EXPECT(lacuna_scene_builder_add_mesh(b, m, NULL), LACUNA_STATUS_NULL_POINTER, "out_index");
    OK(lacuna_mesh_set_material(m, 4));
    EXPECT(lacuna_scene_builder_add_mesh(b, m, &mi), LACUNA_STATUS_INVALID_ARGUMENT, "material index 4");
    OK(lacuna_mesh_set_material(m, 0));
    p[1][0] = NAN;
    OK(lacuna_mesh_set_positions(m, &p[0][0], 0, 4));
    EXPECT(lacuna_scene_builder_add_mesh(b, m, &mi), LACUNA_STATUS_INVALID_ARGUMENT, "position 1");
    p[1][0] = 1;
    OK(lacuna_mesh_set_positions(m, &p[0][0], 0, 4));
    uint32_t bad_tri[3] = {0, 1, 7};
    OK(lacuna_mesh_set_indices(m, bad_tri, 0, 1));
    EXPECT(lacuna_scene_builder_add_mesh(b, m, &mi), LACUNA_STATUS_INVALID_ARGUMENT, "vertex index 7");
    uint32_t degenerate[6] = {0, 1, 2, 0, 1, 1};
    OK(lacuna_mesh_set_indices(m, degenerate, 0, 2));
    EXPECT(lacuna_scene_builder_add_mesh(b, m, &mi), LACUNA_STATUS_INVALID_ARGUMENT, "degenerate");
    float n[2][3] = {{0, 0, 1}, {0, 0, 1}};
    OK(lacuna_mesh_set_normals(m, &n[0][0], 0, 2));
    EXPECT(lacuna_scene_builder_add_mesh(b, m, &mi), LACUNA_STATUS_INVALID_ARGUMENT, "2 normals for 4");
    OK(lacuna_mesh_set_normals(m, NULL, 0, 0));
    uint32_t three[3] = {0, 0, 0};
    OK(lacuna_mesh_set_materials(m, three, 0, 3));
    EXPECT(lacuna_scene_builder_add_mesh(b, m, &mi), LACUNA_STATUS_INVALID_ARGUMENT, "3 material indices");
    OK(lacuna_mesh_set_material(m, 0));
    CHECK(mi == 99);
    EXPECT(lacuna_scene_builder_set_degenerate_policy(b, 2), LACUNA_STATUS_INVALID_ARGUMENT, "policy");
    OK(lacuna_scene_builder_set_degenerate_policy(b, LACUNA_DEGENERATE_POLICY_SKIP));
    OK(lacuna_scene_builder_add_mesh(b, m, &mi));
    CHECK(mi == 0);
    OK(lacuna_scene_builder_set_degenerate_policy(b, LACUNA_DEGENERATE_POLICY_ERROR));
    lacuna_mesh_free(m);
    EXPECT(lacuna_scene_builder_set_bvh_quality(b, 3), LACUNA_STATUS_INVALID_ARGUMENT, "quality");
    OK(lacuna_scene_builder_set_bvh_quality(b, LACUNA_BVH_QUALITY_HIGH));
    /* Lights. */
    OK(lacuna_scene_builder_add_point_light(b, v3(0, 2, 0), rgb(1, 1, 1)));
    EXPECT(lacuna_scene_builder_add_point_light(b, v3(NAN, 2, 0), rgb(1, 1, 1)),
           LACUNA_STATUS_INVALID_ARGUMENT, "position");
    EXPECT(lacuna_scene_builder_add_point_light(b, v3(0, 2, 0), rgb(-1, 1, 1)),
           LACUNA_STATUS_INVALID_ARGUMENT, "intensity");
    OK(lacuna_scene_builder_add_spot_light(b, v3(0, 2, 0), v3(0, -1, 0), rgb(1, 1, 1), 20, 30));
    EXPECT(lacuna_scene_builder_add_spot_light(b, v3(0, 2, 0), v3(0, -1, 0), rgb(1, 1, 1), 40, 30),
           LACUNA_STATUS_INVALID_ARGUMENT, "spot angles");
    EXPECT(lacuna_scene_builder_add_spot_light(b, v3(0, 2, 0), v3(0, 0, 0), rgb(1, 1, 1), 20, 30),
           LACUNA_STATUS_INVALID_ARGUMENT, "direction");
    EXPECT(lacuna_scene_builder_add_spot_light(b, v3(0, 2, 0), v3(0, -1, 0), rgb(1, 1, 1), NAN, 30),
           LACUNA_STATUS_INVALID_ARGUMENT, "inner_degrees");
    OK(lacuna_scene_builder_add_directional_light(b, v3(0, -1, 0), rgb(2, 2, 2)));
    EXPECT(lacuna_scene_builder_add_directional_light(b, v3(0, -1, INFINITY), rgb(2, 2, 2)),
           LACUNA_STATUS_INVALID_ARGUMENT, "direction");
    EXPECT(lacuna_scene_builder_add_directional_light(NULL, v3(0, -1, 0), rgb(2, 2, 2)),
           LACUNA_STATUS_NULL_POINTER, "builder");
    /* Camera. */
    EXPECT(lacuna_scene_builder_set_camera_lens(b, 0.1f, 2), LACUNA_STATUS_INVALID_OPERATION, "no camera");
    EXPECT(lacuna_scene_builder_set_camera(b, v3(0, 0, 1), v3(0, 0, 1), v3(0, 1, 0), 40),
           LACUNA_STATUS_INVALID_ARGUMENT, "same point");
    EXPECT(lacuna_scene_builder_set_camera(b, v3(0, 0, 1), v3(0, 0, 0), v3(0, 0, 1), 40),
           LACUNA_STATUS_INVALID_ARGUMENT, "parallel");
    EXPECT(lacuna_scene_builder_set_camera(b, v3(0, 0, 1), v3(0, 0, 0), v3(0, 1, 0), 180),
           LACUNA_STATUS_INVALID_ARGUMENT, "field of view");
    EXPECT(lacuna_scene_builder_set_camera(b, v3(0, NAN, 1), v3(0, 0, 0), v3(0, 1, 0), 40),
           LACUNA_STATUS_INVALID_ARGUMENT, "eye");
    OK(lacuna_scene_builder_set_camera(b, v3(0, 0, 3), v3(0, 0, 0), v3(0, 1, 0), 40));
    OK(lacuna_scene_builder_set_camera_lens(b, 0.05f, 3));
    EXPECT(lacuna_scene_builder_set_camera_lens(b, -1, 3), LACUNA_STATUS_INVALID_ARGUMENT, "lens radius");
    EXPECT(lacuna_scene_builder_set_camera_lens(b, 0.1f, 0), LACUNA_STATUS_INVALID_ARGUMENT, "focus");
    /* OBJ files. */
    size_t tris = 0;
    EXPECT(lacuna_scene_builder_load_obj(b, path_in_dir("missing.obj"), NULL, &tris), LACUNA_STATUS_IO,
           "missing.obj");
    EXPECT(lacuna_scene_builder_load_obj(b, NULL, NULL, &tris), LACUNA_STATUS_NULL_POINTER, "path");
    EXPECT(lacuna_scene_builder_load_obj(b, "", NULL, &tris), LACUNA_STATUS_INVALID_ARGUMENT, "empty");
    write_file("bad.obj", "v 0 0 0\nv 1 0 zero\nf 1 2 3\n");
    EXPECT(lacuna_scene_builder_load_obj(b, path_in_dir("bad.obj"), NULL, &tris), LACUNA_STATUS_PARSE,
           "bad.obj:");
    write_file("tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n");
    float xf[16] = {2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0, 0, 0, -1, 1};
    OK(lacuna_scene_builder_load_obj(b, path_in_dir("tri.obj"), xf, &tris));
    CHECK(tris == 2);
    OK(lacuna_scene_builder_load_obj(b, path_in_dir("tri.obj"), NULL, NULL));
    xf[5] = NAN;
    EXPECT(lacuna_scene_builder_load_obj(b, path_in_dir("tri.obj"), xf, &tris),
           LACUNA_STATUS_INVALID_ARGUMENT, "transform[5]");
    /* Build: NULL arguments, then a real build. */
    lacuna_scene *scene = NULL;
    EXPECT(lacuna_scene_builder_build(NULL, &scene), LACUNA_STATUS_NULL_POINTER, "builder");
    OK(lacuna_scene_builder_build(b, &scene));
    /* A built builder is gone: building, using or freeing it again is caught, not a crash. */
    lacuna_scene *again = NULL;
    EXPECT(lacuna_scene_builder_build(b, &again), LACUNA_STATUS_INVALID_OPERATION,
           "already built or freed");
    CHECK(again == NULL);
    EXPECT(lacuna_scene_builder_set_degenerate_policy(b, LACUNA_DEGENERATE_POLICY_SKIP),
           LACUNA_STATUS_INVALID_OPERATION, "already built or freed");
    lacuna_scene_builder_free(b);
    CHECK(strstr(lacuna_last_error_message(), "lacuna_scene_builder_free") != NULL);
    lacuna_scene_stats st;
    OK(lacuna_scene_get_stats(scene, &st));
    CHECK(st.meshes == 3 && st.triangles == 5 && st.degenerate_triangles_skipped == 1);
    CHECK(st.lights == 3 && st.materials >= 4);
    lacuna_scene_release(scene);
    /* A builder given to build with a NULL out-parameter is consumed all the same. */
    OK(lacuna_scene_builder_new(ctx, &b));
    EXPECT(lacuna_scene_builder_build(b, NULL), LACUNA_STATUS_NULL_POINTER, "out_scene");
    lacuna_scene_builder_free(NULL);
    OK(lacuna_scene_builder_new(ctx, &b));
    lacuna_scene_builder_free(b);
    /* Scene files. */
    EXPECT(lacuna_scene_builder_new_from_file(ctx, path_in_dir("missing.json"), &b), LACUNA_STATUS_IO,
           "missing.json");
    write_file("bad.json", "{\n  \"objects\": [{ \"obj\": \"tri.obj\" }],\n  \"heigth\": 3\n}\n");
    EXPECT(lacuna_scene_builder_new_from_file(ctx, path_in_dir("bad.json"), &b), LACUNA_STATUS_PARSE,
           "heigth");
    write_file("scene.json",
               "{ \"objects\": [{ \"obj\": \"tri.obj\" }],\n"
               "  \"camera\": { \"eye\": [0.5, 0.5, 2], \"target\": [0.5, 0.5, 0], \"up\": [0, 1, 0], \"fov\": 50 },\n"
               "  \"lights\": [{ \"type\": \"point\", \"position\": [0.5, 0.5, 1], \"intensity\": 1 }],\n"
               "  \"render\": { \"width\": 6, \"height\": 5, \"spp\": 2 } }\n");
    EXPECT(lacuna_scene_builder_new_from_file(NULL, path_in_dir("scene.json"), &b), LACUNA_STATUS_NULL_POINTER,
           "context");
    EXPECT(lacuna_scene_builder_new_from_file(ctx, path_in_dir("scene.json"), NULL), LACUNA_STATUS_NULL_POINTER,
           "out_builder");
    OK(lacuna_scene_builder_new_from_file(ctx, path_in_dir("scene.json"), &b));
    OK(lacuna_scene_builder_build(b, &scene));
    /* The file's render settings are the job's defaults. */
    lacuna_render_job *job = NULL;
    OK(lacuna_render_job_new(scene, NULL, &job));
    lacuna_film *film = NULL;
    OK(lacuna_render_job_run(job, &film));
    uint32_t w = 0, h = 0;
    OK(lacuna_film_get_size(film, &w, &h));
    CHECK(w == 6 && h == 5);
    lacuna_render_stats rs;
    OK(lacuna_film_get_stats(film, &rs));
    CHECK(rs.spp == 2 && !rs.cancelled);
    lacuna_film_release(film);
    lacuna_render_job_free(job);
    lacuna_scene_release(scene);
}

/* ---------------------------------------------------------------------------------------- */

static lacuna_ray make_ray(float ox, float oy, float oz, float dx, float dy, float dz) {
    lacuna_ray r;
    lacuna_ray_init(&r);
    r.origin[0] = ox;
    r.origin[1] = oy;
    r.origin[2] = oz;
    r.direction[0] = dx;
    r.direction[1] = dy;
    r.direction[2] = dz;
    return r;
}

typedef struct query_args {
    const lacuna_scene *scene;
    int mismatches;
} query_args;

static void *query_thread(void *p) {
    query_args *a = (query_args *)p;
    for (int i = 0; i < 2000; i++) {
        float x = -0.9f + 1.8f * (float)(i % 100) / 100.0f;
        lacuna_ray r = make_ray(x, 0, 0, 0, 0, -1);
        lacuna_hit h;
        if (lacuna_scene_intersect(a->scene, &r, &h) != LACUNA_STATUS_OK || fabsf(h.t - 1.0f) > 1e-5f)
            a->mismatches++;
    }
    return NULL;
}

/* A ray embedded in a bigger host struct: exercises strides. */
typedef struct host_ray {
    int id;
    lacuna_ray ray;
    double payload;
} host_ray;

typedef struct host_hit {
    lacuna_hit hit;
    char tag[12];
} host_hit;

static void test_queries(lacuna_context *ctx) {
    lacuna_scene *scene = build_box_scene(ctx);
    lacuna_ray r;
    lacuna_hit h;
    lacuna_ray_init(NULL);
    lacuna_hit_init(NULL);
    lacuna_hit_init(&h);
    CHECK(h.triangle == LACUNA_INVALID_INDEX && h.mesh == LACUNA_INVALID_INDEX && isinf(h.t));
    lacuna_ray_init(&r);
    CHECK(r.flags == 0 && isinf(r.tmax) && r.direction[2] == 1);
    /* Straight down the -z axis hits the back wall (triangles 0 or 1) at t = 1. */
    r = make_ray(0.1f, 0.2f, 0, 0, 0, -1);
    OK(lacuna_scene_intersect(scene, &r, &h));
    CHECK(fabsf(h.t - 1) < 1e-6f);
    CHECK(h.triangle <= 1 && h.mesh == 0 && h.mesh_triangle == h.triangle);
    CHECK(h.u >= 0 && h.v >= 0 && h.u + h.v <= 1);
    CHECK(fabsf(fabsf(h.geometric_normal[2]) - 1) < 1e-6f);
    /* Direction not unit: t in units of its length. */
    r = make_ray(0.1f, 0.2f, 0, 0, 0, -4);
    OK(lacuna_scene_intersect(scene, &r, &h));
    CHECK(fabsf(h.t - 0.25f) < 1e-6f);
    /* Up hits the light quad (mesh 1) at t = 0.99. */
    r = make_ray(0, 0, 0, 0, 1, 0);
    OK(lacuna_scene_intersect(scene, &r, &h));
    CHECK(h.mesh == 1 && h.triangle >= 12 && h.mesh_triangle == h.triangle - 12 && fabsf(h.t - 0.99f) < 1e-5f);
    /* Outside looking away: a miss. */
    r = make_ray(0, 0, 5, 0, 0, 1);
    OK(lacuna_scene_intersect(scene, &r, &h));
    CHECK(h.triangle == LACUNA_INVALID_INDEX && isinf(h.t));
    bool occ = false;
    r = make_ray(0, 0, 0, 1, 0, 0);
    OK(lacuna_scene_occluded(scene, &r, &occ));
    CHECK(occ);
    r.tmax = 0.5f;
    OK(lacuna_scene_occluded(scene, &r, &occ));
    CHECK(!occ);
    /* Invalid rays and arguments. */
    lacuna_hit_init(&h);
    r = make_ray(NAN, 0, 0, 1, 0, 0);
    EXPECT(lacuna_scene_intersect(scene, &r, &h), LACUNA_STATUS_INVALID_ARGUMENT, "origin");
    r = make_ray(0, 0, 0, 0, 0, 0);
    EXPECT(lacuna_scene_intersect(scene, &r, &h), LACUNA_STATUS_INVALID_ARGUMENT, "non-zero");
    r = make_ray(0, 0, 0, INFINITY, 0, 0);
    EXPECT(lacuna_scene_occluded(scene, &r, &occ), LACUNA_STATUS_INVALID_ARGUMENT, "direction");
    r = make_ray(0, 0, 0, 1, 0, 0);
    r.tmax = -1;
    EXPECT(lacuna_scene_intersect(scene, &r, &h), LACUNA_STATUS_INVALID_ARGUMENT, "tmax");
    r.tmax = NAN;
    EXPECT(lacuna_scene_occluded(scene, &r, &occ), LACUNA_STATUS_INVALID_ARGUMENT, "tmax");
    r.tmax = INFINITY;
    r.flags = 1;
    EXPECT(lacuna_scene_intersect(scene, &r, &h), LACUNA_STATUS_INVALID_ARGUMENT, "flags");
    r.flags = 0;
    CHECK(h.triangle == LACUNA_INVALID_INDEX); /* untouched by the failures */
    EXPECT(lacuna_scene_intersect(NULL, &r, &h), LACUNA_STATUS_NULL_POINTER, "scene");
    EXPECT(lacuna_scene_intersect(scene, NULL, &h), LACUNA_STATUS_NULL_POINTER, "ray");
    EXPECT(lacuna_scene_intersect(scene, &r, NULL), LACUNA_STATUS_NULL_POINTER, "out_hit");
    EXPECT(lacuna_scene_occluded(NULL, &r, &occ), LACUNA_STATUS_NULL_POINTER, "scene");
    EXPECT(lacuna_scene_occluded(scene, NULL, &occ), LACUNA_STATUS_NULL_POINTER, "ray");
    EXPECT(lacuna_scene_occluded(scene, &r, NULL), LACUNA_STATUS_NULL_POINTER, "out_occluded");
    /* Batches with strides. */
    enum { N = 1000 };
    host_ray *rays = (host_ray *)calloc(N, sizeof(host_ray));
    host_hit *hits = (host_hit *)calloc(N, sizeof(host_hit));
    bool *occluded = (bool *)calloc(N, sizeof(bool));
    for (int i = 0; i < N; i++) {
        float a = 6.2831853f * (float)i / N;
        rays[i].ray = make_ray(0, 0, 0, cosf(a), sinf(a) * 0.5f, sinf(a));
        memcpy(hits[i].tag, "untouched", 10);
    }
    OK(lacuna_scene_intersect_batch(scene, &rays[0].ray, sizeof(host_ray), N, &hits[0].hit, sizeof(host_hit)));
    int agree = 0;
    for (int i = 0; i < N; i++) {
        lacuna_hit single;
        OK(lacuna_scene_intersect(scene, &rays[i].ray, &single));
        agree += single.triangle == hits[i].hit.triangle && single.t == hits[i].hit.t;
        CHECK(strcmp(hits[i].tag, "untouched") == 0);
    }
    CHECK(agree == N);
    OK(lacuna_scene_occluded_batch(scene, &rays[0].ray, sizeof(host_ray), N, occluded));
    int all = 1;
    for (int i = 0; i < N; i++) all &= occluded[i];
    CHECK(all);
    OK(lacuna_scene_intersect_batch(scene, NULL, 0, 0, NULL, 0));
    OK(lacuna_scene_occluded_batch(scene, NULL, 0, 0, NULL));
    rays[3].ray.direction[0] = NAN;
    hits[0].hit.t = -7;
    EXPECT(lacuna_scene_intersect_batch(scene, &rays[0].ray, sizeof(host_ray), N, &hits[0].hit, sizeof(host_hit)),
           LACUNA_STATUS_INVALID_ARGUMENT, "rays[3]");
    CHECK(hits[0].hit.t == -7); /* nothing written on failure */
    EXPECT(lacuna_scene_occluded_batch(scene, &rays[0].ray, sizeof(host_ray), N, occluded),
           LACUNA_STATUS_INVALID_ARGUMENT, "rays[3]");
    rays[3].ray.direction[0] = 1;
    EXPECT(lacuna_scene_intersect_batch(scene, &rays[0].ray, 16, N, &hits[0].hit, 0),
           LACUNA_STATUS_INVALID_ARGUMENT, "stride 16");
    EXPECT(lacuna_scene_intersect_batch(scene, &rays[0].ray, 0, N, &hits[0].hit, 8),
           LACUNA_STATUS_INVALID_ARGUMENT, "hits");
    EXPECT(lacuna_scene_intersect_batch(scene, NULL, 0, N, &hits[0].hit, 0), LACUNA_STATUS_NULL_POINTER, "rays");
    EXPECT(lacuna_scene_intersect_batch(scene, &rays[0].ray, 0, N, NULL, 0), LACUNA_STATUS_NULL_POINTER, "hits");
    EXPECT(lacuna_scene_intersect_batch(NULL, &rays[0].ray, 0, N, &hits[0].hit, 0), LACUNA_STATUS_NULL_POINTER,
           "scene");
    EXPECT(lacuna_scene_occluded_batch(scene, &rays[0].ray, 0, N, NULL), LACUNA_STATUS_NULL_POINTER,
           "out_occluded");
    EXPECT(lacuna_scene_occluded_batch(NULL, &rays[0].ray, 0, N, occluded), LACUNA_STATUS_NULL_POINTER, "scene");
    EXPECT(lacuna_scene_intersect_batch(scene, &rays[0].ray, SIZE_MAX / 4, 8, &hits[0].hit, 0),
           LACUNA_STATUS_OUT_OF_RANGE, "rays");
    free(rays);
    free(hits);
    free(occluded);
    /* Concurrent queries from host threads. */
    pthread_t threads[4];
    query_args args[4];
    for (int i = 0; i < 4; i++) {
        args[i].scene = scene;
        args[i].mismatches = 0;
        pthread_create(&threads[i], NULL, query_thread, &args[i]);
    }
    for (int i = 0; i < 4; i++) {
        pthread_join(threads[i], NULL);
        CHECK(args[i].mismatches == 0);
    }
    /* Memory and stats. */
    lacuna_memory_report mem;
    OK(lacuna_scene_get_memory_report(scene, &mem));
    CHECK(mem.total == mem.meshes + mem.bvh + mem.textures + mem.lights);
    CHECK(mem.meshes > 0 && mem.bvh > 0 && mem.lights > 0);
    EXPECT(lacuna_scene_get_memory_report(scene, NULL), LACUNA_STATUS_NULL_POINTER, "out_report");
    EXPECT(lacuna_scene_get_memory_report(NULL, &mem), LACUNA_STATUS_NULL_POINTER, "scene");
    lacuna_scene_stats st;
    OK(lacuna_scene_get_stats(scene, &st));
    CHECK(st.triangles == 14 && st.meshes == 2 && st.lights == 2 && st.bvh_nodes > 0);
    CHECK(st.bounds_min.x == -1 && st.bounds_max.z == 1);
    EXPECT(lacuna_scene_get_stats(scene, NULL), LACUNA_STATUS_NULL_POINTER, "out_stats");
    EXPECT(lacuna_scene_get_stats(NULL, &st), LACUNA_STATUS_NULL_POINTER, "scene");
    lacuna_scene_retain(scene);
    lacuna_scene_release(scene);
    lacuna_scene_retain(NULL);
    lacuna_scene_release(NULL);
    lacuna_scene_release(scene);
}

/* ---------------------------------------------------------------------------------------- */

typedef struct progress_log {
    int calls;
    double last;
    int decreasing;
    double cancel_at; /* return false once the fraction reaches this */
} progress_log;

static bool on_progress(void *user, double fraction) {
    progress_log *log = (progress_log *)user;
    log->calls++;
    if (fraction < log->last) log->decreasing++;
    log->last = fraction;
    return fraction < log->cancel_at;
}

typedef struct cancel_args {
    lacuna_render_job *job;
    lacuna_status status;
} cancel_args;

static void *cancel_thread(void *p) {
    cancel_args *a = (cancel_args *)p;
    struct timespec ts = {0, 200 * 1000 * 1000};
    nanosleep(&ts, NULL);
    a->status = lacuna_render_job_cancel(a->job);
    return NULL;
}

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void test_render(lacuna_context *ctx) {
    lacuna_scene *scene = build_box_scene(ctx);
    lacuna_render_job *job = NULL;
    EXPECT(lacuna_render_job_new(NULL, "path", &job), LACUNA_STATUS_NULL_POINTER, "scene");
    EXPECT(lacuna_render_job_new(scene, "path", NULL), LACUNA_STATUS_NULL_POINTER, "out_job");
    EXPECT(lacuna_render_job_new(scene, "nonesuch", &job), LACUNA_STATUS_INVALID_ARGUMENT, "nonesuch");
    CHECK(job == NULL);
    OK(lacuna_render_job_new(scene, "path", &job));
    /* The job keeps the scene alive. */
    lacuna_scene_release(scene);
    /* Setters. */
    EXPECT(lacuna_render_job_set_samples_per_pixel(job, 0), LACUNA_STATUS_INVALID_ARGUMENT, "spp 0");
    EXPECT(lacuna_render_job_set_samples_per_pixel(NULL, 1), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_time_budget(job, NAN), LACUNA_STATUS_INVALID_ARGUMENT, "time budget");
    EXPECT(lacuna_render_job_set_time_budget(job, -1), LACUNA_STATUS_INVALID_ARGUMENT, "time budget");
    EXPECT(lacuna_render_job_set_max_depth(job, LACUNA_MAX_DEPTH_LIMIT + 1), LACUNA_STATUS_OUT_OF_RANGE,
           "max_depth");
    EXPECT(lacuna_render_job_set_resolution(job, 0, 8), LACUNA_STATUS_OUT_OF_RANGE, "resolution 0x8");
    EXPECT(lacuna_render_job_set_resolution(job, 8, 70000), LACUNA_STATUS_OUT_OF_RANGE, "70000");
    EXPECT(lacuna_render_job_set_thread_count(job, LACUNA_MAX_THREADS + 1), LACUNA_STATUS_OUT_OF_RANGE,
           "thread_count");
    EXPECT(lacuna_render_job_set_mis_heuristic(job, 4), LACUNA_STATUS_INVALID_ARGUMENT, "heuristic");
    {
        uint32_t heuristic = 99;
        EXPECT(lacuna_render_job_get_mis_heuristic(job, NULL), LACUNA_STATUS_NULL_POINTER, "out_heuristic");
        EXPECT(lacuna_render_job_get_mis_heuristic(NULL, &heuristic), LACUNA_STATUS_NULL_POINTER, "job");
        OK(lacuna_render_job_get_mis_heuristic(job, &heuristic)); /* path's default */
        CHECK(heuristic == LACUNA_MIS_HEURISTIC_POWER);
        OK(lacuna_render_job_set_mis_heuristic(job, LACUNA_MIS_HEURISTIC_AUTO));
        OK(lacuna_render_job_get_mis_heuristic(job, &heuristic));
        CHECK(heuristic == LACUNA_MIS_HEURISTIC_AUTO);
    }
    OK(lacuna_render_job_set_mis_heuristic(job, LACUNA_MIS_HEURISTIC_OPTIMAL));
    {
        /* path takes balance, power and auto: optimal is refused and writes no film. */
        lacuna_film *refused = NULL;
        EXPECT(lacuna_render_job_run(job, &refused), LACUNA_STATUS_INVALID_ARGUMENT, "env_direct");
        CHECK(refused == NULL);
    }
    EXPECT(lacuna_render_job_set_sampler(job, 2), LACUNA_STATUS_INVALID_ARGUMENT, "sampler");
    EXPECT(lacuna_render_job_set_sampler(NULL, LACUNA_SAMPLER_SOBOL), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_camera(job, v3(0, 0, 0), v3(0, 0, -1), v3(0, NAN, 0), 40),
           LACUNA_STATUS_INVALID_ARGUMENT, "up");
    EXPECT(lacuna_render_job_set_seed(NULL, 1), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_progress_callback(NULL, on_progress, NULL), LACUNA_STATUS_NULL_POINTER, "job");
    OK(lacuna_render_job_set_samples_per_pixel(job, 2));
    OK(lacuna_render_job_set_time_budget(job, 0));
    OK(lacuna_render_job_set_seed(job, 7));
    OK(lacuna_render_job_set_max_depth(job, 3));
    OK(lacuna_render_job_set_resolution(job, 10, 7));
    OK(lacuna_render_job_set_thread_count(job, 2));
    OK(lacuna_render_job_set_mis_heuristic(job, LACUNA_MIS_HEURISTIC_BALANCE));
    OK(lacuna_render_job_set_sampler(job, LACUNA_SAMPLER_INDEPENDENT));
    OK(lacuna_render_job_set_sampler(job, LACUNA_SAMPLER_SOBOL));
    OK(lacuna_render_job_set_camera(job, v3(0, 0, 0.9f), v3(0, 0, -1), v3(0, 1, 0), 70));
    progress_log log = {0, 0.0, 0, 2.0};
    OK(lacuna_render_job_set_progress_callback(job, on_progress, &log));
    lacuna_render_stats rs;
    EXPECT(lacuna_render_job_get_stats(job, &rs), LACUNA_STATUS_INVALID_OPERATION, "not run");
    /* Run. */
    lacuna_film *film = NULL;
    EXPECT(lacuna_render_job_run(NULL, &film), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_run(job, NULL), LACUNA_STATUS_NULL_POINTER, "out_film");
    OK(lacuna_render_job_run(job, &film));
    CHECK(log.calls > 0 && log.decreasing == 0 && log.last == 1.0);
    OK(lacuna_render_job_get_stats(job, &rs));
    CHECK(rs.spp == 2 && rs.samples == 140 && rs.rays > 0 && !rs.cancelled);
    EXPECT(lacuna_render_job_get_stats(job, NULL), LACUNA_STATUS_NULL_POINTER, "out_stats");
    EXPECT(lacuna_render_job_get_stats(NULL, &rs), LACUNA_STATUS_NULL_POINTER, "job");
    /* Film readback: packed, then strided into a padded buffer. */
    uint32_t w = 0, h = 0;
    OK(lacuna_film_get_size(film, &w, &h));
    CHECK(w == 10 && h == 7);
    EXPECT(lacuna_film_get_size(film, NULL, &h), LACUNA_STATUS_NULL_POINTER, "out_width");
    EXPECT(lacuna_film_get_size(NULL, &w, &h), LACUNA_STATUS_NULL_POINTER, "film");
    float packed[10 * 7 * 3];
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, packed, 10, 7, 0, 0));
    double sum = 0;
    for (int i = 0; i < 10 * 7 * 3; i++) sum += packed[i];
    CHECK(sum > 0 && isfinite(sum));
    enum { PS = 20, RS = 10 * PS + 12 };
    unsigned char padded[7 * RS];
    memset(padded, 0xAB, sizeof padded);
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, (float *)(void *)padded, 10, 7, PS, RS));
    int same = 1, pad_ok = 1;
    for (int y = 0; y < 7; y++)
        for (int x = 0; x < 10; x++) {
            float px[3];
            memcpy(px, padded + y * RS + x * PS, 12);
            same &= memcmp(px, &packed[(y * 10 + x) * 3], 12) == 0;
            for (int k = 12; k < PS; k++) pad_ok &= padded[y * RS + x * PS + k] == 0xAB;
        }
    CHECK(same && pad_ok);
    float depth[70], spp_img[70], albedo[210], normal[210];
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_DEPTH, depth, 10, 7, 0, 0));
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_SAMPLE_COUNT, spp_img, 10, 7, 0, 0));
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_ALBEDO, albedo, 10, 7, 0, 0));
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_NORMAL, normal, 10, 7, 0, 0));
    CHECK(depth[35] > 1.5f && depth[35] < 2.5f); /* centre pixel: the back wall ~1.9 away */
    CHECK(spp_img[0] == 2 && spp_img[69] == 2);
    CHECK(albedo[105] > 0.4f && albedo[105] < 0.6f);
    EXPECT(lacuna_film_read(film, 5, packed, 10, 7, 0, 0), LACUNA_STATUS_INVALID_ARGUMENT, "channel");
    EXPECT(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, packed, 9, 7, 0, 0),
           LACUNA_STATUS_INVALID_ARGUMENT, "9x7");
    EXPECT(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, packed, 10, 7, 8, 0),
           LACUNA_STATUS_INVALID_ARGUMENT, "pixel_stride");
    EXPECT(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, packed, 10, 7, 0, 100),
           LACUNA_STATUS_INVALID_ARGUMENT, "row_stride");
    EXPECT(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, NULL, 10, 7, 0, 0), LACUNA_STATUS_NULL_POINTER,
           "dst");
    EXPECT(lacuna_film_read(NULL, LACUNA_FILM_CHANNEL_RADIANCE, packed, 10, 7, 0, 0), LACUNA_STATUS_NULL_POINTER,
           "film");
    EXPECT(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, packed, 10, 7, SIZE_MAX / 2, 0),
           LACUNA_STATUS_OUT_OF_RANGE, "overflows");
    /* Film figures and files. */
    size_t bytes = 0;
    OK(lacuna_film_get_memory_bytes(film, &bytes));
    CHECK(bytes >= 70 * 12);
    EXPECT(lacuna_film_get_memory_bytes(film, NULL), LACUNA_STATUS_NULL_POINTER, "out_bytes");
    EXPECT(lacuna_film_get_memory_bytes(NULL, &bytes), LACUNA_STATUS_NULL_POINTER, "film");
    OK(lacuna_film_get_stats(film, &rs));
    CHECK(rs.spp == 2);
    EXPECT(lacuna_film_get_stats(film, NULL), LACUNA_STATUS_NULL_POINTER, "out_stats");
    EXPECT(lacuna_film_get_stats(NULL, &rs), LACUNA_STATUS_NULL_POINTER, "film");
    OK(lacuna_film_write_exr(film, path_in_dir("box.exr")));
    OK(lacuna_film_write_png(film, path_in_dir("box.png"), 0.5f));
    CHECK(file_exists(path_in_dir("box.exr")) && file_exists(path_in_dir("box.png")));
    EXPECT(lacuna_film_write_exr(film, path_in_dir("no/such/dir/box.exr")), LACUNA_STATUS_IO, "box.exr");
    EXPECT(lacuna_film_write_exr(film, NULL), LACUNA_STATUS_NULL_POINTER, "path");
    EXPECT(lacuna_film_write_exr(NULL, "x.exr"), LACUNA_STATUS_NULL_POINTER, "film");
    EXPECT(lacuna_film_write_png(film, path_in_dir("box.png"), NAN), LACUNA_STATUS_INVALID_ARGUMENT, "exposure");
    EXPECT(lacuna_film_write_png(film, NULL, 0), LACUNA_STATUS_NULL_POINTER, "path");
    EXPECT(lacuna_film_write_png(NULL, "x.png", 0), LACUNA_STATUS_NULL_POINTER, "film");
    /* Reading an EXR back. */
    lacuna_film *loaded = NULL;
    OK(lacuna_film_load_exr(ctx, path_in_dir("box.exr"), &loaded));
    float back[10 * 7 * 3];
    OK(lacuna_film_read(loaded, LACUNA_FILM_CHANNEL_RADIANCE, back, 10, 7, 0, 0));
    CHECK(memcmp(back, packed, sizeof back) == 0);
    EXPECT(lacuna_film_load_exr(ctx, path_in_dir("missing.exr"), &loaded), LACUNA_STATUS_IO, "missing.exr");
    EXPECT(lacuna_film_load_exr(NULL, path_in_dir("box.exr"), &loaded), LACUNA_STATUS_NULL_POINTER, "context");
    EXPECT(lacuna_film_load_exr(ctx, path_in_dir("box.exr"), NULL), LACUNA_STATUS_NULL_POINTER, "out_film");
    lacuna_film_release(loaded);
    lacuna_film_retain(film);
    lacuna_film_release(film);
    lacuna_film_retain(NULL);
    lacuna_film_release(NULL);
    lacuna_film_release(film);

    /* Cancelling from the progress callback: CANCELLED, and the partial film can be taken. */
    progress_log cancel_log = {0, 0.0, 0, 0.5};
    OK(lacuna_render_job_set_samples_per_pixel(job, 8));
    OK(lacuna_render_job_set_progress_callback(job, on_progress, &cancel_log));
    film = NULL;
    EXPECT(lacuna_render_job_run(job, &film), LACUNA_STATUS_CANCELLED, "cancelled");
    CHECK(film == NULL);
    OK(lacuna_render_job_get_stats(job, &rs));
    CHECK(rs.cancelled && rs.spp < 8);
    OK(lacuna_render_job_take_partial_film(job, &film));
    OK(lacuna_film_get_stats(film, &rs));
    CHECK(rs.cancelled);
    lacuna_film_release(film);
    EXPECT(lacuna_render_job_take_partial_film(job, &film), LACUNA_STATUS_INVALID_OPERATION, "partial");
    EXPECT(lacuna_render_job_take_partial_film(job, NULL), LACUNA_STATUS_NULL_POINTER, "out_film");
    EXPECT(lacuna_render_job_take_partial_film(NULL, &film), LACUNA_STATUS_NULL_POINTER, "job");
    OK(lacuna_render_job_set_progress_callback(job, NULL, NULL));

    /* A cancel request before a run cancels that run, and is consumed by it. */
    OK(lacuna_render_job_cancel(job));
    EXPECT(lacuna_render_job_run(job, &film), LACUNA_STATUS_CANCELLED, NULL);
    OK(lacuna_render_job_set_samples_per_pixel(job, 1));
    OK(lacuna_render_job_run(job, &film));
    lacuna_film_release(film);
    EXPECT(lacuna_render_job_cancel(NULL), LACUNA_STATUS_NULL_POINTER, "job");

    /* Cancelling from another thread stops a long time-budget render quickly. */
    lacuna_render_job *slow = NULL;
    lacuna_scene *s2 = build_box_scene(ctx);
    OK(lacuna_render_job_new(s2, "path", &slow));
    lacuna_scene_release(s2);
    OK(lacuna_render_job_set_resolution(slow, 16, 16));
    OK(lacuna_render_job_set_time_budget(slow, 60));
    cancel_args ca = {slow, LACUNA_STATUS_PANIC};
    pthread_t t;
    double t0 = now();
    pthread_create(&t, NULL, cancel_thread, &ca);
    film = NULL;
    EXPECT(lacuna_render_job_run(slow, &film), LACUNA_STATUS_CANCELLED, "cancelled");
    double elapsed = now() - t0;
    pthread_join(t, NULL);
    CHECK(ca.status == LACUNA_STATUS_OK);
    CHECK(film == NULL);
    CHECK(elapsed < 30);
    lacuna_render_job_free(slow);

    /* The memory budget. */
    lacuna_context *tight = NULL;
    OK(lacuna_context_new(&tight));
    OK(lacuna_context_set_memory_budget(tight, 1000));
    lacuna_scene *s3 = build_box_scene(tight);
    lacuna_context_release(tight); /* the scene keeps it alive */
    lacuna_render_job *big = NULL;
    OK(lacuna_render_job_new(s3, NULL, &big));
    lacuna_scene_release(s3);
    OK(lacuna_render_job_set_resolution(big, 100, 100));
    EXPECT(lacuna_render_job_run(big, &film), LACUNA_STATUS_OVER_BUDGET, "memory budget");
    lacuna_render_job_free(big);

    /* Reference and comparison. */
    lacuna_film *ref = NULL;
    lacuna_image_errors noise;
    OK(lacuna_render_job_set_samples_per_pixel(job, 1));
    EXPECT(lacuna_render_job_run_reference(job, &ref, &noise), LACUNA_STATUS_INVALID_ARGUMENT, "2 samples");
    OK(lacuna_render_job_set_samples_per_pixel(job, 4));
    EXPECT(lacuna_render_job_run_reference(job, NULL, &noise), LACUNA_STATUS_NULL_POINTER, "out_film");
    EXPECT(lacuna_render_job_run_reference(NULL, &ref, &noise), LACUNA_STATUS_NULL_POINTER, "job");
    OK(lacuna_render_job_run_reference(job, &ref, &noise));
    CHECK(noise.mae > 0 && noise.rmse >= noise.mae);
    OK(lacuna_film_write_exr(ref, path_in_dir("ref.exr")));
    lacuna_film_release(ref);
    OK(lacuna_film_load_exr(ctx, path_in_dir("ref.exr"), &ref));
    const char *names[2] = {"path", "path"};
    /* 1 s per contender: compare refuses a contender whose precomputation takes its whole budget,
       and under valgrind on a loaded machine 0.1 s was sometimes not enough. */
    OK(lacuna_render_job_compare(job, names, 2, ref, 1.0, 1, path_in_dir("cmp")));
    CHECK(file_exists(path_in_dir("cmp/summary.md")) && file_exists(path_in_dir("cmp/curves.csv")) &&
          file_exists(path_in_dir("cmp/convergence.svg")));
    {
        uint32_t schedule = 99;
        OK(lacuna_render_job_get_compare_schedule(job, &schedule));
        CHECK(schedule == LACUNA_COMPARE_SCHEDULE_SEQUENTIAL);
        EXPECT(lacuna_render_job_set_compare_schedule(job, 2), LACUNA_STATUS_INVALID_ARGUMENT, "schedule");
        EXPECT(lacuna_render_job_set_compare_schedule(NULL, 0), LACUNA_STATUS_NULL_POINTER, "job");
        EXPECT(lacuna_render_job_get_compare_schedule(job, NULL), LACUNA_STATUS_NULL_POINTER, "out_schedule");
        OK(lacuna_render_job_set_compare_schedule(job, LACUNA_COMPARE_SCHEDULE_CONCURRENT));
        OK(lacuna_render_job_get_compare_schedule(job, &schedule));
        CHECK(schedule == LACUNA_COMPARE_SCHEDULE_CONCURRENT);
        OK(lacuna_render_job_compare(job, names, 2, ref, 1.0, 1, path_in_dir("cmp_concurrent")));
        CHECK(file_contains(path_in_dir("cmp_concurrent/summary.md"), "at the same time"));
        OK(lacuna_render_job_set_compare_schedule(job, LACUNA_COMPARE_SCHEDULE_SEQUENTIAL));
    }
    const char *bad_names[2] = {"path", "nonesuch"};
    EXPECT(lacuna_render_job_compare(job, bad_names, 2, ref, 0.1, 1, path_in_dir("cmp2")),
           LACUNA_STATUS_INVALID_ARGUMENT, "nonesuch");
    const char *null_names[1] = {NULL};
    EXPECT(lacuna_render_job_compare(job, null_names, 1, ref, 0.1, 1, path_in_dir("cmp2")),
           LACUNA_STATUS_NULL_POINTER, "integrators[0]");
    EXPECT(lacuna_render_job_compare(job, names, 0, ref, 0.1, 1, path_in_dir("cmp2")),
           LACUNA_STATUS_INVALID_ARGUMENT, "integrator_count");
    EXPECT(lacuna_render_job_compare(job, NULL, 2, ref, 0.1, 1, path_in_dir("cmp2")), LACUNA_STATUS_NULL_POINTER,
           "integrators");
    EXPECT(lacuna_render_job_compare(job, names, 1, ref, NAN, 1, path_in_dir("cmp2")),
           LACUNA_STATUS_INVALID_ARGUMENT, "seconds_per_run");
    EXPECT(lacuna_render_job_compare(job, names, 1, ref, 0.1, 0, path_in_dir("cmp2")),
           LACUNA_STATUS_INVALID_ARGUMENT, "runs");
    EXPECT(lacuna_render_job_compare(job, names, 1, NULL, 0.1, 1, path_in_dir("cmp2")),
           LACUNA_STATUS_NULL_POINTER, "reference");
    EXPECT(lacuna_render_job_compare(job, names, 1, ref, 0.1, 1, NULL), LACUNA_STATUS_NULL_POINTER, "out_dir");
    OK(lacuna_render_job_set_resolution(job, 4, 4));
    EXPECT(lacuna_render_job_compare(job, names, 1, ref, 0.1, 1, path_in_dir("cmp2")),
           LACUNA_STATUS_INVALID_ARGUMENT, "reference is 10x7");
    lacuna_film_release(ref);
    lacuna_render_job_free(job);
    lacuna_render_job_free(NULL);
}

/* ---------------------------------------------------------------------------------------- */
/* Bidirectional path tracing: light subpaths, strategy filter, strategy images, thin lens. */

static void test_bdpt(lacuna_context *ctx) {
    lacuna_scene *scene = build_box_scene(ctx);
    lacuna_render_job *pt = NULL, *job = NULL;
    OK(lacuna_render_job_new(scene, "path", &pt));
    EXPECT(lacuna_render_job_set_light_paths(pt, 10), LACUNA_STATUS_INVALID_OPERATION, "bdpt_skeleton");
    EXPECT(lacuna_render_job_set_strategy_filter(pt, 1, 2, false), LACUNA_STATUS_INVALID_OPERATION, "bdpt");
    EXPECT(lacuna_render_job_set_strategy_images(pt, 3), LACUNA_STATUS_INVALID_OPERATION, "'path'");
    OK(lacuna_render_job_clear_strategy_filter(pt));
    OK(lacuna_render_job_new(scene, "bdpt", &job));
    lacuna_scene_release(scene);
    /* Error paths. */
    EXPECT(lacuna_render_job_set_light_paths(NULL, 10), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_light_paths(job, LACUNA_MAX_LIGHT_PATHS + 1), LACUNA_STATUS_OUT_OF_RANGE,
           "count");
    EXPECT(lacuna_render_job_set_strategy_filter(NULL, 1, 2, false), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_strategy_filter(job, 1, 1, false), LACUNA_STATUS_INVALID_ARGUMENT, "(1, 1)");
    EXPECT(lacuna_render_job_set_strategy_filter(job, 2, 0, true), LACUNA_STATUS_INVALID_ARGUMENT, "(2, 0)");
    EXPECT(lacuna_render_job_set_strategy_filter(job, 0, 1, true), LACUNA_STATUS_INVALID_ARGUMENT, "(0, 1)");
    EXPECT(lacuna_render_job_clear_strategy_filter(NULL), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_strategy_images(NULL, 3), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_thin_lens(NULL, 0.1f, 1), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_thin_lens(job, -0.1f, 1), LACUNA_STATUS_INVALID_ARGUMENT, "lens_radius");
    EXPECT(lacuna_render_job_set_thin_lens(job, NAN, 1), LACUNA_STATUS_INVALID_ARGUMENT, "lens_radius");
    EXPECT(lacuna_render_job_set_thin_lens(job, 0.1f, 0), LACUNA_STATUS_INVALID_ARGUMENT, "focus_distance");
    EXPECT(lacuna_render_job_set_thin_lens(job, 0.1f, INFINITY), LACUNA_STATUS_INVALID_ARGUMENT,
           "focus_distance");
    /* A render with every strategy image of paths up to 4 segments (max depth 3). */
    enum { W = 12, H = 10, N = W * H * 3 };
    OK(lacuna_render_job_set_resolution(job, W, H));
    OK(lacuna_render_job_set_samples_per_pixel(job, 4));
    OK(lacuna_render_job_set_max_depth(job, 3));
    OK(lacuna_render_job_set_seed(job, 3));
    OK(lacuna_render_job_set_light_paths(job, 50));
    OK(lacuna_render_job_set_strategy_images(job, 9)); /* clamped to 4 */
    lacuna_film *film = NULL;
    OK(lacuna_render_job_run(job, &film));
    static float radiance[N], sum[N], img[N], unweighted_1_2[N];
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, radiance, W, H, 0, 0));
    memset(sum, 0, sizeof sum);
    int strategies = 0;
    for (uint32_t k = 1; k <= 4; k++)
        for (uint32_t s = 0; s <= k + 1; s++) {
            uint32_t t = k + 1 - s;
            if (t == 0 || (s == 1 && t == 1) || (k == 1 && s != 0)) continue;
            OK(lacuna_film_read_strategy_image(film, s, t, true, img, W, H, 0, 0));
            for (int i = 0; i < N; i++) sum[i] += img[i];
            OK(lacuna_film_read_strategy_image(film, s, t, false, img, W, H, 0, 0));
            strategies++;
        }
    CHECK(strategies == 1 + 3 + 4 + 5);
    int close = 1;
    double total = 0;
    for (int i = 0; i < N; i++) {
        close &= fabsf(sum[i] - radiance[i]) <= 1e-4f * fmaxf(radiance[i], 1e-3f);
        total += radiance[i];
    }
    CHECK(close && total > 0 && isfinite(total));
    OK(lacuna_film_read_strategy_image(film, 1, 2, false, unweighted_1_2, W, H, 0, 0));
    /* Strided readback agrees with packed. */
    enum { PS = 16, RS = W * PS + 4 };
    static unsigned char padded[H * RS];
    OK(lacuna_film_read_strategy_image(film, 1, 2, false, (float *)(void *)padded, W, H, PS, RS));
    int same = 1;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) same &= memcmp(padded + y * RS + x * PS, &unweighted_1_2[(y * W + x) * 3], 12) == 0;
    CHECK(same);
    EXPECT(lacuna_film_read_strategy_image(film, 1, 1, true, img, W, H, 0, 0), LACUNA_STATUS_OUT_OF_RANGE,
           "(1, 1)");
    EXPECT(lacuna_film_read_strategy_image(film, 0, 6, true, img, W, H, 0, 0), LACUNA_STATUS_OUT_OF_RANGE,
           "(0, 6)");
    EXPECT(lacuna_film_read_strategy_image(film, 1, 2, true, img, W + 1, H, 0, 0), LACUNA_STATUS_INVALID_ARGUMENT,
           "13x10");
    EXPECT(lacuna_film_read_strategy_image(film, 1, 2, true, img, W, H, 4, 0), LACUNA_STATUS_INVALID_ARGUMENT,
           "pixel_stride");
    EXPECT(lacuna_film_read_strategy_image(film, 1, 2, true, NULL, W, H, 0, 0), LACUNA_STATUS_NULL_POINTER, "dst");
    EXPECT(lacuna_film_read_strategy_image(NULL, 1, 2, true, img, W, H, 0, 0), LACUNA_STATUS_NULL_POINTER, "film");
    OK(lacuna_film_write_exr(film, path_in_dir("strategies.exr")));
    CHECK(file_exists(path_in_dir("strategies.exr")));
    lacuna_film_release(film);

    /* A film without strategy images. */
    OK(lacuna_render_job_set_resolution(pt, W, H));
    OK(lacuna_render_job_set_samples_per_pixel(pt, 1));
    OK(lacuna_render_job_run(pt, &film));
    EXPECT(lacuna_film_read_strategy_image(film, 1, 2, true, img, W, H, 0, 0), LACUNA_STATUS_INVALID_OPERATION,
           "no strategy images");
    lacuna_film_release(film);
    lacuna_render_job_free(pt);

    /* The strategy filter renders exactly that strategy's image of the same samples. */
    OK(lacuna_render_job_set_strategy_images(job, 0));
    OK(lacuna_render_job_set_strategy_filter(job, 1, 2, true));
    OK(lacuna_render_job_run(job, &film));
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, img, W, H, 0, 0));
    CHECK(memcmp(img, unweighted_1_2, sizeof img) == 0);
    EXPECT(lacuna_film_read_strategy_image(film, 1, 2, true, img, W, H, 0, 0), LACUNA_STATUS_INVALID_OPERATION,
           "no strategy images");
    lacuna_film_release(film);
    OK(lacuna_render_job_clear_strategy_filter(job));

    /* Light tracing through a thin lens; radius 0 makes the camera a pinhole again. */
    OK(lacuna_render_job_set_thin_lens(job, 0.05f, 0.9f));
    OK(lacuna_render_job_run(job, &film));
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, img, W, H, 0, 0));
    total = 0;
    for (int i = 0; i < N; i++) total += img[i];
    CHECK(total > 0 && isfinite(total));
    lacuna_film_release(film);
    OK(lacuna_render_job_set_thin_lens(job, 0, 0));
    OK(lacuna_render_job_set_light_paths(job, 0)); /* back to one per pixel */
    OK(lacuna_render_job_run(job, &film));
    lacuna_film_release(film);
    lacuna_render_job_free(job);

    /* Strategy images count against the memory budget. */
    lacuna_context *tight = NULL;
    OK(lacuna_context_new(&tight));
    OK(lacuna_context_set_memory_budget(tight, 20000));
    lacuna_scene *s2 = build_box_scene(tight);
    lacuna_context_release(tight);
    lacuna_render_job *big = NULL;
    OK(lacuna_render_job_new(s2, "bdpt", &big));
    lacuna_scene_release(s2);
    OK(lacuna_render_job_set_resolution(big, W, H));
    OK(lacuna_render_job_set_samples_per_pixel(big, 1));
    OK(lacuna_render_job_run(big, &film));
    lacuna_film_release(film);
    OK(lacuna_render_job_set_strategy_images(big, 3));
    EXPECT(lacuna_render_job_run(big, &film), LACUNA_STATUS_OVER_BUDGET, "strategy images");
    lacuna_render_job_free(big);
}

/* ---------------------------------------------------------------------------------------- */
/* Empty-space analysis. */

static int progress_calls;
static bool count_progress(void *user_data, double fraction) {
    (void)user_data;
    CHECK(fraction >= 0 && fraction <= 1);
    progress_calls++;
    return true;
}
static bool stop_at_once(void *user_data, double fraction) {
    (void)user_data;
    (void)fraction;
    return false;
}

static void test_analysis(lacuna_context *ctx) {
    lacuna_scene *scene = build_box_scene(ctx);
    lacuna_analysis *a = NULL;
    /* Error paths first: nothing is written on failure. */
    EXPECT(lacuna_analysis_build(NULL, 32, 0, 0, 0, NULL, NULL, &a), LACUNA_STATUS_NULL_POINTER, "scene");
    EXPECT(lacuna_analysis_build(scene, 32, 0, 0, 0, NULL, NULL, NULL), LACUNA_STATUS_NULL_POINTER, "out_analysis");
    EXPECT(lacuna_analysis_build(scene, 32, 0, 0, 64, NULL, NULL, &a), LACUNA_STATUS_INVALID_ARGUMENT, "flags");
    EXPECT(lacuna_analysis_build(scene, 0, 0, 0, 0, NULL, NULL, &a), LACUNA_STATUS_INVALID_ARGUMENT, "voxel_size");
    EXPECT(lacuna_analysis_build(scene, 0, NAN, 0, 0, NULL, NULL, &a), LACUNA_STATUS_INVALID_ARGUMENT, "voxel_size");
    EXPECT(lacuna_analysis_build(scene, 0, -1, 0, 0, NULL, NULL, &a), LACUNA_STATUS_INVALID_ARGUMENT, "voxel_size");
    EXPECT(lacuna_analysis_build(scene, 512, 0, 1024, 0, NULL, NULL, &a), LACUNA_STATUS_OVER_BUDGET, "budget");
    EXPECT(lacuna_analysis_build(scene, 32, 0, 0, 0, stop_at_once, NULL, &a), LACUNA_STATUS_CANCELLED, NULL);
    CHECK(a == NULL);

    progress_calls = 0;
    /* Filling interiors turns the inside of the closed box into solid. */
    OK(lacuna_analysis_build(scene, 16, 0, 0, LACUNA_ANALYSIS_FILL_INTERIORS | LACUNA_ANALYSIS_OUTSIDE_EMPTY, NULL,
                             NULL, &a));
    {
        lacuna_vec3 middle = v3(0, 0, 0);
        uint32_t o = 9, l = 9;
        OK(lacuna_analysis_query(a, &middle, &o, &l));
        CHECK(o == 0 && l == LACUNA_INVALID_INDEX);
        lacuna_analysis_release(a);
        a = NULL;
    }
    OK(lacuna_analysis_build(scene, 32, 0, 0, LACUNA_ANALYSIS_ALL_MAPS, count_progress, NULL, &a));
    CHECK(a != NULL && progress_calls >= 5);
    uint32_t dims[3] = {0, 0, 0};
    float size = 0;
    lacuna_vec3 origin;
    OK(lacuna_analysis_grid(a, dims, &size, &origin));
    OK(lacuna_analysis_grid(a, NULL, NULL, NULL));
    CHECK(dims[0] >= 32 && dims[1] >= 32 && dims[2] >= 32 && size > 0);
    EXPECT(lacuna_analysis_grid(NULL, dims, NULL, NULL), LACUNA_STATUS_NULL_POINTER, "analysis");

    /* The middle of the box is wide open; far outside is out of range. */
    lacuna_vec3 centre = v3(0, 0, 0), far_away = v3(100, 0, 0), bad = v3(NAN, 0, 0);
    uint32_t opening = 0, label = 12345;
    OK(lacuna_analysis_query(a, &centre, &opening, &label));
    CHECK(opening >= 5 && label != LACUNA_INVALID_INDEX);
    OK(lacuna_analysis_query(a, &centre, NULL, NULL));
    opening = 77;
    EXPECT(lacuna_analysis_query(a, &far_away, &opening, &label), LACUNA_STATUS_OUT_OF_RANGE, "outside");
    CHECK(opening == 77);
    EXPECT(lacuna_analysis_query(a, &bad, &opening, &label), LACUNA_STATUS_INVALID_ARGUMENT, "finite");
    EXPECT(lacuna_analysis_query(a, NULL, &opening, &label), LACUNA_STATUS_NULL_POINTER, "point");

    size_t regions = 0, portals = 0;
    OK(lacuna_analysis_counts(a, &regions, &portals));
    CHECK(regions >= 1 && label < regions);
    lacuna_region r;
    OK(lacuna_analysis_query(a, &centre, &opening, &label));
    OK(lacuna_analysis_region(a, label, &r));
    CHECK(r.opening >= opening && r.voxels >= r.root_voxels && r.root_voxels >= 1);
    EXPECT(lacuna_analysis_region(a, regions, &r), LACUNA_STATUS_OUT_OF_RANGE, "region index");
    EXPECT(lacuna_analysis_region(a, 0, NULL), LACUNA_STATUS_NULL_POINTER, "out_region");
    lacuna_portal p;
    EXPECT(lacuna_analysis_portal(a, portals, &p), LACUNA_STATUS_OUT_OF_RANGE, "portal index");
    lacuna_vec3 point, normal;
    float pdf = -1;
    EXPECT(lacuna_analysis_sample_portal(a, portals, 0.5f, 0.5f, 0.5f, &point, &normal, &pdf),
           LACUNA_STATUS_OUT_OF_RANGE, "portal index");
    EXPECT(lacuna_analysis_sample_portal(a, 0, 1.0f, 0.5f, 0.5f, &point, &normal, &pdf), LACUNA_STATUS_INVALID_ARGUMENT,
           "[0, 1)");
    EXPECT(lacuna_analysis_sample_portal(a, 0, 0.5f, NAN, 0.5f, &point, &normal, &pdf), LACUNA_STATUS_INVALID_ARGUMENT,
           "u1");
    CHECK(pdf == -1);
    for (size_t i = 0; i < portals; i++) {
        OK(lacuna_analysis_portal(a, i, &p));
        CHECK(p.region_a < p.region_b && p.region_b < regions && p.faces > 0 && p.area > 0);
        OK(lacuna_analysis_sample_portal(a, i, 0.25f, 0.5f, 0.75f, &point, &normal, &pdf));
        CHECK(fabsf(pdf * p.area - 1) < 1e-4f);
        CHECK(fabsf(normal.x) + fabsf(normal.y) + fabsf(normal.z) == 1.0f);
    }
    lacuna_analysis_memory mem;
    double seconds = -1;
    OK(lacuna_analysis_stats(a, &mem, &seconds));
    CHECK(mem.total == mem.occupancy + mem.distance + mem.opening + mem.labels + mem.portals + mem.extra_maps);
    CHECK(mem.extra_maps > 0 && seconds >= 0);

    /* The analysis keeps its scene alive. */
    lacuna_analysis_retain(a);
    lacuna_scene_release(scene);
    OK(lacuna_analysis_query(a, &centre, &opening, NULL));
    lacuna_analysis_release(a);
    lacuna_analysis_release(a);
    lacuna_analysis_release(NULL);
    lacuna_analysis_retain(NULL);
}

/* Skeleton-guided path tracing: the job's skeleton settings, and the guide and query API. */
/* Samples a guided query at its point on a fixed 4x4x4 grid of random numbers: each direction
   must be unit and carry the density `lacuna_guide_query_pdf` gives it. Returns how many of
   the 64 point up (y > 0). */
static int sample_upward(const lacuna_guide_query *q) {
    int upward = 0;
    for (int i = 0; i < 64; i++) {
        float u0 = (i % 4) / 4.0f + 0.1f, u1 = (i / 4 % 4) / 4.0f + 0.05f, u2 = (i / 16) / 4.0f + 0.12f;
        lacuna_vec3 d;
        float pdf = -1, pdf2 = -1;
        OK(lacuna_guide_query_sample(q, u0, u1, u2, &d, &pdf));
        CHECK(fabsf(d.x * d.x + d.y * d.y + d.z * d.z - 1) < 1e-4f && pdf > 0 && isfinite(pdf));
        OK(lacuna_guide_query_pdf(q, d, &pdf2));
        CHECK(fabsf(pdf - pdf2) <= 1e-4f * pdf);
        upward += d.y > 0;
    }
    return upward;
}

static void test_skeleton_guide(lacuna_context *ctx) {
    lacuna_scene *scene = build_box_scene(ctx);
    lacuna_render_job *job = NULL;
    OK(lacuna_render_job_new(scene, "path_skeleton", &job));
    /* Setters and their errors. */
    EXPECT(lacuna_render_job_set_skeleton_probability(NULL, 0.5f), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_skeleton_probability(job, 1.0f), LACUNA_STATUS_INVALID_ARGUMENT, "c_skel");
    EXPECT(lacuna_render_job_set_skeleton_probability(job, NAN), LACUNA_STATUS_INVALID_ARGUMENT, "c_skel");
    EXPECT(lacuna_render_job_set_skeleton_strength(NULL, 4), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_skeleton_strength(job, -1), LACUNA_STATUS_INVALID_ARGUMENT, "strength");
    EXPECT(lacuna_render_job_set_skeleton_strength(job, 2 * LACUNA_SKELETON_MAX_STRENGTH),
           LACUNA_STATUS_INVALID_ARGUMENT, "strength");
    EXPECT(lacuna_render_job_set_skeleton_strength_auto(NULL, 16), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_skeleton_strength_auto(job, 0.5f), LACUNA_STATUS_INVALID_ARGUMENT, "bound");
    EXPECT(lacuna_render_job_set_skeleton_strength_auto(job, NAN), LACUNA_STATUS_INVALID_ARGUMENT, "bound");
    EXPECT(lacuna_render_job_set_skeleton_resolution(NULL, 16, 0), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_skeleton_resolution(job, 2, 0), LACUNA_STATUS_INVALID_ARGUMENT, "resolution");
    EXPECT(lacuna_render_job_set_skeleton_resolution(job, 0, 10), LACUNA_STATUS_INVALID_ARGUMENT,
           "voxel budget");
    EXPECT(lacuna_render_job_set_skeleton_importance(NULL, 1, 1, 1), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_skeleton_importance(job, 0, 1, 1), LACUNA_STATUS_INVALID_ARGUMENT, "light rays");
    EXPECT(lacuna_render_job_set_skeleton_importance(job, 1, 0, 1), LACUNA_STATUS_INVALID_ARGUMENT,
           "importance node");
    EXPECT(lacuna_render_job_set_skeleton_importance(job, 1, 1, LACUNA_SKELETON_MAX_LOBES + 1),
           LACUNA_STATUS_INVALID_ARGUMENT, "max_lobes");
    EXPECT(lacuna_render_job_set_skeleton_visibility_test(NULL, true), LACUNA_STATUS_NULL_POINTER, "job");
    OK(lacuna_render_job_set_skeleton_probability(job, 0.6f));
    OK(lacuna_render_job_set_skeleton_strength(job, 8));
    OK(lacuna_render_job_set_skeleton_strength_auto(job, 32));
    OK(lacuna_render_job_set_skeleton_resolution(job, 0, 1 << 14));
    OK(lacuna_render_job_set_skeleton_resolution(job, 20, 0));
    OK(lacuna_render_job_set_skeleton_importance(job, 4096, 8, 2));
    OK(lacuna_render_job_set_skeleton_visibility_test(job, false));
    OK(lacuna_render_job_set_skeleton_visibility_test(job, true));
    OK(lacuna_render_job_set_resolution(job, 8, 6));
    OK(lacuna_render_job_set_samples_per_pixel(job, 2));
    /* A run builds the guide first and reports its time. */
    lacuna_film *film = NULL;
    OK(lacuna_render_job_run(job, &film));
    lacuna_render_stats rs;
    OK(lacuna_render_job_get_stats(job, &rs));
    CHECK(rs.spp == 2 && rs.precompute_seconds > 0 && rs.rays > 0);
    float px[8 * 6 * 3];
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, px, 8, 6, 0, 0));
    double sum = 0;
    for (int i = 0; i < 8 * 6 * 3; i++) sum += px[i];
    CHECK(sum > 0 && isfinite(sum));
    lacuna_film_release(film);
    /* A cancel request stops the next run during its precomputation. */
    film = NULL;
    OK(lacuna_render_job_cancel(job));
    EXPECT(lacuna_render_job_run(job, &film), LACUNA_STATUS_CANCELLED, NULL);
    CHECK(film == NULL);
    /* Integrators without precomputation report none. */
    lacuna_render_job *plain = NULL;
    OK(lacuna_render_job_new(scene, "path", &plain));
    OK(lacuna_render_job_set_resolution(plain, 4, 4));
    OK(lacuna_render_job_set_samples_per_pixel(plain, 1));
    OK(lacuna_render_job_run(plain, &film));
    OK(lacuna_render_job_get_stats(plain, &rs));
    CHECK(rs.precompute_seconds == 0);
    lacuna_film_release(film);
    lacuna_render_job_free(plain);

    /* Building a guide. */
    lacuna_skeleton_guide *g = NULL;
    EXPECT(lacuna_skeleton_guide_build(NULL, job, NULL, NULL, &g), LACUNA_STATUS_NULL_POINTER, "scene");
    EXPECT(lacuna_skeleton_guide_build(scene, job, NULL, NULL, NULL), LACUNA_STATUS_NULL_POINTER, "out_guide");
    EXPECT(lacuna_skeleton_guide_build(scene, NULL, stop_at_once, NULL, &g), LACUNA_STATUS_CANCELLED, NULL);
    EXPECT(lacuna_skeleton_guide_build(scene, job, stop_at_once, NULL, &g), LACUNA_STATUS_CANCELLED, NULL);
    CHECK(g == NULL);
    progress_calls = 0;
    OK(lacuna_skeleton_guide_build(scene, job, count_progress, NULL, &g));
    CHECK(g != NULL && progress_calls > 1);
    lacuna_skeleton_guide_info info;
    EXPECT(lacuna_skeleton_guide_get_info(NULL, &info), LACUNA_STATUS_NULL_POINTER, "guide");
    EXPECT(lacuna_skeleton_guide_get_info(g, NULL), LACUNA_STATUS_NULL_POINTER, "out_info");
    OK(lacuna_skeleton_guide_get_info(g, &info));
    CHECK(info.nodes > 0 && info.raw_nodes >= info.nodes && info.importance_nodes >= 1 &&
          info.guided_nodes >= 1 && info.guided_nodes <= info.nodes);
    CHECK(info.grid[0] > 0 && info.grid[1] > 0 && info.grid[2] > 0 && info.memory_bytes > 0 && info.seconds >= 0);
    lacuna_render_job_free(job);
    /* The options of a job's integrator name reach its guide: the same settings with the
       skeleton's lobes (`directions=lobes`) instead of the learned histograms. */
    lacuna_render_job *lobes_job = NULL;
    OK(lacuna_render_job_new(scene, "path_skeleton:directions=lobes", &lobes_job));
    OK(lacuna_render_job_set_skeleton_probability(lobes_job, 0.6f));
    OK(lacuna_render_job_set_skeleton_strength_auto(lobes_job, 32));
    OK(lacuna_render_job_set_skeleton_resolution(lobes_job, 20, 0));
    OK(lacuna_render_job_set_skeleton_importance(lobes_job, 4096, 8, 2));
    lacuna_skeleton_guide *lobes_guide = NULL;
    OK(lacuna_skeleton_guide_build(scene, lobes_job, NULL, NULL, &lobes_guide));
    lacuna_render_job_free(lobes_job);

    /* Queries. */
    lacuna_guide_query *q = NULL;
    EXPECT(lacuna_guide_query_new(NULL, &q), LACUNA_STATUS_NULL_POINTER, "guide");
    EXPECT(lacuna_guide_query_new(g, NULL), LACUNA_STATUS_NULL_POINTER, "out_query");
    OK(lacuna_guide_query_new(g, &q));
    /* The query keeps the guide (and the guide the scene) alive. */
    lacuna_skeleton_guide_release(g);
    lacuna_scene_release(scene);
    float c = -1;
    OK(lacuna_guide_query_guiding_probability(q, &c));
    CHECK(c == 0); /* not initialised yet */
    EXPECT(lacuna_guide_query_guiding_probability(NULL, &c), LACUNA_STATUS_NULL_POINTER, "query");
    EXPECT(lacuna_guide_query_guiding_probability(q, NULL), LACUNA_STATUS_NULL_POINTER, "out_probability");
    bool guided = false;
    lacuna_vec3 floor_point = v3(0.1f, -1.0f, 0.2f), up = v3(0, 1, 0);
    EXPECT(lacuna_guide_query_init(NULL, floor_point, up, up, &guided), LACUNA_STATUS_NULL_POINTER, "query");
    EXPECT(lacuna_guide_query_init(q, v3(NAN, 0, 0), up, up, &guided), LACUNA_STATUS_INVALID_ARGUMENT,
           "position");
    EXPECT(lacuna_guide_query_init(q, floor_point, v3(0, 0, 0), up, &guided), LACUNA_STATUS_INVALID_ARGUMENT,
           "normal");
    EXPECT(lacuna_guide_query_init(q, floor_point, up, v3(0, INFINITY, 0), &guided),
           LACUNA_STATUS_INVALID_ARGUMENT, "incident");
    OK(lacuna_guide_query_init(q, floor_point, up, up, NULL));
    OK(lacuna_guide_query_init(q, floor_point, up, up, &guided));
    CHECK(guided);
    OK(lacuna_guide_query_guiding_probability(q, &c));
    CHECK(fabsf(c - 0.6f) < 1e-6f);
    lacuna_vec3 d;
    float pdf = -1;
    EXPECT(lacuna_guide_query_sample(NULL, 0.1f, 0.2f, 0.3f, &d, &pdf), LACUNA_STATUS_NULL_POINTER, "query");
    EXPECT(lacuna_guide_query_sample(q, 0.1f, 0.2f, 0.3f, NULL, &pdf), LACUNA_STATUS_NULL_POINTER, "out_direction");
    EXPECT(lacuna_guide_query_sample(q, 0.1f, 0.2f, 0.3f, &d, NULL), LACUNA_STATUS_NULL_POINTER, "out_pdf");
    EXPECT(lacuna_guide_query_sample(q, 1.0f, 0.2f, 0.3f, &d, &pdf), LACUNA_STATUS_INVALID_ARGUMENT, "u0");
    EXPECT(lacuna_guide_query_sample(q, 0.1f, -0.1f, 0.3f, &d, &pdf), LACUNA_STATUS_INVALID_ARGUMENT, "u1");
    EXPECT(lacuna_guide_query_sample(q, 0.1f, 0.2f, NAN, &d, &pdf), LACUNA_STATUS_INVALID_ARGUMENT, "u2");
    CHECK(pdf == -1);
    EXPECT(lacuna_guide_query_pdf(NULL, up, &pdf), LACUNA_STATUS_NULL_POINTER, "query");
    EXPECT(lacuna_guide_query_pdf(q, up, NULL), LACUNA_STATUS_NULL_POINTER, "out_pdf");
    EXPECT(lacuna_guide_query_pdf(q, v3(0, 0, 0), &pdf), LACUNA_STATUS_INVALID_ARGUMENT, "direction");
    /* Most sampled directions point up from the floor, toward the lit inside of the box: with
       the default learned histogram 48 of the 64 (it keeps a uniform share over the sphere). */
    CHECK(sample_upward(q) > 40);
    /* The lobes aim more of the floor's directions up into the box than the histogram. */
    lacuna_guide_query *lobes_query = NULL;
    OK(lacuna_guide_query_new(lobes_guide, &lobes_query));
    lacuna_skeleton_guide_release(lobes_guide);
    OK(lacuna_guide_query_init(lobes_query, floor_point, up, up, &guided));
    CHECK(guided);
    CHECK(sample_upward(lobes_query) > 48);
    lacuna_guide_query_free(lobes_query);
    /* Outside the grid nothing is guided: sampling is refused, the density is 0. */
    OK(lacuna_guide_query_init(q, v3(50, 50, 50), up, up, &guided));
    CHECK(!guided);
    OK(lacuna_guide_query_guiding_probability(q, &c));
    CHECK(c == 0);
    EXPECT(lacuna_guide_query_sample(q, 0.1f, 0.2f, 0.3f, &d, &pdf), LACUNA_STATUS_INVALID_OPERATION,
           "not guided");
    OK(lacuna_guide_query_pdf(q, up, &pdf));
    CHECK(pdf == 0);
    lacuna_guide_query_free(q);
    lacuna_guide_query_free(NULL);
    lacuna_skeleton_guide_retain(NULL);
    lacuna_skeleton_guide_release(NULL);
}

/* ---------------------------------------------------------------------------------------- */
/* Curvilinear skeleton. */

static int count_lines(const char *path, const char *prefix) {
    FILE *f = fopen(path, "r");
    if (!f) {
        return -1;
    }
    char line[512];
    int n = 0;
    while (fgets(line, sizeof line, f)) {
        if (strncmp(line, prefix, strlen(prefix)) == 0) {
            n++;
        }
    }
    fclose(f);
    return n;
}

static void test_skeleton(lacuna_context *ctx) {
    lacuna_scene *scene = build_box_scene(ctx);
    lacuna_analysis *a = NULL;
    OK(lacuna_analysis_build(scene, 24, 0, 0, LACUNA_ANALYSIS_ALL_MAPS, NULL, NULL, &a));
    lacuna_scene_release(scene);
    lacuna_skeleton *s = NULL;
    /* Error paths first: nothing is written on failure. */
    EXPECT(lacuna_skeleton_build(NULL, 0, NULL, NULL, &s), LACUNA_STATUS_NULL_POINTER, "analysis");
    EXPECT(lacuna_skeleton_build(a, 0, NULL, NULL, NULL), LACUNA_STATUS_NULL_POINTER, "out_skeleton");
    EXPECT(lacuna_skeleton_build(a, 8, NULL, NULL, &s), LACUNA_STATUS_INVALID_ARGUMENT, "flags");
    EXPECT(lacuna_skeleton_build(a, 0, stop_at_once, NULL, &s), LACUNA_STATUS_CANCELLED, NULL);
    CHECK(s == NULL);
    progress_calls = 0;
    OK(lacuna_skeleton_build(a, LACUNA_SKELETON_TOPOLOGY, count_progress, NULL, &s));
    CHECK(s != NULL && progress_calls > 3);

    lacuna_skeleton_info info;
    EXPECT(lacuna_skeleton_get_info(NULL, &info), LACUNA_STATUS_NULL_POINTER, "skeleton");
    EXPECT(lacuna_skeleton_get_info(s, NULL), LACUNA_STATUS_NULL_POINTER, "out_info");
    OK(lacuna_skeleton_get_info(s, &info));
    /* The inside of the box and the padding shell around it: two components, no cycle. */
    CHECK(info.has_topology && info.b0 == 2 && info.b1 == 0);
    CHECK(info.components == info.b0 && info.cycle_rank == info.b1);
    CHECK(info.euler == (int64_t)info.b0 - (int64_t)info.b1 + (int64_t)info.b2);
    CHECK(info.raw_nodes >= info.filtered_nodes && info.filtered_nodes >= 2);
    CHECK(info.raw_edges + info.components == info.raw_nodes + info.cycle_rank);
    CHECK(info.seconds >= 0);

    /* Nodes and edges of both graphs. */
    lacuna_skeleton_node node;
    uint32_t e[2];
    EXPECT(lacuna_skeleton_get_node(s, 7, 0, &node), LACUNA_STATUS_INVALID_ARGUMENT, "graph 7");
    EXPECT(lacuna_skeleton_get_node(s, LACUNA_SKELETON_GRAPH_RAW, info.raw_nodes, &node), LACUNA_STATUS_OUT_OF_RANGE,
           "node index");
    EXPECT(lacuna_skeleton_get_node(s, LACUNA_SKELETON_GRAPH_RAW, 0, NULL), LACUNA_STATUS_NULL_POINTER, "out_node");
    EXPECT(lacuna_skeleton_get_node(NULL, 0, 0, &node), LACUNA_STATUS_NULL_POINTER, "skeleton");
    EXPECT(lacuna_skeleton_get_edge(s, 2, 0, e), LACUNA_STATUS_INVALID_ARGUMENT, "graph 2");
    EXPECT(lacuna_skeleton_get_edge(s, LACUNA_SKELETON_GRAPH_FILTERED, info.filtered_edges, e),
           LACUNA_STATUS_OUT_OF_RANGE, "edge index");
    EXPECT(lacuna_skeleton_get_edge(s, LACUNA_SKELETON_GRAPH_RAW, 0, NULL), LACUNA_STATUS_NULL_POINTER, "out_nodes");
    EXPECT(lacuna_skeleton_get_edge(NULL, 0, 0, e), LACUNA_STATUS_NULL_POINTER, "skeleton");
    for (uint32_t g = 0; g < 2; g++) {
        size_t nodes = g ? info.filtered_nodes : info.raw_nodes;
        size_t edges = g ? info.filtered_edges : info.raw_edges;
        size_t degrees = 0;
        int bad = 0;
        for (size_t i = 0; i < nodes; i++) {
            OK(lacuna_skeleton_get_node(s, g, i, &node));
            degrees += node.degree;
            bad += !(node.radius > 0 && isfinite(node.position.x) && node.filtered < info.filtered_nodes);
            bad += g == LACUNA_SKELETON_GRAPH_FILTERED && node.filtered != i;
            /* Every node lies in the padded box [-1, 1]^3 grown by a few voxels. */
            bad += fabsf(node.position.x) > 1.5f || fabsf(node.position.y) > 1.5f || fabsf(node.position.z) > 1.5f;
        }
        CHECK(bad == 0);
        size_t edge_ends = 0;
        for (size_t i = 0; i < edges; i++) {
            OK(lacuna_skeleton_get_edge(s, g, i, e));
            bad += !(e[0] < e[1] && e[1] < nodes);
            edge_ends += 2;
        }
        CHECK(bad == 0 && degrees == edge_ends);
    }

    /* A point on the floor seen from above maps to a filtered node inside the box. */
    lacuna_vec3 floor = v3(0.2f, -1.0f, 0.1f), up = v3(0, 1, 0), from = v3(0.1f, 1, 0.3f);
    uint32_t n = LACUNA_INVALID_INDEX;
    OK(lacuna_skeleton_map_point(s, &floor, &up, &from, &n));
    CHECK(n < info.filtered_nodes);
    OK(lacuna_skeleton_get_node(s, LACUNA_SKELETON_GRAPH_FILTERED, n, &node));
    CHECK(fabsf(node.position.x) < 1 && fabsf(node.position.y) < 1 && fabsf(node.position.z) < 1);
    /* The same point seen from below (outside the box) maps to the outside shell. */
    lacuna_vec3 below = v3(0, -1, 0);
    uint32_t n2 = LACUNA_INVALID_INDEX;
    OK(lacuna_skeleton_map_point(s, &floor, &up, &below, &n2));
    CHECK(n2 < info.filtered_nodes && n2 != n);
    lacuna_vec3 far_away = v3(100, 0, 0), bad = v3(NAN, 0, 0), zero = v3(0, 0, 0);
    EXPECT(lacuna_skeleton_map_point(s, &far_away, &up, &from, &n), LACUNA_STATUS_OUT_OF_RANGE, "outside");
    EXPECT(lacuna_skeleton_map_point(s, &bad, &up, &from, &n), LACUNA_STATUS_INVALID_ARGUMENT, "point");
    EXPECT(lacuna_skeleton_map_point(s, &floor, &bad, &from, &n), LACUNA_STATUS_INVALID_ARGUMENT, "normal");
    EXPECT(lacuna_skeleton_map_point(s, &floor, &up, &bad, &n), LACUNA_STATUS_INVALID_ARGUMENT, "incident");
    EXPECT(lacuna_skeleton_map_point(s, &floor, &zero, &from, &n), LACUNA_STATUS_INVALID_ARGUMENT, "zero");
    EXPECT(lacuna_skeleton_map_point(s, NULL, &up, &from, &n), LACUNA_STATUS_NULL_POINTER, "point");
    EXPECT(lacuna_skeleton_map_point(s, &floor, NULL, &from, &n), LACUNA_STATUS_NULL_POINTER, "normal");
    EXPECT(lacuna_skeleton_map_point(s, &floor, &up, NULL, &n), LACUNA_STATUS_NULL_POINTER, "incident");
    EXPECT(lacuna_skeleton_map_point(s, &floor, &up, &from, NULL), LACUNA_STATUS_NULL_POINTER, "out_node");
    EXPECT(lacuna_skeleton_map_point(NULL, &floor, &up, &from, &n), LACUNA_STATUS_NULL_POINTER, "skeleton");

    /* Export: OBJ and PLY with the right counts. */
    OK(lacuna_skeleton_export(s, LACUNA_SKELETON_GRAPH_RAW, LACUNA_SKELETON_FORMAT_OBJ, path_in_dir("skel.obj")));
    CHECK(count_lines(path_in_dir("skel.obj"), "v ") == (int)info.raw_nodes);
    CHECK(count_lines(path_in_dir("skel.obj"), "l ") == (int)info.raw_edges);
    OK(lacuna_skeleton_export(s, LACUNA_SKELETON_GRAPH_FILTERED, LACUNA_SKELETON_FORMAT_PLY,
                              path_in_dir("skel.ply")));
    CHECK(count_lines(path_in_dir("skel.ply"), "property float radius") == 1);
    char header[64];
    snprintf(header, sizeof header, "element vertex %zu", info.filtered_nodes);
    CHECK(count_lines(path_in_dir("skel.ply"), header) == 1);
    EXPECT(lacuna_skeleton_export(s, 0, 9, path_in_dir("x")), LACUNA_STATUS_INVALID_ARGUMENT, "format");
    EXPECT(lacuna_skeleton_export(s, 9, 0, path_in_dir("x")), LACUNA_STATUS_INVALID_ARGUMENT, "graph");
    EXPECT(lacuna_skeleton_export(s, 0, 0, path_in_dir("no-such-dir/skel.obj")), LACUNA_STATUS_IO, "no-such-dir");
    EXPECT(lacuna_skeleton_export(s, 0, 0, NULL), LACUNA_STATUS_NULL_POINTER, "path");
    EXPECT(lacuna_skeleton_export(NULL, 0, 0, path_in_dir("x")), LACUNA_STATUS_NULL_POINTER, "skeleton");

    /* Sequential thinning gives the same skeleton; without TOPOLOGY no Betti numbers. */
    lacuna_skeleton *seq = NULL;
    OK(lacuna_skeleton_build(a, LACUNA_SKELETON_SEQUENTIAL, NULL, NULL, &seq));
    lacuna_skeleton_info si;
    OK(lacuna_skeleton_get_info(seq, &si));
    CHECK(!si.has_topology && si.raw_nodes == info.raw_nodes && si.raw_edges == info.raw_edges &&
          si.filtered_nodes == info.filtered_nodes);
    lacuna_skeleton_release(seq);

    /* The skeleton keeps its analysis alive. */
    lacuna_skeleton_retain(s);
    lacuna_analysis_release(a);
    OK(lacuna_skeleton_map_point(s, &floor, &up, &from, &n2));
    CHECK(n2 == n);
    lacuna_skeleton_release(s);
    lacuna_skeleton_release(s);
    lacuna_skeleton_release(NULL);
    lacuna_skeleton_retain(NULL);
}

/* Vertex-connection resampling options (bdpt_skeleton, bdpt_ic): set, read back, rejected
 * with clear messages; a small bdpt_ic render. */
static void test_resampling(lacuna_context *ctx) {
    lacuna_scene *scene = build_box_scene(ctx);
    lacuna_render_job *pt = NULL, *skel = NULL, *ic = NULL;
    uint32_t subset = 0;
    float accept = -1, density = -1;
    bool images = true;
    OK(lacuna_render_job_new(scene, "path", &pt));
    EXPECT(lacuna_render_job_set_resampling_subset(pt, 64), LACUNA_STATUS_INVALID_OPERATION, "bdpt_skeleton");
    EXPECT(lacuna_render_job_set_resampling_accept(pt, 1), LACUNA_STATUS_INVALID_OPERATION, "'path'");
    EXPECT(lacuna_render_job_set_resampling_images(pt, true), LACUNA_STATUS_INVALID_OPERATION, "bdpt_ic");
    EXPECT(lacuna_render_job_set_record_density(pt, 0.01f), LACUNA_STATUS_INVALID_OPERATION, "bdpt_ic");
    EXPECT(lacuna_render_job_get_resampling_subset(pt, &subset), LACUNA_STATUS_INVALID_OPERATION, "'path'");
    CHECK(subset == 0);
    lacuna_render_job_free(pt);
    /* Defaults (002 section 5), then the integrator name's options, then setters (the latest wins). */
    OK(lacuna_render_job_new(scene, "bdpt_skeleton", &skel));
    OK(lacuna_render_job_get_resampling_subset(skel, &subset));
    OK(lacuna_render_job_get_resampling_accept(skel, &accept));
    OK(lacuna_render_job_get_resampling_images(skel, &images));
    OK(lacuna_render_job_get_record_density(skel, &density));
    CHECK(subset == 1024 && accept == 1.0f && !images && density == 0.001f);
    lacuna_render_job_free(skel);
    OK(lacuna_render_job_new(scene, "bdpt_skeleton:subset=64:accept=0.5", &skel));
    OK(lacuna_render_job_get_resampling_subset(skel, &subset));
    OK(lacuna_render_job_get_resampling_accept(skel, &accept));
    CHECK(subset == 64 && accept == 0.5f);
    OK(lacuna_render_job_set_resampling_subset(skel, 128));
    OK(lacuna_render_job_set_resampling_accept(skel, 0.25f));
    OK(lacuna_render_job_set_resampling_images(skel, true));
    OK(lacuna_render_job_get_resampling_subset(skel, &subset));
    OK(lacuna_render_job_get_resampling_accept(skel, &accept));
    OK(lacuna_render_job_get_resampling_images(skel, &images));
    CHECK(subset == 128 && accept == 0.25f && images);
    /* Invalid values: rejected, nothing changed. */
    EXPECT(lacuna_render_job_set_resampling_subset(skel, 0), LACUNA_STATUS_INVALID_ARGUMENT, "subset=0");
    EXPECT(lacuna_render_job_set_resampling_subset(skel, (1u << 24) + 1), LACUNA_STATUS_INVALID_ARGUMENT,
           "subset");
    EXPECT(lacuna_render_job_set_resampling_accept(skel, -1), LACUNA_STATUS_INVALID_ARGUMENT, "accept=-1");
    EXPECT(lacuna_render_job_set_resampling_accept(skel, NAN), LACUNA_STATUS_INVALID_ARGUMENT, "accept");
    EXPECT(lacuna_render_job_set_resampling_accept(skel, INFINITY), LACUNA_STATUS_INVALID_ARGUMENT, "accept");
    EXPECT(lacuna_render_job_set_record_density(skel, 0.01f), LACUNA_STATUS_INVALID_OPERATION, "bdpt_ic");
    OK(lacuna_render_job_get_resampling_subset(skel, &subset));
    OK(lacuna_render_job_get_resampling_accept(skel, &accept));
    CHECK(subset == 128 && accept == 0.25f);
    /* NULL arguments. */
    EXPECT(lacuna_render_job_set_resampling_subset(NULL, 64), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_resampling_accept(NULL, 1), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_resampling_images(NULL, true), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_set_record_density(NULL, 0.1f), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_get_resampling_subset(NULL, &subset), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_get_resampling_subset(skel, NULL), LACUNA_STATUS_NULL_POINTER, "out_subset");
    EXPECT(lacuna_render_job_get_resampling_accept(NULL, &accept), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_get_resampling_accept(skel, NULL), LACUNA_STATUS_NULL_POINTER, "out_accept");
    EXPECT(lacuna_render_job_get_resampling_images(NULL, &images), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_get_resampling_images(skel, NULL), LACUNA_STATUS_NULL_POINTER, "out_enabled");
    EXPECT(lacuna_render_job_get_record_density(NULL, &density), LACUNA_STATUS_NULL_POINTER, "job");
    EXPECT(lacuna_render_job_get_record_density(skel, NULL), LACUNA_STATUS_NULL_POINTER, "out_density");
    lacuna_render_job_free(skel);
    /* ICBPT: density and subset, and a small render. */
    OK(lacuna_render_job_new(scene, "bdpt_ic:density=0.5", &ic));
    lacuna_scene_release(scene);
    OK(lacuna_render_job_get_record_density(ic, &density));
    CHECK(density == 0.5f);
    EXPECT(lacuna_render_job_set_record_density(ic, 0), LACUNA_STATUS_INVALID_ARGUMENT, "density=0");
    EXPECT(lacuna_render_job_set_record_density(ic, 1.5f), LACUNA_STATUS_INVALID_ARGUMENT, "(0, 1]");
    EXPECT(lacuna_render_job_set_record_density(ic, NAN), LACUNA_STATUS_INVALID_ARGUMENT, "density");
    EXPECT(lacuna_render_job_set_resampling_accept(ic, 1), LACUNA_STATUS_INVALID_OPERATION, "bdpt_skeleton");
    OK(lacuna_render_job_set_record_density(ic, 0.05f));
    OK(lacuna_render_job_set_resampling_subset(ic, 16));
    OK(lacuna_render_job_set_light_paths(ic, 40)); /* the resampling integrators trace light subpaths */
    OK(lacuna_render_job_get_record_density(ic, &density));
    OK(lacuna_render_job_get_resampling_subset(ic, &subset));
    CHECK(density == 0.05f && subset == 16);
    enum { W = 10, H = 8, N = W * H * 3 };
    OK(lacuna_render_job_set_resolution(ic, W, H));
    OK(lacuna_render_job_set_samples_per_pixel(ic, 2));
    OK(lacuna_render_job_set_max_depth(ic, 3));
    lacuna_film *film = NULL;
    OK(lacuna_render_job_run(ic, &film));
    static float radiance[N];
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, radiance, W, H, 0, 0));
    double sum = 0;
    int finite = 1;
    for (int i = 0; i < N; i++) {
        sum += radiance[i];
        finite &= isfinite(radiance[i]) && radiance[i] >= 0;
    }
    CHECK(finite && sum > 0);
    lacuna_film_release(film);
    lacuna_render_job_free(ic);
}

/* Instant radiosity (vpl): options in the integrator name, refused when wrong; a small
 * compensated render, finite and not black. */
static void test_vpl(lacuna_context *ctx) {
    lacuna_scene *scene = build_box_scene(ctx);
    lacuna_render_job *job = NULL, *bad = NULL;
    EXPECT(lacuna_render_job_new(scene, "vpl:count=0", &bad), LACUNA_STATUS_INVALID_ARGUMENT, "count");
    EXPECT(lacuna_render_job_new(scene, "vpl:clamp=-1", &bad), LACUNA_STATUS_INVALID_ARGUMENT, "clamp");
    EXPECT(lacuna_render_job_new(scene, "vpl:visibility=clusters", &bad), LACUNA_STATUS_INVALID_ARGUMENT,
           "not implemented");
    EXPECT(lacuna_render_job_new(scene, "vpl:visibility=skeleton:shadow_res=2", &bad),
           LACUNA_STATUS_INVALID_ARGUMENT, "shadow_res");
    CHECK(bad == NULL);
    /* Skeleton visibility through the same option string: a finite, lit image. */
    lacuna_render_job *skeleton_job = NULL;
    OK(lacuna_render_job_new(scene, "vpl:count=8:visibility=skeleton:shadow_res=16:shadow_budget_mb=4",
                             &skeleton_job));
    OK(lacuna_render_job_set_resolution(skeleton_job, 10, 8));
    OK(lacuna_render_job_set_samples_per_pixel(skeleton_job, 2));
    OK(lacuna_render_job_set_max_depth(skeleton_job, 3));
    lacuna_film *skeleton_film = NULL;
    OK(lacuna_render_job_run(skeleton_job, &skeleton_film));
    static float skeleton_radiance[10 * 8 * 3];
    OK(lacuna_film_read(skeleton_film, LACUNA_FILM_CHANNEL_RADIANCE, skeleton_radiance, 10, 8, 0, 0));
    double skeleton_sum = 0;
    int skeleton_finite = 1;
    for (int i = 0; i < 10 * 8 * 3; i++) {
        skeleton_sum += skeleton_radiance[i];
        skeleton_finite &= isfinite(skeleton_radiance[i]) && skeleton_radiance[i] >= 0;
    }
    CHECK(skeleton_finite && skeleton_sum > 0);
    lacuna_film_release(skeleton_film);
    lacuna_render_job_free(skeleton_job);
    OK(lacuna_render_job_new(scene, "vpl:count=8:clamp=0.2:compensate=true", &job));
    lacuna_scene_release(scene);
    enum { W = 10, H = 8, N = W * H * 3 };
    OK(lacuna_render_job_set_resolution(job, W, H));
    OK(lacuna_render_job_set_samples_per_pixel(job, 2));
    OK(lacuna_render_job_set_max_depth(job, 3));
    lacuna_film *film = NULL;
    OK(lacuna_render_job_run(job, &film));
    static float radiance[N];
    OK(lacuna_film_read(film, LACUNA_FILM_CHANNEL_RADIANCE, radiance, W, H, 0, 0));
    double sum = 0;
    int finite = 1;
    for (int i = 0; i < N; i++) {
        sum += radiance[i];
        finite &= isfinite(radiance[i]) && radiance[i] >= 0;
    }
    CHECK(finite && sum > 0);
    OK(lacuna_film_write_exr(film, path_in_dir("vpl.exr")));
    lacuna_film_release(film);
    lacuna_render_job_free(job);
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s SCRATCH_DIR\n", argv[0]);
        return 2;
    }
    snprintf(dir, sizeof dir, "%s", argv[1]);
    test_version_and_status();
    test_context();
    test_mesh();
    lacuna_context *ctx = NULL;
    OK(lacuna_context_new(&ctx));
    OK(lacuna_context_set_thread_count(ctx, 2));
    test_builder(ctx);
    test_queries(ctx);
    test_render(ctx);
    test_bdpt(ctx);
    test_resampling(ctx);
    test_vpl(ctx);
    test_analysis(ctx);
    test_skeleton_guide(ctx);
    test_skeleton(ctx);
    lacuna_context_release(ctx);
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
