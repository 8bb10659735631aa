/* A path tracer written by a host, in C, on Lacuna's C API only.
 *
 * Lacuna does the ray queries (lacuna_scene_intersect / _occluded), the light sampling
 * (lacuna_light_sampler_sample) and the light-sampling density of emitters the host's own rays
 * hit (lacuna_light_sampler_eval); the host evaluates and samples the materials (Lambertian,
 * modified Phong, mirror), combines the two strategies by multiple importance sampling with
 * the power heuristic, and runs Russian roulette. It estimates the same image as
 * `lacuna render --integrator path` (tests/c_api.rs checks that by z-tests).
 *
 *   host_pathtracer SCENE OUT.pfm [WIDTH HEIGHT SPP SEED MAX_DEPTH THREADS]
 *
 * SCENE is a JSON scene file or a built-in scene name (two-rooms, corridor). The image is
 * written as a little-endian PFM (linear RGB, mean radiance per pixel). The run time of the
 * rendering loop goes to stderr as `render_seconds S`. */
#include <lacuna.h>

#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define PI_F 3.14159265358979f

#define TRY(call)                                                                        \
    do {                                                                                 \
        lacuna_status s_ = (call);                                                       \
        if (s_ != LACUNA_STATUS_OK) {                                                    \
            fprintf(stderr, "%s failed: %s\n", #call, lacuna_last_error_message());     \
            exit(1);                                                                     \
        }                                                                                \
    } while (0)

/* ---- small vector helpers ---- */
typedef struct { float x, y, z; } vec3;
static vec3 v3(float x, float y, float z) { vec3 v = {x, y, z}; return v; }
static vec3 vload(const float *a) { return v3(a[0], a[1], a[2]); }
static vec3 add(vec3 a, vec3 b) { return v3(a.x + b.x, a.y + b.y, a.z + b.z); }
static vec3 sub(vec3 a, vec3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
static vec3 scale(vec3 a, float s) { return v3(a.x * s, a.y * s, a.z * s); }
static vec3 mul(vec3 a, vec3 b) { return v3(a.x * b.x, a.y * b.y, a.z * b.z); }
static float dot(vec3 a, vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static vec3 cross(vec3 a, vec3 b) {
    return v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static vec3 normalize(vec3 a) { return scale(a, 1.0f / sqrtf(dot(a, a))); }
static vec3 rgb3(lacuna_rgb c) { return v3(c.r, c.g, c.b); }
static float max3(vec3 a) { return fmaxf(a.x, fmaxf(a.y, a.z)); }
static float luminance(vec3 c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }

/* An orthonormal basis around unit n (Duff et al. 2017). */
static void basis(vec3 n, vec3 *s, vec3 *t) {
    float sign = copysignf(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    *s = v3(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    *t = v3(b, sign + n.y * n.y * a, -n.y);
}

/* ---- random numbers: PCG32 per pixel sample ---- */
typedef struct { uint64_t state, inc; } pcg32;
static uint32_t pcg_next(pcg32 *r) {
    uint64_t old = r->state;
    r->state = old * 6364136223846793005ULL + r->inc;
    uint32_t xorshifted = (uint32_t)(((old >> 18u) ^ old) >> 27u);
    uint32_t rot = (uint32_t)(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((32 - rot) & 31));
}
static float uniform(pcg32 *r) { return (float)(pcg_next(r) >> 8) * (1.0f / 16777216.0f); }
static pcg32 pcg_seed(uint64_t a, uint64_t b) {
    pcg32 r = {0, (b << 1u) | 1u};
    pcg_next(&r);
    r.state += a;
    pcg_next(&r);
    return r;
}

/* ---- the host's materials (Lacuna's conventions: two-sided, see lacuna_surface) ---- */
typedef struct {
    uint32_t kind;
    vec3 diffuse, specular;
    float exponent, p_specular;
} material;

static material material_of(const lacuna_surface *s) {
    if (s->kind == LACUNA_MATERIAL_KIND_DIELECTRIC) {
        fprintf(stderr, "this host does not shade glass (material %u)\n", s->material);
        exit(1);
    }
    material m;
    m.kind = s->kind;
    m.diffuse = rgb3(s->diffuse);
    m.specular = rgb3(s->specular);
    m.exponent = s->exponent;
    float ld = luminance(m.diffuse), ls = luminance(m.specular);
    m.p_specular = ld + ls > 0 ? ls / (ld + ls) : 0;
    return m;
}

static vec3 reflect(vec3 wo, vec3 n) { return sub(scale(n, 2 * dot(wo, n)), wo); }

/* f(wo, wi) for wo, wi on the side of the facing normal n (zero otherwise). */
static vec3 bsdf_eval(const material *m, vec3 n, vec3 wo, vec3 wi) {
    if (dot(wi, n) <= 0 || dot(wo, n) <= 0) return v3(0, 0, 0);
    vec3 f = scale(m->diffuse, 1.0f / PI_F);
    if (m->kind == LACUNA_MATERIAL_KIND_GLOSSY) {
        float c = dot(reflect(wo, n), wi);
        if (c > 0) f = add(f, scale(m->specular, (m->exponent + 2) / (2 * PI_F) * powf(c, m->exponent)));
    }
    return f;
}

static float bsdf_pdf(const material *m, vec3 n, vec3 wo, vec3 wi) {
    float cos_i = dot(wi, n);
    if (cos_i <= 0 || dot(wo, n) <= 0) return 0;
    float pdf = cos_i / PI_F;
    if (m->kind == LACUNA_MATERIAL_KIND_GLOSSY) {
        float c = dot(reflect(wo, n), wi);
        float spec = c > 0 ? (m->exponent + 1) / (2 * PI_F) * powf(c, m->exponent) : 0;
        pdf = (1 - m->p_specular) * pdf + m->p_specular * spec;
    }
    return pdf;
}

/* Samples wi; returns its pdf (0: none). */
static float bsdf_sample(const material *m, vec3 n, vec3 wo, pcg32 *rng, vec3 *wi) {
    float uc = uniform(rng), u1 = uniform(rng), u2 = uniform(rng);
    vec3 axis = n;
    float cos_t, phi = 2 * PI_F * u2;
    if (m->kind == LACUNA_MATERIAL_KIND_GLOSSY && uc < m->p_specular) {
        axis = reflect(wo, n);
        cos_t = powf(u1, 1.0f / (m->exponent + 1));
    } else {
        cos_t = sqrtf(1 - u1);
    }
    float sin_t = sqrtf(fmaxf(0.0f, 1 - cos_t * cos_t));
    vec3 s, t;
    basis(axis, &s, &t);
    *wi = add(add(scale(s, sin_t * cosf(phi)), scale(t, sin_t * sinf(phi))), scale(axis, cos_t));
    return bsdf_pdf(m, n, wo, *wi);
}

static float power_heuristic(float a, float b) { return a * a / (a * a + b * b); }

/* ---- the renderer ---- */
typedef struct {
    const lacuna_scene *scene;
    const lacuna_light_sampler *lights;
    uint32_t environment_light;
    vec3 eye, forward, right, up; /* right and up scaled by tan(fov/2) (and the aspect) */
    uint32_t width, height, spp, max_depth;
    uint64_t seed;
    float *pixels;
    uint32_t next_row;
    pthread_mutex_t lock;
} renderer;

static vec3 trace(const renderer *r, lacuna_ray ray, pcg32 *rng) {
    vec3 radiance = v3(0, 0, 0), beta = v3(1, 1, 1);
    /* The previous vertex's light query and BSDF density, for the MIS weight of an emitter
     * the BSDF-sampled ray hits. */
    lacuna_light_query prev;
    lacuna_light_query_init(&prev);
    float prev_pdf = 0;
    int prev_delta = 1;
    for (uint32_t depth = 0;; depth++) {
        vec3 dir = vload(ray.direction);
        lacuna_hit hit;
        TRY(lacuna_scene_intersect(r->scene, &ray, &hit));
        if (hit.triangle == LACUNA_INVALID_INDEX) {
            if (r->environment_light != LACUNA_INVALID_INDEX) {
                lacuna_light_hit lh = {r->environment_light, {dir.x, dir.y, dir.z}, INFINITY};
                lacuna_light_eval e;
                TRY(lacuna_light_sampler_eval(r->lights, &prev, &lh, &e));
                float w = prev_delta ? 1 : power_heuristic(prev_pdf, e.pdf);
                radiance = add(radiance, scale(mul(beta, rgb3(e.radiance)), w));
            }
            break;
        }
        lacuna_surface surf;
        TRY(lacuna_scene_get_surface(r->scene, &hit, &surf));
        vec3 wo = scale(dir, -1), ng = vload(surf.geometric_normal);

        uint32_t light;
        TRY(lacuna_light_sampler_get_triangle_light(r->lights, hit.triangle, &light));
        if (light != LACUNA_INVALID_INDEX) {
            lacuna_light_hit lh = {light, {dir.x, dir.y, dir.z}, hit.t};
            lacuna_light_eval e;
            TRY(lacuna_light_sampler_eval(r->lights, &prev, &lh, &e));
            float w = prev_delta ? 1 : power_heuristic(prev_pdf, e.pdf);
            radiance = add(radiance, scale(mul(beta, rgb3(e.radiance)), w));
        }
        if (depth >= r->max_depth) break;

        material m = material_of(&surf);
        vec3 n = vload(surf.shading_normal);
        if (dot(n, wo) < 0) n = scale(n, -1); /* two-sided: the side of wo */
        int delta = m.kind == LACUNA_MATERIAL_KIND_MIRROR;

        lacuna_light_query q;
        lacuna_light_query_init(&q);
        memcpy(q.position, surf.position, sizeof q.position);
        q.normal[0] = n.x, q.normal[1] = n.y, q.normal[2] = n.z;
        if (!delta) {
            /* Next-event estimation: Lacuna picks the light and the point on it. */
            q.u[0] = uniform(rng);
            q.u[1] = uniform(rng);
            lacuna_light_sample ls;
            TRY(lacuna_light_sampler_sample(r->lights, &q, &ls));
            vec3 wi = vload(ls.direction);
            /* Light on wo's side of the geometric surface only (shading normals would
             * otherwise let it through walls). */
            if (ls.light != LACUNA_INVALID_INDEX && dot(wi, ng) * dot(wo, ng) > 0) {
                vec3 f = bsdf_eval(&m, n, wo, wi);
                if (max3(f) > 0) {
                    lacuna_ray shadow;
                    bool occluded;
                    TRY(lacuna_surface_spawn_shadow_ray(&surf, &ls, &shadow));
                    TRY(lacuna_scene_occluded(r->scene, &shadow, &occluded));
                    if (!occluded) {
                        float w = (ls.flags & LACUNA_LIGHT_SAMPLE_DELTA)
                                      ? 1
                                      : power_heuristic(ls.pdf, bsdf_pdf(&m, n, wo, wi));
                        vec3 c = mul(f, rgb3(ls.radiance));
                        radiance = add(radiance, scale(mul(beta, c), dot(wi, n) * w / ls.pdf));
                    }
                }
            }
        }

        /* The host's BSDF sampling. */
        vec3 wi, f;
        float pdf;
        if (m.kind == LACUNA_MATERIAL_KIND_MIRROR) {
            wi = reflect(wo, n);
            f = m.specular; /* f |cos| / pdf */
            pdf = 1;
        } else {
            pdf = bsdf_sample(&m, n, wo, rng, &wi);
            if (!(pdf > 0)) break;
            f = scale(bsdf_eval(&m, n, wo, wi), dot(wi, n) / pdf);
        }
        if (dot(wi, ng) * dot(wo, ng) <= 0) break; /* reflections stay on wo's side */
        beta = mul(beta, f);
        if (!(max3(beta) > 0) || !isfinite(max3(beta))) break;
        prev = q;
        prev_pdf = pdf;
        prev_delta = delta;
        lacuna_vec3 d = {wi.x, wi.y, wi.z};
        TRY(lacuna_surface_spawn_ray(&surf, d, &ray));

        if (depth + 1 >= 5) { /* Russian roulette, as Lacuna's path tracer */
            float qr = fmaxf(1 - max3(beta), 0.05f);
            if (uniform(rng) < qr) break;
            beta = scale(beta, 1 / (1 - qr));
        }
    }
    return radiance;
}

static void *render_rows(void *arg) {
    renderer *r = (renderer *)arg;
    for (;;) {
        pthread_mutex_lock(&r->lock);
        uint32_t y = r->next_row++;
        pthread_mutex_unlock(&r->lock);
        if (y >= r->height) return NULL;
        for (uint32_t x = 0; x < r->width; x++) {
            vec3 sum = v3(0, 0, 0);
            uint64_t pixel = (uint64_t)y * r->width + x;
            for (uint32_t s = 0; s < r->spp; s++) {
                pcg32 rng = pcg_seed(r->seed * 0x9E3779B97F4A7C15ULL + pixel, s);
                float fx = (x + uniform(&rng)) / r->width, fy = (y + uniform(&rng)) / r->height;
                vec3 d = normalize(add(r->forward, add(scale(r->right, 2 * fx - 1), scale(r->up, 1 - 2 * fy))));
                lacuna_ray ray;
                lacuna_ray_init(&ray);
                ray.origin[0] = r->eye.x, ray.origin[1] = r->eye.y, ray.origin[2] = r->eye.z;
                ray.direction[0] = d.x, ray.direction[1] = d.y, ray.direction[2] = d.z;
                vec3 l = trace(r, ray, &rng);
                if (isfinite(l.x + l.y + l.z)) sum = add(sum, l);
            }
            float *p = r->pixels + 3 * pixel;
            p[0] = sum.x / r->spp, p[1] = sum.y / r->spp, p[2] = sum.z / r->spp;
        }
    }
}

static void write_pfm(const char *path, const float *pixels, uint32_t w, uint32_t h) {
    FILE *f = fopen(path, "wb");
    if (!f) {
        fprintf(stderr, "cannot write %s\n", path);
        exit(1);
    }
    fprintf(f, "PF\n%u %u\n-1.0\n", w, h);
    for (uint32_t y = h; y-- > 0;) fwrite(pixels + 3 * (size_t)y * w, sizeof(float), 3 * (size_t)w, f);
    fclose(f);
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: host_pathtracer SCENE OUT.pfm [WIDTH HEIGHT SPP SEED MAX_DEPTH THREADS]\n");
        return 2;
    }
    renderer r;
    memset(&r, 0, sizeof r);
    r.width = argc > 3 ? (uint32_t)atoi(argv[3]) : 128;
    r.height = argc > 4 ? (uint32_t)atoi(argv[4]) : 128;
    r.spp = argc > 5 ? (uint32_t)atoi(argv[5]) : 16;
    r.seed = argc > 6 ? (uint64_t)atoll(argv[6]) : 1;
    r.max_depth = argc > 7 ? (uint32_t)atoi(argv[7]) : 8;
    int threads = argc > 8 ? atoi(argv[8]) : 2;
    if (r.width == 0 || r.height == 0 || r.spp == 0 || threads < 1 || threads > 256) {
        fprintf(stderr, "width, height, spp and threads must be positive\n");
        return 2;
    }

    lacuna_context *ctx = NULL;
    TRY(lacuna_context_new(&ctx));
    lacuna_scene_builder *builder = NULL;
    const char *name = argv[1];
    if (strcmp(name, "two-rooms") == 0 || strcmp(name, "corridor") == 0)
        TRY(lacuna_scene_builder_new_builtin(ctx, name, &builder));
    else
        TRY(lacuna_scene_builder_new_from_file(ctx, name, &builder));
    lacuna_scene *scene = NULL;
    TRY(lacuna_scene_builder_build(builder, &scene));
    lacuna_light_sampler *lights = NULL;
    TRY(lacuna_light_sampler_new(scene, LACUNA_TRIANGLE_STRATEGY_AREA,
                                 LACUNA_ENVIRONMENT_STRATEGY_AUTO, &lights));
    lacuna_light_sampler_info info;
    TRY(lacuna_light_sampler_get_info(lights, &info));
    lacuna_camera cam;
    TRY(lacuna_scene_get_camera(scene, &cam));
    if (cam.lens_radius > 0) fprintf(stderr, "note: the thin lens is ignored (pinhole)\n");

    r.scene = scene;
    r.lights = lights;
    r.environment_light = info.environment_light;
    r.eye = vload(cam.eye);
    r.forward = normalize(sub(vload(cam.target), r.eye));
    vec3 right = normalize(cross(r.forward, vload(cam.up)));
    vec3 up = cross(right, r.forward);
    float t = tanf(cam.vfov_degrees * PI_F / 360.0f);
    r.right = scale(right, t * (float)r.width / (float)r.height);
    r.up = scale(up, t);
    r.pixels = calloc(3 * (size_t)r.width * r.height, sizeof(float));
    if (!r.pixels) return 1;
    pthread_mutex_init(&r.lock, NULL);

    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    pthread_t pool[256];
    for (int i = 0; i < threads; i++) pthread_create(&pool[i], NULL, render_rows, &r);
    for (int i = 0; i < threads; i++) pthread_join(pool[i], NULL);
    clock_gettime(CLOCK_MONOTONIC, &t1);
    fprintf(stderr, "render_seconds %.6f\n", (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec));

    write_pfm(argv[2], r.pixels, r.width, r.height);
    pthread_mutex_destroy(&r.lock);
    free(r.pixels);
    lacuna_light_sampler_release(lights);
    lacuna_scene_release(scene);
    lacuna_context_release(ctx);
    return 0;
}
