//! Progress of a long run: an indicatif bar on a terminal, plain lines every
//! 10 % (or 15 s) when stderr is a file or pipe, nothing with `--quiet`.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
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

/// Counts finished scenarios and reports them.
pub struct Progress {
    bar: Option<ProgressBar>,
    plain: Option<Mutex<(Instant, u64)>>,
    done: AtomicU64,
    total: u64,
    start: Instant,
}

impl Progress {
    pub fn new(total: u64, mode: ProgressMode) -> Progress {
        let start = Instant::now();
        let terminal = std::io::stderr().is_terminal();
        let (bar, plain) = match mode {
            ProgressMode::Quiet => (None, None),
            ProgressMode::Auto if terminal => {
                let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
                bar.set_style(
                    ProgressStyle::with_template(
                        "{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} scenarios ({per_sec}, ETA {eta})",
                    )
                    .expect("valid template"),
                );
                bar.enable_steady_tick(Duration::from_millis(200));
                (Some(bar), None)
            }
            ProgressMode::Auto => (None, Some(Mutex::new((start, 0)))),
        };
        Progress { bar, plain, done: AtomicU64::new(0), total, start }
    }

    /// One more scenario finished.
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
                let rate = done as f64 / secs.max(1e-9);
                let eta = (self.total - done) as f64 / rate.max(1e-9);
                eprintln!(
                    "progress: {done}/{} scenarios ({:.0} %), {rate:.1}/s, ETA {eta:.0} s",
                    self.total,
                    100.0 * done as f64 / self.total.max(1) as f64
                );
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
