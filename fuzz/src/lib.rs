//! Shared parts of the fuzz targets: a scratch directory of fixed side files, a panic policy,
//! and an allocator that turns any single allocation over [`ALLOCATION_LIMIT`] into a crash
//! (a loader that allocates what a file's header claims before checking it is a bug even when
//! the machine happens to have the memory).

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Largest single allocation the targets allow; the loaders run with [`FUZZ_BUDGET`].
pub const ALLOCATION_LIMIT: usize = 1 << 30;

/// The memory budget the targets give the loaders.
pub const FUZZ_BUDGET: u64 = 256 << 20;

pub struct GuardedAllocator;

// SAFETY: forwards to the system allocator unchanged; only refuses (by aborting) oversize
// requests, which never return memory.
unsafe impl GlobalAlloc for GuardedAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        check(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

fn check(size: usize) {
    if size > ALLOCATION_LIMIT {
        // No formatting here: we are inside the allocator.
        let _ = std::io::Write::write_all(
            &mut std::io::stderr(),
            b"lacuna-fuzz: single allocation over the 1 GiB limit\n",
        );
        std::process::abort();
    }
}

#[global_allocator]
static ALLOCATOR: GuardedAllocator = GuardedAllocator;

/// Panics abort (libFuzzer records a crash), except inside tobj, whose panics on malformed
/// input `lacuna::scene::load_obj` catches and reports as parse errors by design.
pub fn init_panic_policy() {
    std::panic::set_hook(Box::new(|info| {
        let in_tobj = info.location().is_some_and(|l| l.file().contains("/tobj-"));
        if in_tobj {
            return;
        }
        eprintln!("{info}");
        std::process::abort();
    }));
}

/// This process's scratch directory, with side files the inputs may name: `tri.obj`,
/// `tri.mtl`, `tex.png`, `env.hdr` (4x2).
pub fn scratch() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let base = if Path::new("/dev/shm").is_dir() {
            PathBuf::from("/dev/shm")
        } else {
            std::env::temp_dir()
        };
        let dir = base.join(format!("lacuna-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("scratch directory");
        std::fs::write(
            dir.join("tri.obj"),
            "mtllib tri.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl red\nf 1/1 2/2 3/3\n",
        )
        .unwrap();
        std::fs::write(
            dir.join("tri.mtl"),
            "newmtl red\nKd 0.8 0.1 0.1\nmap_Kd tex.png\nnewmtl light\nKe 10 10 10\n",
        )
        .unwrap();
        image::RgbImage::from_pixel(2, 2, image::Rgb([200, 100, 50]))
            .save(dir.join("tex.png"))
            .unwrap();
        let mut hdr = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 4\n".to_vec();
        hdr.extend(std::iter::repeat_n([128u8, 128, 128, 129], 8).flatten());
        std::fs::write(dir.join("env.hdr"), hdr).unwrap();
        dir
    })
}

/// Writes `data` to `name` in the scratch directory and returns its path.
pub fn write(name: &str, data: &[u8]) -> PathBuf {
    let path = scratch().join(name);
    std::fs::write(&path, data).expect("scratch file");
    path
}
