//! Progress of a long run: an indicatif bar on a terminal, plain lines every
//! 10 % (or 15 s) when stderr is a file or pipe, nothing with `--quiet`.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressState, ProgressStyle};
use std::io::IsTerminal;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How progress is shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgressMode {
    /// A bar on a terminal, plain lines otherwise.
    Auto,
    Quiet,
}

/// Counts finished scenarios (or other units of work) and reports them.
pub struct Progress {
    /// What is counted, plural ("scenarios", "tar files").
    unit: &'static str,
    bar: Option<ProgressBar>,
    plain: Option<Mutex<(Instant, u64)>>,
    done: AtomicU64,
    /// Of `done`, those found finished already (a resumed run's): left
    /// out of the rate, which they made meaningless ("70/100, 586/s").
    skipped: std::sync::Arc<AtomicU64>,
    total: u64,
    start: Instant,
}

impl Progress {
    pub fn new(total: u64, mode: ProgressMode) -> Progress {
        Progress::since(Instant::now(), total, mode)
    }

    /// [`Progress::new`] counting `unit` (plural, e.g. "tar files").
    pub fn counting(total: u64, mode: ProgressMode, unit: &'static str) -> Progress {
        Progress::of(Instant::now(), total, mode, unit)
    }

    /// [`Progress::new`] of work that began at `start` (rates and the ETA
    /// count from then).
    pub fn since(start: Instant, total: u64, mode: ProgressMode) -> Progress {
        Progress::of(start, total, mode, "scenarios")
    }

    fn of(start: Instant, total: u64, mode: ProgressMode, unit: &'static str) -> Progress {
        let terminal = std::io::stderr().is_terminal();
        let skipped = std::sync::Arc::new(AtomicU64::new(0));
        let skipped_seen = skipped.clone();
        let (bar, plain) = match mode {
            ProgressMode::Quiet => (None, None),
            ProgressMode::Auto if terminal => {
                let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
                let style =
                    ProgressStyle::with_template("{spinner} [{since}] {wide_bar} {pos}/{len} {unit} ({rate_eta})")
                        .expect("valid template")
                        // (From `start`, as the rate: indicatif's own clock starts here.)
                        .with_key("since", move |_: &ProgressState, w: &mut dyn std::fmt::Write| {
                            let s = start.elapsed().as_secs();
                            let _ = write!(w, "{:02}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60);
                        })
                        .with_key("unit", move |_: &ProgressState, w: &mut dyn std::fmt::Write| {
                            let _ = w.write_str(unit);
                        })
                        .with_key("rate_eta", move |state: &ProgressState, w: &mut dyn std::fmt::Write| {
                            let total = state.len().unwrap_or(0);
                            let skipped = skipped_seen.load(Ordering::Relaxed);
                            let seconds = start.elapsed().as_secs_f64();
                            let _ = w.write_str(&rate_and_eta_skipping(state.pos(), skipped, total, seconds));
                        });
                bar.set_style(style);
                bar.enable_steady_tick(Duration::from_millis(200));
                (Some(bar), None)
            }
            ProgressMode::Auto => (None, Some(Mutex::new((start, 0)))),
        };
        Progress { unit, bar, plain, done: AtomicU64::new(0), skipped, total, start }
    }

    /// One more scenario (unit) found finished already: counted as done,
    /// but not into the rate and ETA.
    pub fn skip(&self) {
        self.skipped.fetch_add(1, Ordering::Relaxed);
        self.inc();
    }

    /// One more scenario (unit) finished.
    pub fn inc(&self) {
        let done = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        if let Some(bar) = &self.bar {
            bar.inc(1);
        }
        if let Some(plain) = &self.plain {
            let mut last = plain.lock().expect("progress lock");
            let step = (self.total / 10).max(1);
            let due = done / step > last.1 / step || last.0.elapsed() > Duration::from_secs(15) || done == self.total;
            if due {
                let secs = self.start.elapsed().as_secs_f64();
                note(format_args!(
                    "progress: {done}/{} {} ({:.0} %), {}",
                    self.total,
                    self.unit,
                    100.0 * done as f64 / self.total.max(1) as f64,
                    rate_and_eta_skipping(done, self.skipped.load(Ordering::Relaxed), self.total, secs)
                ));
                *last = (Instant::now(), done);
            }
        }
    }

    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// `12/s, ETA 40 s` (`0.4/s` below 10 per second); `starting` before the
/// first one finishes, when there is no rate to tell yet.
pub fn rate_and_eta(done: u64, total: u64, seconds: f64) -> String {
    rate_and_eta_skipping(done, 0, total, seconds)
}

/// [`rate_and_eta`] of `done` units of which `skipped` were found done
/// already: the rate is of the others, the ETA of what is left at it.
fn rate_and_eta_skipping(done: u64, skipped: u64, total: u64, seconds: f64) -> String {
    let worked = done.saturating_sub(skipped);
    if worked == 0 || seconds <= 0.0 {
        return if skipped > 0 { "resuming" } else { "starting" }.into();
    }
    let rate = worked as f64 / seconds;
    let rate_text = if rate >= 10.0 { format!("{rate:.0}/s") } else { format!("{rate:.1}/s") };
    let eta = total.saturating_sub(done) as f64 / rate;
    let eta_text = if eta >= 3600.0 {
        format!("{}h{:02}m", (eta / 3600.0) as u64, ((eta % 3600.0) / 60.0) as u64)
    } else if eta >= 60.0 {
        format!("{}m{:02}s", (eta / 60.0) as u64, (eta % 60.0) as u64)
    } else {
        format!("{eta:.0} s")
    };
    format!("{rate_text}, ETA {eta_text}")
}

/// Writes one line to stderr, as `eprintln!` does, but never panics: a
/// stderr that cannot be written (a full disk, `ulimit -f`, a closed pipe)
/// loses the line and the work goes on to its own error or success.
pub fn note(line: impl std::fmt::Display) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr().lock(), "{line}");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_are_readable_and_there_is_no_eta_before_the_first_scenario() {
        assert_eq!(rate_and_eta(0, 30, 2.0), "starting");
        assert_eq!(rate_and_eta(3, 30, 22.44), "0.1/s, ETA 3m21s");
        assert_eq!(rate_and_eta(150, 1000, 10.0), "15/s, ETA 57 s");
        assert_eq!(rate_and_eta(10, 100_000, 1.0), "10/s, ETA 2h46m");
        assert_eq!(rate_and_eta(30, 30, 3.0), "10/s, ETA 0 s");
        // A resumed run: 70 found done, 10 written in 2 s, 20 left.
        assert_eq!(rate_and_eta_skipping(80, 70, 100, 2.0), "5.0/s, ETA 4 s");
        assert_eq!(rate_and_eta_skipping(70, 70, 100, 2.0), "resuming");
    }
}
