//! Third-party decoders that panic on corrupt input (Burn's record reader does, on some damaged
//! optimizer states) run inside [`contain`], which turns the panic into an error the caller can
//! name the file in. A panic hook can ask [`is_contained`] and stay quiet for these.

use std::cell::Cell;
use std::panic::{AssertUnwindSafe, catch_unwind};

thread_local! {
    static CONTAINED: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f`; a panic inside it becomes `Err(message)`.
pub fn contain<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    let outer = CONTAINED.replace(true);
    let r = catch_unwind(AssertUnwindSafe(f));
    CONTAINED.set(outer);
    r.map_err(|p| {
        p.downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "the decoder failed".into())
    })
}

/// Whether the current thread is inside [`contain`] (a panic hook's cue to stay quiet).
pub fn is_contained() -> bool {
    CONTAINED.get()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn panics_become_errors_and_the_flag_is_scoped() {
        assert!(!is_contained());
        let hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(|_| {}));
        let r: Result<(), String> = contain(|| {
            assert!(is_contained());
            panic!("bad length {}", 7)
        });
        std::panic::set_hook(hook);
        assert_eq!(r, Err("bad length 7".to_string()));
        assert!(!is_contained());
        assert_eq!(contain(|| 3), Ok(3));
    }
}
