//! "rendered 3/40" on stderr while frames are rendered. On a terminal the count is rewritten
//! in place; in a log (CI, a file, the viewer's `--log`) every `\r` stays, so the counts would
//! run together on one line: there it prints a line at each tenth of the way and at the end.

use std::io::IsTerminal;

pub struct Counter {
    what: &'static str,
    total: usize,
    terminal: bool,
    tenths_shown: usize,
}

impl Counter {
    pub fn new(what: &'static str, total: usize) -> Self {
        Self {
            what,
            total,
            terminal: std::io::stderr().is_terminal(),
            tenths_shown: 0,
        }
    }

    /// `done` of the total are finished (1 after the first).
    pub fn done(&mut self, done: usize) {
        let (what, total) = (self.what, self.total);
        if self.terminal {
            eprint!("\r{what} {done}/{total}");
            if done >= total {
                eprintln!();
            }
        } else if self.log_line_due(done) {
            eprintln!("{what} {done}/{total}");
        }
    }

    /// In a log: whether `done` passes a new tenth of the way or ends it (and notes the tenth).
    fn log_line_due(&mut self, done: usize) -> bool {
        let tenths = (done * 10).checked_div(self.total).unwrap_or(10);
        let due = tenths > self.tenths_shown || done >= self.total;
        self.tenths_shown = self.tenths_shown.max(tenths);
        due
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn log_lines(total: usize) -> Vec<usize> {
        let mut c = Counter {
            what: "rendered",
            total,
            terminal: false,
            tenths_shown: 0,
        };
        (1..=total).filter(|&d| c.log_line_due(d)).collect()
    }

    #[test]
    fn a_log_gets_a_line_per_tenth_and_the_last() {
        assert_eq!(log_lines(3), [1, 2, 3]);
        assert_eq!(log_lines(120), (1..=10).map(|k| 12 * k).collect::<Vec<_>>());
        assert_eq!(log_lines(25), [3, 5, 8, 10, 13, 15, 18, 20, 23, 25]);
    }
}
