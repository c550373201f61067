//! Progress bars with ETA (indicatif) for long runs: the studies of `sheaf
//! bench` and `sheaf demo`. Their report lines go through `Progress::say`,
//! so a bar drawn on a terminal stays below them and nothing changes when
//! the output is a file or a pipe (no bar is drawn then).

use indicatif::{ProgressBar, ProgressStyle};

/// The progress of a long run (a study, a demo): a bar with ETA on the
/// terminal (stderr; none when stderr is not a terminal), and the run's
/// report lines, printed above the bar to stdout (or stderr after
/// `on_stderr`) whether or not a bar is drawn.
pub struct Progress {
    bar: ProgressBar,
    to_stderr: bool,
}

impl Progress {
    /// A bar of `steps` steps (configurations, frames, ...) named `what`.
    pub fn new(what: &str, steps: u64) -> Progress {
        let bar = ProgressBar::new(steps);
        let style = ProgressStyle::with_template(
            "{prefix} [{elapsed_precise}] {wide_bar} {pos}/{len} (ETA {eta}) {msg}",
        )
        .expect("a valid progress template");
        bar.set_style(style);
        bar.set_prefix(what.to_string());
        Progress {
            bar,
            to_stderr: false,
        }
    }
    /// Report lines on stderr (`sheaf bench --stress` keeps stdout quiet).
    pub fn on_stderr(mut self) -> Progress {
        self.to_stderr = true;
        self
    }
    /// Print a report line above the bar.
    pub fn say(&self, line: impl std::fmt::Display) {
        let to_stderr = self.to_stderr;
        self.bar.suspend(|| {
            if to_stderr {
                eprintln!("{line}");
            } else {
                println!("{line}");
            }
        });
    }
    /// One step done.
    pub fn step(&self) {
        self.bar.inc(1);
    }
    /// `n` steps done (or skipped with their scene).
    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
    }
    /// `n` more steps to do (a count known only later).
    pub fn add(&self, n: u64) {
        self.bar.inc_length(n);
    }
    /// What is running now, after the bar.
    pub fn doing(&self, msg: impl Into<String>) {
        self.bar.set_message(msg.into());
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}
