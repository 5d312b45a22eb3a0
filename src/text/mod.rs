//! Text output without the standard library's slow paths: numbers to fixed decimals (`fixed`) and
//! text made in pieces for a writer. Pure; the exports and the reports write through it.

pub mod fixed;

/// The text `fill` writes, as a string (small outputs and tests; writing to memory cannot fail).
pub fn text_of(fill: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>) -> String {
    let mut v = Vec::new();
    let _ = fill(&mut v);
    String::from_utf8_lossy(&v).into_owned()
}

/// Text made in pieces and passed to `w` once a piece is large: a long video's outputs never
/// stand whole in memory, and `w` is not called for every row.
pub(crate) struct Pieces<'w> {
    w: &'w mut dyn std::io::Write,
    pub(crate) s: String,
}

impl<'w> Pieces<'w> {
    pub(crate) fn new(w: &'w mut dyn std::io::Write) -> Pieces<'w> {
        Pieces {
            w,
            s: String::new(),
        }
    }

    /// Passes the text on once it is 64 KiB or more.
    pub(crate) fn done_piece(&mut self) -> std::io::Result<()> {
        if self.s.len() >= 1 << 16 {
            self.finish()?;
        }
        Ok(())
    }

    /// Passes the rest of the text on.
    pub(crate) fn finish(&mut self) -> std::io::Result<()> {
        self.w.write_all(self.s.as_bytes())?;
        self.s.clear();
        Ok(())
    }
}
