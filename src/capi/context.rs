//! `lacuna_context`: thread count, memory budget and error callback shared by everything made
//! from it.

use std::ffi::{c_char, c_void};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use super::boundary::{self, lacuna_status, CapiError, CapiResult};
use super::buffer::{arc_into_handle, arc_release, arc_retain, out_ptr, write_out};
use crate::workers::WorkerPool;

/// Called on the failing thread, synchronously, for every failed call on an object made from
/// the context: `user_data` as registered, the status and the message (valid during the call
/// only). It may run on any thread that uses the context's objects, so it must be thread-safe;
/// it must not unwind (throw) into Lacuna or call back into the failing object.
pub type lacuna_error_callback = Option<
    unsafe extern "C" fn(user_data: *mut c_void, status: lacuna_status, message: *const c_char),
>;

#[derive(Clone, Copy)]
struct ErrorCallback {
    function: unsafe extern "C" fn(*mut c_void, lacuna_status, *const c_char),
    user_data: usize,
}

/// The root object: settings shared by the scenes and jobs made from it.
///
/// Refcounted (`lacuna_context_retain`/`lacuna_context_release`); every object made from a
/// context keeps it alive. Thread-safe: every function taking a context may be called from any
/// thread at any time.
pub struct lacuna_context {
    threads: AtomicUsize,
    memory_budget: AtomicU64,
    error_callback: Mutex<Option<ErrorCallback>>,
    /// Worker threads of batched ray queries, made on first use.
    pool: Mutex<Option<Arc<WorkerPool>>>,
}

/// The default memory budget: 8 GiB.
pub const LACUNA_DEFAULT_MEMORY_BUDGET: u64 = 8_589_934_592;

/// Most worker threads a context or a job accepts.
pub const LACUNA_MAX_THREADS: u32 = 4096;

// The C API's limits are the library's (src/limits.rs); cbindgen needs literals.
const _: () = assert!(LACUNA_DEFAULT_MEMORY_BUDGET == crate::limits::DEFAULT_MEMORY_BUDGET);
const _: () = assert!(LACUNA_MAX_THREADS == crate::limits::MAX_THREADS);

/// The C API's one way to lock: a lock whose holder panicked stays usable, so a panic caught
/// at the boundary does not turn every later call on the handle into another panic.
pub(super) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl lacuna_context {
    /// Worker threads for renders and batched queries; `None` is all cores.
    pub(crate) fn threads(&self) -> Option<usize> {
        match self.threads.load(Ordering::Relaxed) {
            0 => None,
            n => Some(n),
        }
    }

    /// The budget set, but never more than the machine's physical memory.
    pub(crate) fn memory_budget(&self) -> u64 {
        crate::limits::effective_memory_budget(self.memory_budget.load(Ordering::Relaxed))
    }

    /// The worker pool of batched queries.
    pub(crate) fn pool(&self) -> CapiResult<Arc<WorkerPool>> {
        let mut slot = lock(&self.pool);
        if let Some(p) = slot.as_ref() {
            return Ok(p.clone());
        }
        let pool = WorkerPool::new(self.threads(), Some("lacuna-query")).map_err(|e| {
            CapiError::new(
                lacuna_status::OutOfMemory,
                format!("cannot start worker threads: {e}"),
            )
        })?;
        let pool = Arc::new(pool);
        *slot = Some(pool.clone());
        Ok(pool)
    }

    /// Tells the error callback, if any, about a failure.
    pub(crate) fn report(&self, status: lacuna_status, message: &std::ffi::CStr) {
        let cb = *lock(&self.error_callback);
        if let Some(cb) = cb {
            // SAFETY: the host registered this function with this user data and promised it
            // is callable from any thread; the message outlives the call.
            unsafe { (cb.function)(cb.user_data as *mut c_void, status, message.as_ptr()) }
        }
    }
}

/// Creates a context (reference count 1) with all cores as worker threads, the default memory
/// budget and no error callback. Writes it to `*out_context` on success. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_context_new(
    out_context: *mut *mut lacuna_context,
) -> lacuna_status {
    boundary::status("lacuna_context_new", |_| {
        let out = out_ptr(out_context, "out_context")?;
        let ctx = arc_into_handle(lacuna_context {
            threads: AtomicUsize::new(0),
            memory_budget: AtomicU64::new(LACUNA_DEFAULT_MEMORY_BUDGET),
            error_callback: Mutex::new(None),
            pool: Mutex::new(None),
        });
        // SAFETY: `out` was checked non-NULL; the caller promises it is writable.
        unsafe { write_out(out, ctx) };
        Ok(())
    })
}

/// Adds a reference to `context`. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_context_retain(context: *const lacuna_context) {
    boundary::value("lacuna_context_retain", (), |_| {
        // SAFETY: the caller passes NULL or a live context.
        unsafe { arc_retain(context) };
        Ok(())
    })
}

/// Drops a reference to `context`; the last reference destroys it (objects made from it keep
/// it alive). NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_context_release(context: *const lacuna_context) {
    boundary::value("lacuna_context_release", (), |_| {
        // SAFETY: the caller passes NULL or a live context and gives up one reference.
        unsafe { arc_release(context) };
        Ok(())
    })
}

/// Sets the number of worker threads of renders (unless a job sets its own) and batched ray
/// queries started afterwards; 0 means all cores. At most `LACUNA_MAX_THREADS`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_context_set_thread_count(
    context: *const lacuna_context,
    thread_count: u32,
) -> lacuna_status {
    boundary::status("lacuna_context_set_thread_count", |call| {
        // SAFETY: NULL or a live context.
        let ctx = unsafe { super::buffer::arg(context, "context") }?;
        call.context(ctx);
        if thread_count > LACUNA_MAX_THREADS {
            return Err(CapiError::range(format!(
                "thread_count {thread_count} exceeds {LACUNA_MAX_THREADS}"
            )));
        }
        let old = ctx.threads.swap(thread_count as usize, Ordering::Relaxed);
        if old != thread_count as usize {
            *lock(&ctx.pool) = None;
        }
        Ok(())
    })
}

/// Reads the thread count set with `lacuna_context_set_thread_count` (0 = all cores).
/// Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_context_get_thread_count(
    context: *const lacuna_context,
    out_thread_count: *mut u32,
) -> lacuna_status {
    boundary::status("lacuna_context_get_thread_count", |call| {
        // SAFETY: NULL or a live context.
        let ctx = unsafe { super::buffer::arg(context, "context") }?;
        call.context(ctx);
        let out = out_ptr(out_thread_count, "out_thread_count")?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, ctx.threads.load(Ordering::Relaxed) as u32) };
        Ok(())
    })
}

/// Sets the memory budget in bytes: a render whose film would need more fails with
/// `LACUNA_STATUS_OVER_BUDGET` before allocating. Must be > 0. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_context_set_memory_budget(
    context: *const lacuna_context,
    bytes: u64,
) -> lacuna_status {
    boundary::status("lacuna_context_set_memory_budget", |call| {
        // SAFETY: NULL or a live context.
        let ctx = unsafe { super::buffer::arg(context, "context") }?;
        call.context(ctx);
        if bytes == 0 {
            return Err(CapiError::invalid("memory budget 0 bytes must be positive"));
        }
        ctx.memory_budget.store(bytes, Ordering::Relaxed);
        Ok(())
    })
}

/// Registers (or, with a NULL `callback`, removes) the error callback of the context; see
/// `lacuna_error_callback` for when it runs. `user_data` is passed back untouched.
/// Thread-safe; calls already failing may still report to the previous callback.
#[no_mangle]
pub unsafe extern "C" fn lacuna_context_set_error_callback(
    context: *const lacuna_context,
    callback: lacuna_error_callback,
    user_data: *mut c_void,
) -> lacuna_status {
    boundary::status("lacuna_context_set_error_callback", |call| {
        // SAFETY: NULL or a live context.
        let ctx = unsafe { super::buffer::arg(context, "context") }?;
        call.context(ctx);
        *lock(&ctx.error_callback) = callback.map(|function| ErrorCallback {
            function,
            user_data: user_data as usize,
        });
        Ok(())
    })
}
