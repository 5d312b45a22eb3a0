//! Flight telemetry recorded beside the video (pure parsing): DJI's `.SRT` subtitles.

pub mod srt;
