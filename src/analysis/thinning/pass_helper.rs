//! The helper thread of a collapse run: a second pool thread that shares the per-brick passes
//! of [`Thinning::run`](super::Thinning::run) with the calling thread, handed each pass through
//! one atomic state word rather than a rayon fork/join per pass.
//!
//! # Why `unsafe`
//!
//! A pass is a closure borrowing the collapse's state for the duration of the pass only, but
//! the helper is a detached rayon task that outlives every pass, so the closure cannot be moved
//! to it with a lifetime the compiler can check. [`PassHelper`] stores the borrowed closure
//! with its lifetime erased in an `UnsafeCell` and guarantees by the protocol of its `state`
//! word that the helper reads it only while the pass that posted it is running, and that the
//! pass does not return (or unwind) before the helper is done with it. Hence the two `unsafe`
//! blocks (the erasure and the reads and writes of the cell) and `unsafe impl Sync`; each has
//! its `SAFETY` argument beside it. Everything else (the claiming of chunks, the back-off) is
//! safe code over atomics.

use std::cell::UnsafeCell;
use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::sync::atomic::Ordering::{Acquire, Relaxed, Release};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64};
use std::sync::{Arc, Mutex};

/// States of [`PassHelper::state`].
const IDLE: u32 = 0;
const POSTED: u32 = 1;
const TAKEN: u32 = 2;
const DONE: u32 = 3;
const PANICKED: u32 = 4;
const SHUT_DOWN: u32 = 5;

/// The helper thread of a [`Thinning::run`](super::Thinning::run): one pool thread that joins the collapse at the run's
/// first pass worth sharing, stays to the run's end and takes part in every split pass, instead of
/// a rayon fork/join per pass. A pass follows some microseconds of sequential list work, after
/// which a rayon worker has gone to sleep: waking it (an inter-processor interrupt on this KVM
/// guest) cost about 10 µs per pass at the door's 234, more than half of a typical pass
/// (BENCHMARKS.md). The helper instead polls (spin, then yield) between passes.
///
/// Never a hang: the calling thread never waits for work the helper has not taken. A pass is
/// split into chunks that the caller claims from the front and the helper from the back of the
/// list ([`claim`]); the caller, once the list is exhausted, withdraws the job if the helper has
/// not taken it (then the caller did everything) and otherwise waits only for the chunks the
/// helper is running, whose panics are caught and passed on to the caller. The helper returns
/// when the run ends (also on a panic of the caller: [`ShutDownOnDrop`]); with one pool thread
/// there is no helper.
pub(super) struct PassHelper {
    /// IDLE (no job), POSTED (a job for the helper), TAKEN (the helper runs it), DONE or
    /// PANICKED (it finished), SHUT_DOWN (the run is over).
    state: AtomicU32,
    /// The posted job, with its lifetime erased; read by the helper only between taking it
    /// (POSTED -> TAKEN) and DONE/PANICKED, written by the caller only when IDLE.
    job: UnsafeCell<Option<&'static (dyn Fn() + Sync)>>,
    /// The thread that runs the collapse: if the pool ever hands the helper's task to it
    /// (while it waits inside some rayon call), the task returns at once instead of serving
    /// itself forever.
    pub(super) owner: Mutex<Option<std::thread::ThreadId>>,
    /// Whether the helper's task was spawned ([`PassHelper::start`]).
    started: AtomicBool,
}

// SAFETY: `job` is accessed under the protocol of `state` (see the field's comment), with
// one writer: only the thread running the collapse calls `run_pair`, one pass at a time
// (checked there). The caller writes it only in IDLE, before the Release store of POSTED;
// the helper reads it only after its Acquire CAS POSTED -> TAKEN and before its Release store
// of DONE/PANICKED, and the caller does not write it again before reading DONE/PANICKED with
// Acquire (or withdrawing the job with a successful CAS POSTED -> IDLE, after which the
// helper cannot take it).
unsafe impl Sync for PassHelper {}

/// Polls: spins for up to [`SPIN`], then yields the core at each poll. Between two shared
/// passes lie the sequential list work (some tens of microseconds) and, late in a collapse,
/// runs of passes too small to share (hundreds of microseconds), so the helper normally spins
/// through them; a helper that yields hands its core to another task for a whole time slice
/// on a loaded machine, and misses the next passes (100 µs was tried: slower at 234). After
/// the spin, a wait (say, for a helper that was preempted mid-chunk) yields so as not to keep
/// the thread it waits for off the core.
struct BackOff {
    start: Option<std::time::Instant>,
    polls: u32,
    yielding: bool,
}

/// How long [`BackOff`] spins before it yields.
const SPIN: std::time::Duration = std::time::Duration::from_micros(1000);

impl BackOff {
    fn new() -> BackOff {
        BackOff {
            start: None,
            polls: 0,
            yielding: false,
        }
    }

    #[inline]
    fn wait(&mut self) {
        if self.yielding {
            std::thread::yield_now();
            return;
        }
        // The clock is read every 64 polls (a read costs some 20 ns).
        if self.polls % 64 == 0 {
            let now = std::time::Instant::now();
            self.yielding = now - *self.start.get_or_insert(now) > SPIN;
        }
        self.polls = self.polls.wrapping_add(1);
        std::hint::spin_loop();
    }
}

impl PassHelper {
    pub(super) fn new() -> PassHelper {
        PassHelper {
            state: AtomicU32::new(IDLE),
            job: UnsafeCell::new(None),
            owner: Mutex::new(None),
            started: AtomicBool::new(false),
        }
    }

    /// Spawns the helper's task (detached, see [`Thinning::run`](super::Thinning::run)) unless it already was.
    pub(super) fn start(self: &Arc<Self>) {
        if !self.started.swap(true, Relaxed) {
            let helper = Arc::clone(self);
            rayon::spawn(move || helper.serve());
        }
    }

    /// The helper's loop: runs posted jobs until the run shuts it down.
    ///
    /// Panics only inside the caught job: it runs as a detached rayon task, whose panic would
    /// abort the process.
    fn serve(&self) {
        let owner = *self.owner.lock().unwrap_or_else(|e| e.into_inner());
        if owner == Some(std::thread::current().id()) {
            return;
        }
        let mut back_off = BackOff::new();
        loop {
            match self.state.load(Acquire) {
                POSTED => {
                    if self
                        .state
                        .compare_exchange(POSTED, TAKEN, Acquire, Relaxed)
                        .is_ok()
                    {
                        // SAFETY: TAKEN, so the caller keeps the job alive and does not
                        // write `job` until it reads DONE or PANICKED (see `Sync for PassHelper`).
                        let Some(job) = (unsafe { *self.job.get() }) else {
                            // Unreachable: a job is written before every POSTED store.
                            self.state.store(PANICKED, Release);
                            continue;
                        };
                        let done = catch_unwind(AssertUnwindSafe(job)).is_ok();
                        self.state
                            .store(if done { DONE } else { PANICKED }, Release);
                        back_off = BackOff::new();
                    }
                }
                SHUT_DOWN => return,
                _ => back_off.wait(),
            }
        }
    }

    /// Runs `mine` on the calling thread while the helper (if it is serving) runs `helper`;
    /// returns when both are done. `mine` must itself finish the work the helper does not
    /// take (both claim from one list, see [`claim`]).
    ///
    /// Only the thread running the collapse calls it, one pass at a time (a pass's closure
    /// does not start another pass): the `Sync` argument rests on that single writer of
    /// `job`, so it is checked in release builds too (one load per pass).
    pub(super) fn run_pair(&self, helper: &(dyn Fn() + Sync), mine: impl FnOnce()) {
        assert_eq!(
            self.state.load(Relaxed),
            IDLE,
            "a thinning pass started inside another pass"
        );
        // SAFETY: only the lifetime is erased. The state is IDLE, so the helper does not read
        // `job`; it may read it from the POSTED store below until this function has seen
        // DONE/PANICKED or withdrawn the job, and this function returns (or unwinds, the
        // caller's panic being caught below) only after that, while `helper` is alive.
        unsafe {
            *self.job.get() = Some(std::mem::transmute::<
                &(dyn Fn() + Sync),
                &'static (dyn Fn() + Sync),
            >(helper));
        }
        self.state.store(POSTED, Release);
        let mine = catch_unwind(AssertUnwindSafe(mine));
        let mut helper_panicked = false;
        if self
            .state
            .compare_exchange(POSTED, IDLE, Relaxed, Relaxed)
            .is_err()
        {
            // Taken: the helper is running its last chunks (or found none left).
            let mut back_off = BackOff::new();
            loop {
                match self.state.load(Acquire) {
                    DONE => break,
                    PANICKED => {
                        helper_panicked = true;
                        break;
                    }
                    _ => back_off.wait(),
                }
            }
            self.state.store(IDLE, Relaxed);
        }
        // SAFETY: IDLE again (withdrawn, or DONE/PANICKED seen), so the helper does not read
        // `job`; clearing it leaves no dangling reference to `helper` behind.
        unsafe {
            *self.job.get() = None;
        }
        if let Err(panic) = mine {
            resume_unwind(panic);
        }
        assert!(
            !helper_panicked,
            "a thinning pass panicked on the helper thread"
        );
    }
}

/// Shuts the helper down when the run ends, also when the caller unwinds.
pub(super) struct ShutDownOnDrop<'d>(pub(super) &'d PassHelper);

impl Drop for ShutDownOnDrop<'_> {
    fn drop(&mut self) {
        self.0.state.store(SHUT_DOWN, Release);
    }
}

/// Claims the next chunk of a pass from the front (the caller) or the back (the helper) of the
/// unclaimed range `lo..hi` packed as lo | hi << 32: a quarter of what is left, at least
/// `min`. Each thread so works on a contiguous part of the (sorted) brick list, a slab of the
/// grid, and the two meet wherever the work balances.
pub(super) fn claim(range: &AtomicU64, min: u32, front: bool) -> Option<(usize, usize)> {
    let mut current = range.load(Relaxed);
    loop {
        let (lo, hi) = (current as u32, (current >> 32) as u32);
        if lo >= hi {
            return None;
        }
        let take = ((hi - lo) / 4).max(min).min(hi - lo);
        let (a, b) = if front {
            (lo, lo + take)
        } else {
            (hi - take, hi)
        };
        let next = if front {
            (lo + take) as u64 | (hi as u64) << 32
        } else {
            lo as u64 | ((hi - take) as u64) << 32
        };
        match range.compare_exchange_weak(current, next, Relaxed, Relaxed) {
            Ok(_) => return Some((a as usize, b as usize)),
            Err(now) => current = now,
        }
    }
}
