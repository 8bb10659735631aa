/* A C host of Lacuna: builds a Cornell box from arrays written inline, renders it with the
 * path tracer and writes an OpenEXR file.
 *   render_c [out.exr] [spp] */
#include <lacuna.h>

#include <stdio.h>
#include <stdlib.h>

/* Every call returns a status; on failure, print the library's message and stop. */
#define TRY(call)                                                                        \
    do {                                                                                 \
        lacuna_status s_ = (call);                                                       \
        if (s_ != LACUNA_STATUS_OK) {                                                    \
            fprintf(stderr, "%s failed: %s\n", #call, lacuna_last_error_message());     \
            exit(1);                                                                     \
        }                                                                                \
    } while (0)

/* The Cornell box (after the original measurements, scaled to metres): one quad per row,
 * corners counter-clockwise seen from inside the box. */
static const float quads[][4][3] = {
    /* floor */ {{0.556f, 0, 0}, {0, 0, 0}, {0, 0, 0.559f}, {0.556f, 0, 0.559f}},
    /* ceiling */ {{0.556f, 0.549f, 0}, {0.556f, 0.549f, 0.559f}, {0, 0.549f, 0.559f}, {0, 0.549f, 0}},
    /* back */ {{0.556f, 0, 0.559f}, {0, 0, 0.559f}, {0, 0.549f, 0.559f}, {0.556f, 0.549f, 0.559f}},
    /* right (green) */ {{0, 0, 0.559f}, {0, 0, 0}, {0, 0.549f, 0}, {0, 0.549f, 0.559f}},
    /* left (red) */ {{0.556f, 0, 0}, {0.556f, 0, 0.559f}, {0.556f, 0.549f, 0.559f}, {0.556f, 0.549f, 0}},
    /* light */ {{0.343f, 0.5488f, 0.227f}, {0.343f, 0.5488f, 0.332f}, {0.213f, 0.5488f, 0.332f}, {0.213f, 0.5488f, 0.227f}},
    /* short block */
    {{0.130f, 0.165f, 0.065f}, {0.082f, 0.165f, 0.225f}, {0.240f, 0.165f, 0.272f}, {0.290f, 0.165f, 0.114f}},
    {{0.290f, 0, 0.114f}, {0.290f, 0.165f, 0.114f}, {0.240f, 0.165f, 0.272f}, {0.240f, 0, 0.272f}},
    {{0.130f, 0, 0.065f}, {0.130f, 0.165f, 0.065f}, {0.290f, 0.165f, 0.114f}, {0.290f, 0, 0.114f}},
    {{0.082f, 0, 0.225f}, {0.082f, 0.165f, 0.225f}, {0.130f, 0.165f, 0.065f}, {0.130f, 0, 0.065f}},
    {{0.240f, 0, 0.272f}, {0.240f, 0.165f, 0.272f}, {0.082f, 0.165f, 0.225f}, {0.082f, 0, 0.225f}},
    /* tall block */
    {{0.423f, 0.330f, 0.247f}, {0.265f, 0.330f, 0.296f}, {0.314f, 0.330f, 0.456f}, {0.472f, 0.330f, 0.406f}},
    {{0.423f, 0, 0.247f}, {0.423f, 0.330f, 0.247f}, {0.472f, 0.330f, 0.406f}, {0.472f, 0, 0.406f}},
    {{0.472f, 0, 0.406f}, {0.472f, 0.330f, 0.406f}, {0.314f, 0.330f, 0.456f}, {0.314f, 0, 0.456f}},
    {{0.314f, 0, 0.456f}, {0.314f, 0.330f, 0.456f}, {0.265f, 0.330f, 0.296f}, {0.265f, 0, 0.296f}},
    {{0.265f, 0, 0.296f}, {0.265f, 0.330f, 0.296f}, {0.423f, 0.330f, 0.247f}, {0.423f, 0, 0.247f}},
};
enum { WHITE, RED, GREEN, LIGHT };
static const unsigned quad_material[] = {WHITE, WHITE, WHITE, GREEN, RED, LIGHT, WHITE, WHITE, WHITE,
                                         WHITE, WHITE, WHITE, WHITE, WHITE, WHITE, WHITE};
#define QUADS (sizeof quads / sizeof quads[0])

static bool print_progress(void *user_data, double fraction) {
    int *last = (int *)user_data;
    int percent = (int)(fraction * 100);
    if (percent / 10 > *last / 10) {
        fprintf(stderr, "\r%3d%%", percent);
        *last = percent;
    }
    return true;
}

int main(int argc, char **argv) {
    const char *out = argc > 1 ? argv[1] : "cornell.exr";
    unsigned spp = argc > 2 ? (unsigned)atoi(argv[2]) : 16;
    if (lacuna_version() != LACUNA_VERSION) {
        fprintf(stderr, "header %s but library %s\n", LACUNA_VERSION_STRING, lacuna_version_string());
        return 1;
    }
    lacuna_context *ctx = NULL;
    TRY(lacuna_context_new(&ctx));
    lacuna_scene_builder *builder = NULL;
    TRY(lacuna_scene_builder_new(ctx, &builder));

    uint32_t material[4];
    const lacuna_rgb albedo[4] = {{0.73f, 0.73f, 0.73f}, {0.63f, 0.065f, 0.05f}, {0.14f, 0.45f, 0.091f}, {0, 0, 0}};
    for (int m = 0; m < 4; m++) {
        TRY(lacuna_scene_builder_add_material(builder, LACUNA_MATERIAL_KIND_DIFFUSE, &material[m]));
        TRY(lacuna_scene_builder_set_material_rgb(builder, material[m], LACUNA_MATERIAL_RGB_DIFFUSE, albedo[m]));
    }
    const lacuna_rgb emission = {17, 12, 4};
    TRY(lacuna_scene_builder_set_material_rgb(builder, material[LIGHT], LACUNA_MATERIAL_RGB_EMISSION, emission));

    /* One mesh: 4 vertices and 2 triangles per quad, one material per triangle. */
    static uint32_t indices[QUADS][2][3];
    static uint32_t materials[QUADS][2];
    for (uint32_t q = 0; q < QUADS; q++) {
        uint32_t v = 4 * q;
        uint32_t t[2][3] = {{v, v + 1, v + 2}, {v, v + 2, v + 3}};
        for (int k = 0; k < 3; k++) {
            indices[q][0][k] = t[0][k];
            indices[q][1][k] = t[1][k];
        }
        materials[q][0] = materials[q][1] = material[quad_material[q]];
    }
    lacuna_mesh *mesh = NULL;
    TRY(lacuna_mesh_new(&mesh));
    TRY(lacuna_mesh_set_name(mesh, "cornell box"));
    TRY(lacuna_mesh_set_positions(mesh, &quads[0][0][0], 0, QUADS * 4));
    TRY(lacuna_mesh_set_indices(mesh, &indices[0][0][0], 0, QUADS * 2));
    TRY(lacuna_mesh_set_materials(mesh, &materials[0][0], 0, QUADS * 2));
    uint32_t mesh_index;
    TRY(lacuna_scene_builder_add_mesh(builder, mesh, &mesh_index));
    lacuna_mesh_free(mesh); /* the builder copied the data */

    const lacuna_vec3 eye = {0.278f, 0.273f, -0.800f}, target = {0.278f, 0.273f, 0}, up = {0, 1, 0};
    TRY(lacuna_scene_builder_set_camera(builder, eye, target, up, 39.3f));
    lacuna_scene *scene = NULL;
    TRY(lacuna_scene_builder_build(builder, &scene)); /* consumes the builder */

    lacuna_render_job *job = NULL;
    TRY(lacuna_render_job_new(scene, "path", &job));
    TRY(lacuna_render_job_set_resolution(job, 256, 256));
    TRY(lacuna_render_job_set_samples_per_pixel(job, spp));
    TRY(lacuna_render_job_set_max_depth(job, 8));
    int last = -1;
    TRY(lacuna_render_job_set_progress_callback(job, print_progress, &last));
    lacuna_film *film = NULL;
    TRY(lacuna_render_job_run(job, &film));
    fprintf(stderr, "\n");

    lacuna_render_stats stats;
    TRY(lacuna_film_get_stats(film, &stats));
    lacuna_memory_report memory;
    TRY(lacuna_scene_get_memory_report(scene, &memory));
    TRY(lacuna_film_write_exr(film, out));
    char preview[4096];
    snprintf(preview, sizeof preview, "%s.png", out);
    TRY(lacuna_film_write_png(film, preview, 0));
    printf("%u spp in %.2f s (%.2f M rays/s); scene memory %zu bytes (BVH %zu) -> %s\n", stats.spp,
           stats.seconds, (double)stats.rays / stats.seconds / 1e6, memory.total, memory.bvh, out);

    lacuna_film_release(film);
    lacuna_render_job_free(job);
    lacuna_scene_release(scene);
    lacuna_context_release(ctx);
    return 0;
}
