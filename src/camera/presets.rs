//! Nominal camera presets shipped in `calib/` (embedded, so they work from any folder). They
//! come from published specifications and are not calibrations.

use std::path::Path;

use super::Calibration;
use super::formats::{self, Format};

/// Name, file in the repository, JSON.
pub const PRESETS: [(&str, &str, &str); 2] = [
    (
        "mavic3e",
        "calib/dji-mavic3e-4k.json",
        include_str!("../../calib/dji-mavic3e-4k.json"),
    ),
    (
        "mini3pro",
        "calib/dji-mini3pro-4k.json",
        include_str!("../../calib/dji-mini3pro-4k.json"),
    ),
];

/// A preset by name.
pub fn preset(name: &str) -> Option<Calibration> {
    PRESETS
        .iter()
        .find(|(n, _, _)| *n == name)
        .map(|(_, path, text)| {
            formats::parse(Path::new(path), text, Some(Format::Json))
                .expect("shipped presets parse")
        })
}

/// The names of the presets, for messages.
pub fn names() -> Vec<&'static str> {
    PRESETS.iter().map(|(n, _, _)| *n).collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn presets_parse_and_are_marked_nominal() {
        for n in super::names() {
            let c = super::preset(n).unwrap();
            assert!(c.notes[0].starts_with("NOMINAL"), "{n}");
            assert_eq!(c.camera.image_size.unwrap().width, 3840);
        }
    }
}
