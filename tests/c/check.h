/* The check macros and small helpers shared by the C tests (test_capi.c, test_environment.c):
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

#endif
