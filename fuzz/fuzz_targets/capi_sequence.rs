//! The C API under random sequences of valid and invalid calls: each input byte picks a call,
//! the next bytes its arguments (handles from a small table, NULL, values inside and outside
//! the limits, NaN). Handles are only ever passed live or NULL, as the header's contract
//! requires, except scene builders, which are also passed after being built or freed: that
//! misuse must be caught (`LACUNA_STATUS_INVALID_OPERATION`). Any `LACUNA_STATUS_PANIC` is a
//! crash: a panic inside Lacuna is a bug even when the boundary catches it.
#![no_main]

use std::ffi::{CStr, CString};
use std::ptr::{null, null_mut};

use lacuna::capi::*;
use libfuzzer_sys::fuzz_target;

/// Argument bytes of a call, read front to back; zeros once exhausted.
struct Args<'a>(&'a [u8]);

impl Args<'_> {
    fn byte(&mut self) -> u8 {
        let (&b, rest) = self.0.split_first().unwrap_or((&0, &[]));
        self.0 = rest;
        b
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.byte(), self.byte(), self.byte(), self.byte()])
    }
    /// A float: mostly small, sometimes extreme or not finite.
    fn f32(&mut self) -> f32 {
        match self.byte() {
            0 => f32::NAN,
            1 => f32::INFINITY,
            2 => 1e30,
            3 => -1e-30,
            4 => f32::from_bits(self.u32()),
            b => (b as f32 - 128.0) / 16.0,
        }
    }
    fn vec3(&mut self) -> lacuna_vec3 {
        lacuna_vec3 {
            x: self.f32(),
            y: self.f32(),
            z: self.f32(),
        }
    }
    /// A count or size: mostly small, sometimes at or past a limit.
    fn count(&mut self) -> u32 {
        match self.byte() {
            0 => 0,
            1 => u32::MAX,
            2 => 1 << 16,
            3 => 65537,
            4 => 1 << 28,
            5 => (1 << 28) + 1,
            6 => 1025,
            7 => 4097,
            b => (b % 24) as u32 + 1,
        }
    }
    /// An index into a table of `len` handles, or `None` (NULL) for one value in eight.
    fn pick(&mut self, len: usize) -> Option<usize> {
        let b = self.byte() as usize;
        (len > 0 && b % 8 != 0).then(|| b % len)
    }
}

#[derive(Default)]
struct Handles {
    contexts: Vec<*mut lacuna_context>,
    builders: Vec<*mut lacuna_scene_builder>,
    /// Builders already built or freed: passed again to check the misuse is caught.
    stale_builders: Vec<*mut lacuna_scene_builder>,
    scenes: Vec<*mut lacuna_scene>,
    jobs: Vec<*mut lacuna_render_job>,
    films: Vec<*mut lacuna_film>,
}

fn pick_ptr<T>(a: &mut Args, list: &[*mut T]) -> *mut T {
    a.pick(list.len()).map_or(null_mut(), |i| list[i])
}

fn check(status: lacuna_status) {
    if status == lacuna_status::Panic {
        // SAFETY: a valid C string for the calling thread.
        let message = unsafe { CStr::from_ptr(lacuna_last_error_message()) };
        panic!("LACUNA_STATUS_PANIC: {}", message.to_string_lossy());
    }
}

/// `path_skeleton` at a coarse grid: at its default voxel budget the guide build is a full
/// empty-space analysis (about 2e10 instructions, 1.4 s natively and over the 10 s limit in
/// the instrumented build: `fuzz/known/capi_sequence-timeout-1`), which is cost, not a hang.
const INTEGRATORS: &[&CStr] = &[
    c"path",
    c"bdpt",
    c"path_skeleton:resolution=24",
    c"env_direct",
    c"path:max_depth=2",
    c"bdpt:max_depth=100000",
    c"nope",
    c"",
];

const MAX_HANDLES: usize = 4;

unsafe fn step(h: &mut Handles, op: u8, a: &mut Args) {
    unsafe {
        match op % 20 {
            0 if h.contexts.len() < MAX_HANDLES => {
                let mut c = null_mut();
                check(lacuna_context_new(&mut c));
                if !c.is_null() {
                    // Keep renders cheap: one worker thread, a 64 MiB budget.
                    check(lacuna_context_set_thread_count(c, 1));
                    check(lacuna_context_set_memory_budget(c, 64 << 20));
                    h.contexts.push(c);
                }
            }
            1 => {
                let c = pick_ptr(a, &h.contexts);
                let n = a.count();
                // Thread counts are capped: the sequence must stay cheap.
                check(lacuna_context_set_thread_count(
                    c,
                    if n > 4 && n < 4097 { 2 } else { n },
                ));
            }
            2 => {
                let c = pick_ptr(a, &h.contexts);
                let bytes = match a.byte() % 4 {
                    0 => 0,
                    1 => 1 << 20,
                    2 => u64::MAX,
                    _ => 64 << 20,
                };
                check(lacuna_context_set_memory_budget(c, bytes));
                // Above physical memory the budget is clamped, never more than ours allows.
                if !c.is_null() {
                    check(lacuna_context_set_memory_budget(c, 64 << 20));
                }
            }
            3 if h.builders.len() < MAX_HANDLES => {
                let c = pick_ptr(a, &h.contexts);
                let mut b = null_mut();
                let s = if a.byte() % 4 == 0 {
                    let path =
                        CString::new(lacuna_fuzz::scratch().join("tri.obj").to_str().unwrap())
                            .unwrap();
                    // An OBJ given as a scene file: a parse error.
                    lacuna_scene_builder_new_from_file(c, path.as_ptr(), &mut b)
                } else {
                    lacuna_scene_builder_new(c, &mut b)
                };
                check(s);
                if !b.is_null() {
                    h.builders.push(b);
                }
            }
            4 => {
                let b = builder_arg(h, a);
                let mut index = 0;
                check(lacuna_scene_builder_add_material(
                    b,
                    a.byte() as u32 % 8,
                    &mut index,
                ));
            }
            5 => {
                let b = builder_arg(h, a);
                let mut mesh = null_mut();
                check(lacuna_mesh_new(&mut mesh));
                let vertices = (a.byte() % 8) as usize;
                let positions: Vec<f32> = (0..vertices * 3).map(|_| a.f32()).collect();
                check(lacuna_mesh_set_positions(
                    mesh,
                    if vertices == 0 && a.byte() % 2 == 0 {
                        null()
                    } else {
                        positions.as_ptr()
                    },
                    0,
                    vertices,
                ));
                let triangles = (a.byte() % 4) as usize;
                let indices: Vec<u32> =
                    (0..triangles * 3).map(|_| (a.byte() % 10) as u32).collect();
                check(lacuna_mesh_set_indices(
                    mesh,
                    indices.as_ptr(),
                    0,
                    triangles,
                ));
                check(lacuna_mesh_set_material(mesh, a.byte() as u32 % 6));
                let mut index = 0;
                check(lacuna_scene_builder_add_mesh(b, mesh, &mut index));
                lacuna_mesh_free(mesh);
            }
            6 => {
                let b = builder_arg(h, a);
                let p = a.vec3();
                let i = a.vec3();
                check(lacuna_scene_builder_add_point_light(
                    b,
                    p,
                    lacuna_rgb {
                        r: i.x,
                        g: i.y,
                        b: i.z,
                    },
                ));
            }
            7 => {
                let b = builder_arg(h, a);
                check(lacuna_scene_builder_set_camera(
                    b,
                    a.vec3(),
                    a.vec3(),
                    a.vec3(),
                    a.f32(),
                ));
            }
            8 => {
                let b = builder_arg(h, a);
                let mut scene = null_mut();
                let s = lacuna_scene_builder_build(b, &mut scene);
                check(s);
                retire_builder(h, b);
                if !scene.is_null() {
                    h.scenes.push(scene);
                }
            }
            9 => {
                let b = builder_arg(h, a);
                lacuna_scene_builder_free(b);
                retire_builder(h, b);
            }
            10 => {
                let b = builder_arg(h, a);
                let name = match a.byte() % 3 {
                    0 => "tri.obj",
                    1 => "tex.png",
                    _ => "missing.obj",
                };
                let path =
                    CString::new(lacuna_fuzz::scratch().join(name).to_str().unwrap()).unwrap();
                let xf: Vec<f32> = (0..16).map(|_| a.f32()).collect();
                let transform = if a.byte() % 2 == 0 {
                    null()
                } else {
                    xf.as_ptr()
                };
                let mut count = 0;
                check(lacuna_scene_builder_load_obj(
                    b,
                    path.as_ptr(),
                    transform,
                    &mut count,
                ));
            }
            11 => {
                let s = pick_ptr(a, &h.scenes);
                let o = a.vec3();
                let d = a.vec3();
                let ray = lacuna_ray {
                    origin: [o.x, o.y, o.z],
                    tmax: a.f32(),
                    direction: [d.x, d.y, d.z],
                    flags: a.byte() as u32,
                };
                let mut hit = std::mem::zeroed();
                check(lacuna_scene_intersect(s, &ray, &mut hit));
            }
            12 if h.jobs.len() < MAX_HANDLES => {
                let s = pick_ptr(a, &h.scenes);
                let name = INTEGRATORS[a.byte() as usize % INTEGRATORS.len()];
                let name = if a.byte() % 16 == 0 {
                    null()
                } else {
                    name.as_ptr()
                };
                let mut job = null_mut();
                check(lacuna_render_job_new(s, name, &mut job));
                if !job.is_null() {
                    check(lacuna_render_job_set_resolution(job, 8, 8));
                    check(lacuna_render_job_set_samples_per_pixel(job, 1));
                    h.jobs.push(job);
                }
            }
            13 => {
                let j = pick_ptr(a, &h.jobs);
                let (w, hh) = (a.count(), a.count());
                check(lacuna_render_job_set_resolution(j, w, hh));
                let spp = a.count();
                check(lacuna_render_job_set_samples_per_pixel(j, spp));
                // Keep the run cheap whatever was accepted.
                if !j.is_null() && (w as u64 * hh as u64 * spp as u64 > 4096 || spp > 4) {
                    check(lacuna_render_job_set_resolution(j, 8, 8));
                    check(lacuna_render_job_set_samples_per_pixel(j, 1));
                }
            }
            14 => {
                let j = pick_ptr(a, &h.jobs);
                let d = a.count();
                check(lacuna_render_job_set_max_depth(j, d));
                check(lacuna_render_job_set_light_paths(j, a.count()));
                check(lacuna_render_job_set_thread_count(j, a.count().min(2)));
                if !j.is_null() {
                    // Deep paths are allowed but slow: keep the run short.
                    check(lacuna_render_job_set_max_depth(j, d.min(4)));
                    check(lacuna_render_job_set_light_paths(j, 64));
                }
            }
            15 if h.films.len() < MAX_HANDLES => {
                let j = pick_ptr(a, &h.jobs);
                let mut film = null_mut();
                check(lacuna_render_job_run(j, &mut film));
                if !film.is_null() {
                    h.films.push(film);
                }
            }
            16 => {
                let f = pick_ptr(a, &h.films);
                let (mut w, mut hh) = (0, 0);
                check(lacuna_film_get_size(f, &mut w, &mut hh));
                // A destination of the size the input claims (refused when it is not the film's).
                let (dw, dh) = ((a.byte() % 12) as usize, (a.byte() % 12) as usize);
                let mut dst = vec![0f32; dw * dh * 4];
                check(lacuna_film_read(
                    f,
                    a.byte() as u32 % 8,
                    dst.as_mut_ptr(),
                    dw,
                    dh,
                    0,
                    0,
                ));
                if dst.iter().any(|v| !v.is_finite()) {
                    panic!("a film channel holds NaN or Inf");
                }
            }
            17 => release_one(h, a),
            18 => {
                let s = pick_ptr(a, &h.scenes);
                let mut analysis = null_mut();
                check(lacuna_analysis_build(
                    s,
                    a.count().min(16),
                    a.f32(),
                    a.byte() as u64 * (1 << 16),
                    a.byte() as u32,
                    None,
                    null_mut(),
                    &mut analysis,
                ));
                lacuna_analysis_release(analysis);
            }
            _ => {}
        }
    }
}

/// A builder argument: live, stale (already built or freed) or NULL.
fn builder_arg(h: &Handles, a: &mut Args) -> *mut lacuna_scene_builder {
    if a.byte() % 4 == 0 && !h.stale_builders.is_empty() {
        let i = a.byte() as usize % h.stale_builders.len();
        return h.stale_builders[i];
    }
    pick_ptr(a, &h.builders)
}

fn retire_builder(h: &mut Handles, b: *mut lacuna_scene_builder) {
    if let Some(i) = h.builders.iter().position(|&x| x == b) {
        h.builders.swap_remove(i);
        h.stale_builders.push(b);
    }
}

unsafe fn release_one(h: &mut Handles, a: &mut Args) {
    unsafe {
        match a.byte() % 4 {
            0 => {
                if let Some(i) = a.pick(h.films.len()) {
                    lacuna_film_release(h.films.swap_remove(i));
                }
            }
            1 => {
                if let Some(i) = a.pick(h.jobs.len()) {
                    lacuna_render_job_free(h.jobs.swap_remove(i));
                }
            }
            2 => {
                if let Some(i) = a.pick(h.scenes.len()) {
                    lacuna_scene_release(h.scenes.swap_remove(i));
                }
            }
            _ => {
                if let Some(i) = a.pick(h.contexts.len()) {
                    lacuna_context_release(h.contexts.swap_remove(i));
                }
            }
        }
    }
}

fuzz_target!(init: lacuna_fuzz::init_panic_policy(), |data: &[u8]| {
    let mut h = Handles::default();
    let mut a = Args(data);
    // At most 64 calls per input, so that each input stays quick.
    for _ in 0..64 {
        if a.0.is_empty() {
            break;
        }
        let op = a.byte();
        unsafe { step(&mut h, op, &mut a) };
    }
    unsafe {
        for f in h.films.drain(..) {
            lacuna_film_release(f);
        }
        for j in h.jobs.drain(..) {
            lacuna_render_job_free(j);
        }
        for s in h.scenes.drain(..) {
            lacuna_scene_release(s);
        }
        for b in h.builders.drain(..) {
            lacuna_scene_builder_free(b);
        }
        for c in h.contexts.drain(..) {
            lacuna_context_release(c);
        }
    }
});
