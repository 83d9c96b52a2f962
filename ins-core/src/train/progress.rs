//! Progress bar: step, phase, losses, PSNR and ETA on one line (hidden when not a terminal).

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

    /// Leaves the bar at its final state.
    pub fn finish(&self) {
        self.bar.finish();
    }
}
