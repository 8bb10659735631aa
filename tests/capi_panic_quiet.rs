//! The C API's panic boundary keeps panics off the host's stderr (issue 29): the host's own
//! panic hook is not called for a panic inside a Lacuna call, the message (with its location)
//! goes to `lacuna_last_error_message()` (also for a panic on a worker thread of a pool made
//! inside the call), and panics outside Lacuna still reach the host's
//! hook. Its own test binary: the panic hook is process-wide.

use std::sync::atomic::{AtomicUsize, Ordering};

static HOST_HOOK_CALLS: AtomicUsize = AtomicUsize::new(0);

#[test]
fn panics_inside_the_c_api_do_not_reach_the_host_hook() {
    std::panic::set_hook(Box::new(|_| {
        HOST_HOOK_CALLS.fetch_add(1, Ordering::SeqCst);
    }));
    let status = lacuna::capi::lacuna_debug_trigger_panic();
    assert_eq!(status, lacuna::capi::lacuna_status::Panic);
    assert_eq!(HOST_HOOK_CALLS.load(Ordering::SeqCst), 0);
    let message = unsafe { std::ffi::CStr::from_ptr(lacuna::capi::lacuna_last_error_message()) }
        .to_string_lossy()
        .into_owned();
    assert!(
        message.contains("internal panic at src/capi/boundary.rs:")
            && message.contains("lacuna_debug_trigger_panic was called"),
        "{message}"
    );
    // A panic on a worker thread of a pool made inside a call (as in a render) is quiet too.
    let status = lacuna::capi::debug_trigger_worker_panic();
    assert_eq!(status, lacuna::capi::lacuna_status::Panic);
    assert_eq!(HOST_HOOK_CALLS.load(Ordering::SeqCst), 0);
    let message = unsafe { std::ffi::CStr::from_ptr(lacuna::capi::lacuna_last_error_message()) }
        .to_string_lossy()
        .into_owned();
    assert!(
        message.contains("debug_trigger_worker_panic was called"),
        "{message}"
    );
    // A panic of the host's own still goes to the host's hook.
    let _ = std::panic::catch_unwind(|| panic!("the host's own panic"));
    assert_eq!(HOST_HOOK_CALLS.load(Ordering::SeqCst), 1);
}
