//! Worker thread pools whose threads have exited when the pool is dropped.
//!
//! A dropped `rayon::ThreadPool` only asks its threads to stop; they finish exiting some time
//! later, on their own. A host that releases its last Lacuna object and returns from `main`
//! can then exit while those threads are still tearing down. That is harmless for the host, but
//! LeakSanitizer (and other tools that stop every thread at exit) can deadlock when a thread
//! vanishes under them: CI saw exactly this in the C++ wrapper test under AddressSanitizer. So
//! every pool Lacuna makes spawns its own threads and joins them on drop.

use std::cell::Cell;
use std::ops::Deref;
use std::thread::JoinHandle;

thread_local! {
    /// Whether a panic on this thread is reported by a caller instead of printed: true inside
    /// a C API call (the boundary turns the panic into `LACUNA_STATUS_PANIC` and an error
    /// message; the host's stderr is not Lacuna's) and on the workers of pools made there.
    static PANICS_REPORTED_BY_CALLER: Cell<bool> = const { Cell::new(false) };
}

/// See [`PANICS_REPORTED_BY_CALLER`].
pub(crate) fn panics_reported_by_caller() -> bool {
    PANICS_REPORTED_BY_CALLER.with(Cell::get)
}

/// Sets the calling thread's flag (see [`PANICS_REPORTED_BY_CALLER`]); returns the old value.
pub(crate) fn set_panics_reported_by_caller(on: bool) -> bool {
    PANICS_REPORTED_BY_CALLER.with(|flag| flag.replace(on))
}

/// A rayon pool that joins its worker threads when dropped (see the module doc).
pub struct WorkerPool {
    /// Always `Some` until `drop` takes it, so that the pool is gone before the joins.
    pool: Option<rayon::ThreadPool>,
    threads: Vec<JoinHandle<()>>,
}

impl WorkerPool {
    /// A pool of `threads` workers (`None`: one per core), named `NAME-INDEX` when `name` is
    /// given (names show in debuggers and profilers).
    pub fn new(
        threads: Option<usize>,
        name: Option<&str>,
    ) -> Result<WorkerPool, rayon::ThreadPoolBuildError> {
        let mut handles = Vec::new();
        // Workers of a pool made inside a C API call panic as quietly as the call itself.
        let quiet = panics_reported_by_caller();
        let mut builder = rayon::ThreadPoolBuilder::new().num_threads(threads.unwrap_or(0));
        if let Some(name) = name {
            let name = name.to_string();
            builder = builder.thread_name(move |i| format!("{name}-{i}"));
        }
        let pool = builder
            .spawn_handler(|worker| {
                let mut thread = std::thread::Builder::new();
                if let Some(name) = worker.name() {
                    thread = thread.name(name.to_string());
                }
                if let Some(size) = worker.stack_size() {
                    thread = thread.stack_size(size);
                }
                handles.push(thread.spawn(move || {
                    set_panics_reported_by_caller(quiet);
                    worker.run()
                })?);
                Ok(())
            })
            .build()?;
        Ok(WorkerPool {
            pool: Some(pool),
            threads: handles,
        })
    }
}

impl Deref for WorkerPool {
    type Target = rayon::ThreadPool;

    fn deref(&self) -> &rayon::ThreadPool {
        self.pool.as_ref().expect("the pool lives until drop")
    }
}

impl Drop for WorkerPool {
    fn drop(&mut self) {
        let Some(pool) = self.pool.take() else {
            return;
        };
        // A worker dropping its own pool would wait for itself: let the threads exit alone.
        if pool.current_thread_index().is_some() {
            return;
        }
        drop(pool);
        for thread in self.threads.drain(..) {
            // A worker that panicked has already been reported by rayon's handler (or has
            // aborted the process); there is nothing more to do with its result here.
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;

    /// After the drop, every worker thread has finished: a value each worker holds a clone
    /// of (through a thread-local destructor) is back to one owner.
    #[test]
    fn drop_joins_every_worker() {
        for threads in [1, 2, 5] {
            let pool = WorkerPool::new(Some(threads), Some("lacuna-test")).unwrap();
            assert_eq!(pool.current_num_threads(), threads);
            let names = Arc::new(AtomicUsize::new(0));
            let marker = Arc::new(());
            thread_local! {
                static HELD: std::cell::RefCell<Option<Arc<()>>> = const { std::cell::RefCell::new(None) };
            }
            pool.broadcast(|_| {
                HELD.with(|h| *h.borrow_mut() = Some(marker.clone()));
                let name = std::thread::current().name().map(str::to_string);
                if name.is_some_and(|n| n.starts_with("lacuna-test-")) {
                    names.fetch_add(1, Ordering::Relaxed);
                }
            });
            assert_eq!(names.load(Ordering::Relaxed), threads);
            assert_eq!(Arc::strong_count(&marker), threads + 1);
            drop(pool);
            // Thread-local destructors run before a thread counts as joined.
            assert_eq!(Arc::strong_count(&marker), 1);
        }
    }

    #[test]
    fn install_runs_on_the_pool() {
        let pool = WorkerPool::new(Some(3), None).unwrap();
        assert_eq!(pool.install(rayon::current_num_threads), 3);
    }
}
