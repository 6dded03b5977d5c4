//! Long work says so: a spinner or a bar on standard error while a command computes,
//! only when standard error is a terminal (never in a pipe, a log or a test).

use std::io::IsTerminal as _;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};

/// A progress indicator that disappears when dropped.
pub struct Progress(Option<ProgressBar>);

fn shown() -> bool {
    std::io::stderr().is_terminal()
}

/// An indeterminate spinner with a message and the elapsed time.
pub fn spinner(message: impl Into<String>) -> Progress {
    if !shown() {
        return Progress(None);
    }
    let pb = ProgressBar::new_spinner();
    if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} ({elapsed})") {
        pb.set_style(style);
    }
    pb.set_message(message.into());
    pb.enable_steady_tick(Duration::from_millis(120));
    Progress(Some(pb))
}

/// A bar over `len` steps of `what`.
pub fn bar(len: u64, what: impl Into<String>) -> Progress {
    if !shown() {
        return Progress(None);
    }
    Progress(Some(styled(ProgressBar::new(len), what)))
}

/// `pb` in the style of [`bar`].
fn styled(pb: ProgressBar, what: impl Into<String>) -> ProgressBar {
    if let Ok(style) =
        ProgressStyle::with_template("{msg} [{bar:32}] {pos}/{len} ({elapsed}, {eta} left)")
    {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(what.into());
    pb
}

/// Steps of a [`share_bar`].
const SHARES: u64 = 1000;

/// A bar over work whose size is known as a quantity, not a count (an experiment's
/// device time): the share done as a percentage, the time taken and left. Updated
/// with [`Progress::set_share`].
pub fn share_bar(what: impl Into<String>) -> Progress {
    if !shown() {
        return Progress(None);
    }
    let pb = ProgressBar::new(SHARES);
    if let Ok(style) =
        ProgressStyle::with_template("{msg} [{bar:32}] {percent}% ({elapsed}, {eta} left)")
    {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(what.into());
    Progress(Some(pb))
}

/// A bar over `len` items of `what` that also shows the rate (items per minute of
/// wall time) and the time left.
pub fn rate_bar(len: u64, what: impl Into<String>) -> Progress {
    if !shown() {
        return Progress(None);
    }
    let pb = ProgressBar::new(len);
    let template = "{msg} [{bar:32}] {pos}/{len} ({elapsed}, {per_min}, {eta} left)";
    if let Ok(style) = ProgressStyle::with_template(template).map(|s| {
        s.with_key(
            "per_min",
            |st: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
                let _ = write!(w, "{:.0}/min", st.per_sec() * 60.0);
            },
        )
    }) {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(what.into());
    Progress(Some(pb))
}

/// A bar over `len` grid points of `what` that stays hidden until the work has taken
/// `delay`: a field done in a second shows nothing. Updated from any thread with
/// [`Progress::set_from`].
pub fn delayed_bar(len: u64, what: impl Into<String>, delay: Duration) -> Delayed {
    let hidden = indicatif::ProgressDrawTarget::hidden();
    let bar =
        Progress(shown().then(|| styled(ProgressBar::with_draw_target(Some(len), hidden), what)));
    Delayed {
        bar,
        start: std::time::Instant::now(),
        delay,
        shown: std::sync::atomic::AtomicBool::new(false),
    }
}

/// A [`delayed_bar`].
pub struct Delayed {
    bar: Progress,
    start: std::time::Instant,
    delay: Duration,
    shown: std::sync::atomic::AtomicBool,
}

impl Delayed {
    /// `pos` steps done; the bar appears once the delay has passed.
    pub fn set_from(&self, pos: u64) {
        let Some(pb) = &self.bar.0 else { return };
        if self.start.elapsed() >= self.delay
            && !self.shown.swap(true, std::sync::atomic::Ordering::Relaxed)
        {
            pb.set_draw_target(indicatif::ProgressDrawTarget::stderr());
        }
        pb.set_position(pos);
    }
}

impl Progress {
    /// One more step done.
    pub fn inc(&self) {
        if let Some(pb) = &self.0 {
            pb.inc(1);
        }
    }

    /// The share `f` of a [`share_bar`]'s work done (clamped to [0, 1]; NaN is 0).
    pub fn set_share(&self, f: f64) {
        if let Some(pb) = &self.0 {
            let f = if f.is_nan() { 0.0 } else { f.clamp(0.0, 1.0) };
            pb.set_position((f * SHARES as f64).round() as u64);
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if let Some(pb) = &self.0 {
            pb.finish_and_clear();
        }
    }
}
