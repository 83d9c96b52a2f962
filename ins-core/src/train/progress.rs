//! Progress bar: step, phase, losses, PSNR and ETA on one line (hidden when not a terminal).

use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A progress bar over training steps.
pub struct Progress {
    bar: ProgressBar,
}

impl Progress {
    /// A bar for `total` steps starting at `start`; `quiet` hides it.
    pub fn new(total: usize, start: usize, quiet: bool) -> Self {
        let bar = ProgressBar::new(total as u64);
        if quiet {
            bar.set_draw_target(ProgressDrawTarget::hidden());
        }
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} ETA {eta} {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar.set_position(start as u64);
        Self { bar }
    }

    /// Advances to `step` with a status message.
    pub fn update(&self, step: usize, msg: String) {
        self.bar.set_position(step as u64);
        self.bar.set_message(msg);
    }

    /// Prints a line above the bar.
    pub fn println(&self, line: impl AsRef<str>) {
        self.bar.println(line);
    }

    /// Prints a warning on stderr, quiet or not, without breaking the bar's line.
    pub fn warn(&self, line: impl AsRef<str>) {
        self.bar.suspend(|| eprintln!("{}", line.as_ref()));
    }

    /// Leaves the bar at its final state.
    pub fn finish(&self) {
        self.bar.finish();
    }

    /// Lets `first_step` report above this bar while it waits.
    pub fn attach(&self, first_step: &FirstStep) {
        *lock(&first_step.inner.bar) = Some(self.bar.clone());
    }
}

/// A wait before a run's first step that is said out loud: a first wgpu run compiles and tunes
/// kernels for minutes (the painting's VGG features, then the first step), which looks like a
/// hang otherwise. Says its note at once and then, every interval until [`FirstStep::done`],
/// how long the wait has lasted: on stderr, or above the training bar once one is attached.
#[derive(Clone)]
pub struct FirstStep {
    inner: Arc<Waiting>,
}

struct Waiting {
    done: Mutex<bool>,
    wake: Condvar,
    bar: Mutex<Option<ProgressBar>>,
}

impl std::fmt::Debug for FirstStep {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("FirstStep")
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl FirstStep {
    /// Says `note` and starts reporting every `every` (`quiet`: the note only).
    pub fn watch(note: &str, every: Duration, quiet: bool) -> Self {
        let first = Self {
            inner: Arc::new(Waiting {
                done: Mutex::new(false),
                wake: Condvar::new(),
                bar: Mutex::new(None),
            }),
        };
        first.say(note.to_string());
        if !quiet {
            let watcher = first.clone();
            std::thread::spawn(move || watcher.report(every));
        }
        first
    }

    fn say(&self, line: String) {
        match lock(&self.inner.bar).as_ref() {
            Some(bar) if !bar.is_hidden() => bar.println(line),
            _ => eprintln!("{line}"),
        }
    }

    fn report(&self, every: Duration) {
        let started = Instant::now();
        let mut done = lock(&self.inner.done);
        while !*done {
            let (guard, timeout) = self
                .inner
                .wake
                .wait_timeout(done, every)
                .unwrap_or_else(|e| e.into_inner());
            done = guard;
            if !*done && timeout.timed_out() {
                let line = format!(
                    "still compiling and tuning kernels before the first step: {:.0} s",
                    started.elapsed().as_secs_f64()
                );
                drop(done);
                self.say(line);
                done = lock(&self.inner.done);
            }
        }
    }

    /// The first step is done: no more lines.
    pub fn done(&self) {
        *lock(&self.inner.done) = true;
        self.inner.wake.notify_all();
    }

    /// Whether [`Self::done`] was called.
    pub fn is_done(&self) -> bool {
        *lock(&self.inner.done)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_step_wait_is_reported_until_done() {
        let first = FirstStep::watch("note", Duration::from_millis(10), false);
        let progress = Progress::new(10, 0, true);
        progress.attach(&first);
        std::thread::sleep(Duration::from_millis(50));
        assert!(!first.is_done());
        first.done();
        assert!(first.is_done());
        // The reporter wakes and ends at once: its thread holds the only other handle.
        let started = Instant::now();
        while Arc::strong_count(&first.inner) > 1 {
            assert!(
                started.elapsed() < Duration::from_secs(2),
                "the reporter did not end"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}
