//! Progress reporting for long work, decoupled from the terminal UI.

/// Something that shows progress. Library code reports through this; the CLI shows a bar.
pub trait Progress: Sync {
    fn set_length(&self, len: u64);
    fn inc(&self, n: u64);
    fn set_message(&self, msg: String);
}

/// Shows nothing.
pub struct NoProgress;

impl Progress for NoProgress {
    fn set_length(&self, _: u64) {}
    fn inc(&self, _: u64) {}
    fn set_message(&self, _: String) {}
}

impl Progress for indicatif::ProgressBar {
    fn set_length(&self, len: u64) {
        indicatif::ProgressBar::set_length(self, len);
    }
    fn inc(&self, n: u64) {
        indicatif::ProgressBar::inc(self, n);
    }
    fn set_message(&self, msg: String) {
        indicatif::ProgressBar::set_message(self, msg);
    }
}
