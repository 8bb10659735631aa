/* The check macros and small helpers shared by the C tests (tests/c/test_*.c):
 * each test program includes this once; results are counted in `passed` and `failed`, and
 * `dir` holds the scratch directory given as argv[1]. */
#ifndef LACUNA_TEST_CHECK_H
#define LACUNA_TEST_CHECK_H

#include "lacuna.h"

#include <stdio.h>
#include <string.h>

static int passed, failed;
static char dir[1024];

#define CHECK(cond)                                                                  \
    do {                                                                             \
        if (cond) {                                                                  \
            passed++;                                                                \
        } else {                                                                     \
            failed++;                                                                \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
        }                                                                            \
    } while (0)

/* Checks a status against the expected one; a failure's message must contain `needle`
 * (unless it is NULL). */
static void expect_status(lacuna_status got, lacuna_status want, const char *needle, const char *call,
                          int line) {
    const char *message = lacuna_last_error_message();
    if (got != want) {
        failed++;
        fprintf(stderr, "%s:%d: %s returned %s, expected %s (%s)\n", __FILE__, line, call,
                lacuna_status_string(got), lacuna_status_string(want), message);
    } else if (want != LACUNA_STATUS_OK && needle != NULL && strstr(message, needle) == NULL) {
        failed++;
        fprintf(stderr, "%s:%d: message \"%s\" lacks \"%s\"\n", __FILE__, line, message, needle);
    } else {
        passed++;
    }
}

#define EXPECT(call, want, needle) expect_status((call), (want), (needle), #call, __LINE__)
#define OK(call) EXPECT(call, LACUNA_STATUS_OK, NULL)

/* `name` inside the scratch directory; up to 8 results are valid at once. */
static const char *path_in_dir(const char *name) {
    static char buf[8][1200];
    static int next;
    char *p = buf[next++ % 8];
    snprintf(p, 1200, "%s/%s", dir, name);
    return p;
}

static lacuna_vec3 v3(float x, float y, float z) {
    lacuna_vec3 v;
    v.x = x;
    v.y = y;
    v.z = z;
    return v;
}

static lacuna_rgb rgb(float r, float g, float b) {
    lacuna_rgb c;
    c.r = r;
    c.g = g;
    c.b = b;
    return c;
}

/* Adds a floor: the square [-half, half]^2 at y = 0, facing +y, two triangles of `material`.
 * (inline: programs that do not use it get no unused-function warning.) */
static inline void add_floor_quad(lacuna_scene_builder *b, float half, uint32_t material) {
    const float p[4][3] = {{-half, 0, -half}, {half, 0, -half}, {half, 0, half}, {-half, 0, half}};
    const uint32_t idx[2][3] = {{0, 2, 1}, {0, 3, 2}};
    lacuna_mesh *m = NULL;
    OK(lacuna_mesh_new(&m));
    OK(lacuna_mesh_set_positions(m, &p[0][0], 0, 4));
    OK(lacuna_mesh_set_indices(m, &idx[0][0], 0, 2));
    OK(lacuna_mesh_set_material(m, material));
    uint32_t mesh_index = 99;
    OK(lacuna_scene_builder_add_mesh(b, m, &mesh_index));
    lacuna_mesh_free(m);
}

#endif
