//! Wall-clock timings of the stages of a computation (the analysis pipeline, a guide's build,
//! an integrator's precomputation), reported to hosts and written into image metadata. Kept
//! at the bottom of the layers so that every stage can record them.

/// Wall-clock time of one stage.
#[derive(Clone, Debug, PartialEq)]
pub struct StageTime {
    pub stage: &'static str,
    pub seconds: f64,
}

/// Seconds of CPU time this thread has used: a cost measurement that time slices given to
/// other processes do not enter (wall time on a loaded machine does). A system call on Linux
/// (no vDSO path for this clock): time batches of work, not single short operations. Where the
/// clock is missing, a monotonic wall clock stands in.
pub fn thread_cpu_seconds() -> f64 {
    #[cfg(unix)]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid, writable timespec; clock_gettime writes it and nothing else.
        let status = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
        if status == 0 {
            return ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9;
        }
    }
    wall_seconds()
}

/// Seconds on a monotonic clock since the first call in this process.
fn wall_seconds() -> f64 {
    static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    START
        .get_or_init(std::time::Instant::now)
        .elapsed()
        .as_secs_f64()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thread_cpu_time_counts_work_and_not_sleep() {
        let start = thread_cpu_seconds();
        std::thread::sleep(std::time::Duration::from_millis(50));
        let slept = thread_cpu_seconds() - start;
        let start = thread_cpu_seconds();
        let mut x = 1u64;
        let begun = std::time::Instant::now();
        while begun.elapsed().as_millis() < 50 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let worked = thread_cpu_seconds() - start;
        assert!(worked > slept, "worked {worked} s, slept {slept} s");
        assert!(
            slept < 0.025,
            "a sleeping thread used {slept} s of CPU time"
        );
    }
}
