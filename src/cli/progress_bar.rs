//! Progress bars on standard error (indicatif), or nothing with `-q`.

use std::sync::Mutex;
use std::time::Duration;

use illumnet::progress::Progress;
use indicatif::{ProgressBar, ProgressStyle};

/// Shows one bar per stage.
pub struct BarProgress {
    quiet: bool,
    bar: Mutex<Option<ProgressBar>>,
}

impl BarProgress {
    pub fn new(quiet: bool) -> Self {
        Self { quiet, bar: Mutex::new(None) }
    }
}

impl Progress for BarProgress {
    fn start(&self, stage: &str, total: u64) {
        if self.quiet {
            return;
        }
        let bar = if total > 0 {
            let b = ProgressBar::new(total);
            b.set_style(
                ProgressStyle::with_template("{msg:28} [{bar:32}] {pos}/{len} ({eta})")
                    .expect("valid template")
                    .progress_chars("=> "),
            );
            b
        } else {
            let b = ProgressBar::new_spinner();
            b.set_style(ProgressStyle::with_template("{msg:28} {spinner} {pos} iterations").expect("valid template"));
            b.enable_steady_tick(Duration::from_millis(100));
            b
        };
        bar.set_message(stage.to_string());
        *self.bar.lock().unwrap_or_else(|e| e.into_inner()) = Some(bar);
    }

    fn advance(&self, units: u64) {
        if let Some(b) = self.bar.lock().unwrap_or_else(|e| e.into_inner()).as_ref() {
            b.inc(units);
        }
    }

    fn busy(&self, stage: &str) {
        if self.quiet {
            return;
        }
        let b = ProgressBar::new_spinner();
        b.set_style(ProgressStyle::with_template("{msg:28} {spinner} {elapsed}").expect("valid template"));
        b.enable_steady_tick(Duration::from_millis(100));
        b.set_message(stage.to_string());
        *self.bar.lock().unwrap_or_else(|e| e.into_inner()) = Some(b);
    }

    fn note(&self, message: &str) {
        eprintln!("illumnet: note: {message}");
    }

    fn finish(&self) {
        if let Some(b) = self.bar.lock().unwrap_or_else(|e| e.into_inner()).take() {
            b.finish_and_clear();
        }
    }
}
