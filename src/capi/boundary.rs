//! Status codes, the thread-local last error, and the one panic boundary every entry point runs
//! under.

use std::cell::RefCell;
use std::ffi::{c_char, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Once;

use super::context::lacuna_context;
use crate::error::Error;

/// The result of every fallible function. The values are frozen: a code never changes meaning
/// and new codes are only ever appended. `LACUNA_STATUS_OK` is 0, so `if (status)` tests for
/// failure. On failure, `lacuna_last_error_message()` tells what went wrong.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_status {
    /// Success.
    Ok = 0,
    /// An argument has an invalid value (the message names the argument and the value).
    InvalidArgument = 1,
    /// A pointer argument that must not be NULL is NULL.
    NullPointer = 2,
    /// An index or a count is out of range.
    OutOfRange = 3,
    /// A file could not be read or written.
    Io = 4,
    /// A file was read but its content is malformed.
    Parse = 5,
    /// An allocation failed.
    OutOfMemory = 6,
    /// A structure would exceed the memory budget of the context.
    OverBudget = 7,
    /// The operation was cancelled (progress callback returned false, or a cancel call).
    Cancelled = 8,
    /// Lacuna panicked internally: a bug in Lacuna. The message tells where.
    Panic = 9,
    /// The call is not valid in the object's current state (e.g. running a job twice at once).
    InvalidOperation = 10,
}

impl lacuna_status {
    fn name(self) -> &'static CStr {
        match self {
            lacuna_status::Ok => c"LACUNA_STATUS_OK",
            lacuna_status::InvalidArgument => c"LACUNA_STATUS_INVALID_ARGUMENT",
            lacuna_status::NullPointer => c"LACUNA_STATUS_NULL_POINTER",
            lacuna_status::OutOfRange => c"LACUNA_STATUS_OUT_OF_RANGE",
            lacuna_status::Io => c"LACUNA_STATUS_IO",
            lacuna_status::Parse => c"LACUNA_STATUS_PARSE",
            lacuna_status::OutOfMemory => c"LACUNA_STATUS_OUT_OF_MEMORY",
            lacuna_status::OverBudget => c"LACUNA_STATUS_OVER_BUDGET",
            lacuna_status::Cancelled => c"LACUNA_STATUS_CANCELLED",
            lacuna_status::Panic => c"LACUNA_STATUS_PANIC",
            lacuna_status::InvalidOperation => c"LACUNA_STATUS_INVALID_OPERATION",
        }
    }

    fn from_u32(code: u32) -> Option<Self> {
        use lacuna_status::*;
        [
            Ok,
            InvalidArgument,
            NullPointer,
            OutOfRange,
            Io,
            Parse,
            OutOfMemory,
            OverBudget,
            Cancelled,
            Panic,
            InvalidOperation,
        ]
        .into_iter()
        .find(|s| *s as u32 == code)
    }
}

/// An error on its way out through the boundary: a status and a human-readable message.
#[derive(Debug)]
pub(crate) struct CapiError {
    pub status: lacuna_status,
    pub message: String,
}

impl CapiError {
    pub fn new(status: lacuna_status, message: impl Into<String>) -> Self {
        CapiError {
            status,
            message: message.into(),
        }
    }

    /// A NULL pointer where one is required; `what` names the argument.
    pub fn null(what: &str) -> Self {
        Self::new(
            lacuna_status::NullPointer,
            format!("argument `{what}` is NULL"),
        )
    }

    pub fn invalid(message: impl Into<String>) -> Self {
        Self::new(lacuna_status::InvalidArgument, message)
    }

    pub fn range(message: impl Into<String>) -> Self {
        Self::new(lacuna_status::OutOfRange, message)
    }

    pub fn operation(message: impl Into<String>) -> Self {
        Self::new(lacuna_status::InvalidOperation, message)
    }
}

impl From<Error> for CapiError {
    fn from(e: Error) -> Self {
        let status = match &e {
            Error::InvalidArgument(_) => lacuna_status::InvalidArgument,
            Error::Io { .. } => lacuna_status::Io,
            Error::Parse { .. } => lacuna_status::Parse,
            Error::OverBudget { .. } => lacuna_status::OverBudget,
            Error::Cancelled => lacuna_status::Cancelled,
        };
        CapiError::new(status, e.to_string())
    }
}

pub(crate) type CapiResult<T> = Result<T, CapiError>;

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
    /// Where the last panic inside a boundary happened, for its message.
    static PANIC_LOCATION: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// Installs, once, a panic hook that stays silent for panics inside a boundary call, on the
/// calling thread or on a worker of a pool made inside one (the host's stderr is not Lacuna's
/// to write: the message goes to `lacuna_last_error_message()` instead, with its location
/// when the panic happened on the calling thread) and hands every other panic to the hook
/// that was there before.
fn install_quiet_panic_hook() {
    static INSTALL: Once = Once::new();
    INSTALL.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !crate::workers::panics_reported_by_caller() {
                return previous(info);
            }
            let location = info
                .location()
                .map(|l| format!("{}:{}", l.file(), l.line()));
            PANIC_LOCATION.with(|p| *p.borrow_mut() = location);
        }));
    });
}

/// Marks the calling thread as inside a boundary call while alive: its panics are reported
/// by the boundary, not printed. Entry points may nest; the outermost restores the flag.
struct InBoundary {
    was_inside: bool,
}

impl InBoundary {
    fn enter() -> Self {
        InBoundary {
            was_inside: crate::workers::set_panics_reported_by_caller(true),
        }
    }
}

impl Drop for InBoundary {
    fn drop(&mut self) {
        crate::workers::set_panics_reported_by_caller(self.was_inside);
    }
}

/// What the body of an entry point tells the boundary besides its result: the context whose
/// error callback hears about a failure, once the body knows it.
#[derive(Default)]
pub(crate) struct Call<'a> {
    context: Option<&'a lacuna_context>,
}

impl<'a> Call<'a> {
    /// Failures of this call are also reported to `ctx`'s error callback.
    pub fn context(&mut self, ctx: &'a lacuna_context) {
        self.context = Some(ctx);
    }
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic payload".to_string()
    }
}

/// The panic boundary: runs `body` under `catch_unwind`; on an error or a panic, records the
/// message for `lacuna_last_error_message()` (prefixed with the function's name) and calls the
/// context's error callback. Every `extern "C"` function goes through here.
pub(crate) fn boundary<T>(
    function: &'static str,
    body: impl for<'a> FnOnce(&mut Call<'a>) -> CapiResult<T>,
) -> Result<T, lacuna_status> {
    install_quiet_panic_hook();
    let mut call = Call::default();
    let result = {
        let _inside = InBoundary::enter();
        catch_unwind(AssertUnwindSafe(|| body(&mut call)))
    };
    let error = match result {
        Ok(Ok(value)) => return Ok(value),
        Ok(Err(e)) => e,
        Err(payload) => {
            let location = PANIC_LOCATION
                .with(|p| p.borrow_mut().take())
                .map_or(String::new(), |l| format!(" at {l}"));
            CapiError::new(
                lacuna_status::Panic,
                format!(
                    "internal panic{location}: {}",
                    panic_message(payload.as_ref())
                ),
            )
        }
    };
    let status = error.status;
    // Reporting must not unwind either (a context's mutex could be poisoned, a message could
    // hold a NUL): everything below is infallible or ignored.
    let _ = catch_unwind(AssertUnwindSafe(|| {
        let text = format!("{function}: {}", error.message).replace('\0', "\\0");
        let message = CString::new(text).unwrap_or_default();
        if let Some(ctx) = call.context {
            ctx.report(status, &message);
        }
        LAST_ERROR.with(|m| *m.borrow_mut() = message);
    }));
    Err(status)
}

/// [`boundary`] for functions returning a status.
pub(crate) fn status(
    function: &'static str,
    body: impl for<'a> FnOnce(&mut Call<'a>) -> CapiResult<()>,
) -> lacuna_status {
    match boundary(function, body) {
        Ok(()) => lacuna_status::Ok,
        Err(s) => s,
    }
}

/// [`boundary`] for infallible functions: `fallback` on a panic.
pub(crate) fn value<T>(
    function: &'static str,
    fallback: T,
    body: impl for<'a> FnOnce(&mut Call<'a>) -> CapiResult<T>,
) -> T {
    boundary(function, body).unwrap_or(fallback)
}

/// The message of the last failed Lacuna call on the calling thread, naming the function, the
/// argument and the bad value; an empty string when no call has failed on this thread yet.
///
/// Thread safety: each thread has its own message. Successful calls leave it unchanged; the
/// pointer stays valid until the next failing Lacuna call on the same thread. Never NULL; do
/// not free it.
#[no_mangle]
pub extern "C" fn lacuna_last_error_message() -> *const c_char {
    value("lacuna_last_error_message", c"".as_ptr(), |_| {
        Ok(LAST_ERROR.with(|m| m.borrow().as_ptr()))
    })
}

/// The name of a status code (e.g. `"LACUNA_STATUS_NULL_POINTER"`), or
/// `"LACUNA_STATUS_UNKNOWN"` for a value that is not a status. A static string: never NULL,
/// never freed. Thread-safe.
#[no_mangle]
pub extern "C" fn lacuna_status_string(status: u32) -> *const c_char {
    value(
        "lacuna_status_string",
        c"LACUNA_STATUS_UNKNOWN".as_ptr(),
        |_| {
            Ok(lacuna_status::from_u32(status)
                .map_or(c"LACUNA_STATUS_UNKNOWN", lacuna_status::name)
                .as_ptr())
        },
    )
}

/// Testing aid for Rust tests (not in the C header): panics on a worker thread of a pool made
/// inside a C API call, as a render's panic would, and returns what the boundary makes of it.
#[doc(hidden)]
pub fn debug_trigger_worker_panic() -> lacuna_status {
    status("debug_trigger_worker_panic", |_| {
        let pool = crate::workers::WorkerPool::new(Some(1), Some("lacuna-debug"))
            .map_err(|e| CapiError::operation(format!("no worker thread: {e}")))?;
        pool.install(|| panic!("debug_trigger_worker_panic was called"))
    })
}

/// Testing aid: panics inside Lacuna and returns what the panic boundary makes of it
/// (`LACUNA_STATUS_PANIC`, with the message in `lacuna_last_error_message()`). Lets a host's
/// test suite check that no panic crosses the C boundary. Thread-safe.
#[no_mangle]
pub extern "C" fn lacuna_debug_trigger_panic() -> lacuna_status {
    status("lacuna_debug_trigger_panic", |_| {
        panic!("lacuna_debug_trigger_panic was called")
    })
}
