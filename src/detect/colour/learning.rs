//! The detector that learns its palette from frames drawn from the video as it goes by.

use super::*;

/// The colour detector as one pass over a video runs it: it learns its palette from pixels of
/// randomly chosen frames as they go by, and meanwhile keeps, for every frame, only the runs of
/// colours that could be a hat whatever the palette (with their colours); once the last chosen
/// frame has been seen it learns the palette and finishes the kept frames. The video is
/// decoded once. Should the kept runs outgrow `budget_bytes` first (a long video with many hat
/// colours about), the palette is learnt from the chosen frames seen so far.
pub struct LearningColourDetector {
    pub(super) settings: ColourSettings,
    pub(super) screen: Vec<u64>,
    /// Frames to sample (ascending) and every how many pixels.
    pub(super) sample_frames: Vec<usize>,
    pub(super) step: usize,
    pub(super) samples: Vec<[u8; 3]>,
    pub(super) kept: Vec<Kept>,
    pub(super) kept_bytes: usize,
    pub(super) budget_bytes: usize,
    pub(super) ready: Option<(ColourDetector, Palette)>,
}

/// A frame held back: its candidate runs and the 6-bit colour of each of their pixels.
pub(super) struct Kept {
    pub(super) index: usize,
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) runs: Vec<Run>,
    pub(super) colours: Vec<u32>,
}

impl LearningColourDetector {
    /// `frames`: how many frames the video has (to spread `sample_count` frames over, by a draw
    /// seeded with `settings.seed`); `None`: the first `sample_count` frames. Every `step`-th
    /// pixel of a chosen frame is sampled.
    pub fn new(
        settings: ColourSettings,
        frames: Option<usize>,
        sample_count: usize,
        step: usize,
        budget_bytes: usize,
    ) -> LearningColourDetector {
        let mut sample_frames: Vec<usize> = match frames {
            Some(n) if sample_count < n => {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(settings.seed);
                (0..sample_count).map(|_| rng.random_range(0..n)).collect()
            }
            Some(n) => (0..n).collect(),
            None => (0..sample_count.max(1)).collect(),
        };
        sample_frames.sort_unstable();
        sample_frames.dedup();
        LearningColourDetector {
            screen: permissive_table(&settings),
            settings,
            sample_frames,
            step: step.max(1),
            samples: Vec::new(),
            kept: Vec::new(),
            kept_bytes: 0,
            budget_bytes,
            ready: None,
        }
    }

    /// The frames whose pixels the palette is learnt from, ascending.
    pub fn frames_to_sample(&self) -> &[usize] {
        &self.sample_frames
    }

    /// Takes the sampled pixels of one of [`frames_to_sample`](Self::frames_to_sample).
    pub fn sample(&mut self, f: &FrameView) {
        // The same pixels whichever way the frames are read: an offset from the index.
        let mut k = (f.index * 7919) % self.step;
        while k < f.width * f.height {
            self.samples.push(f.pixel(k % f.width, k / f.width));
            k += self.step;
        }
    }

    /// The palette learnt from the pixels sampled so far, and the detector it gives: what a
    /// pass over the whole video learns, when every frame to sample was given to
    /// [`sample`](Self::sample) first.
    pub fn learn_now(&self) -> Result<(ColourDetector, Palette), ColourError> {
        let palette = Palette::learn(&self.samples, &self.settings)?;
        Ok((
            ColourDetector::new(&palette, self.settings.clone()),
            palette,
        ))
    }

    /// The palette, once learnt.
    pub fn palette(&self) -> Option<&Palette> {
        self.ready.as_ref().map(|r| &r.1)
    }

    /// Learns the palette and finishes the frames held back.
    pub(super) fn learn(&mut self) -> Result<Vec<FrameDetections>, crate::PluginError> {
        let palette = Palette::learn(&self.samples, &self.settings).map_err(|e| e.to_string())?;
        let mut table = self.screen.clone();
        ColourDetector::restrict(&mut table, &palette);
        let det = ColourDetector {
            table,
            settings: self.settings.clone(),
        };
        // The frames held back are independent: finish them in parallel (this happens once,
        // often when the rest of the pass is done and the cores are free).
        let out: Vec<FrameDetections> = std::mem::take(&mut self.kept)
            .into_par_iter()
            .map(|k| {
                // Split each candidate run where its colours are not hat colours.
                let mut runs = Vec::new();
                let mut c = 0;
                for r in &k.runs {
                    let mut start: Option<usize> = None;
                    for x in r.x0..r.x1 {
                        let hat = has_colour(&det.table, k.colours[c] as usize);
                        c += 1;
                        match (hat, start) {
                            (true, None) => start = Some(x),
                            (false, Some(s)) => {
                                runs.push(Run {
                                    y: r.y,
                                    x0: s,
                                    x1: x,
                                });
                                start = None;
                            }
                            _ => {}
                        }
                    }
                    if let Some(s) = start {
                        runs.push(Run {
                            y: r.y,
                            x0: s,
                            x1: r.x1,
                        });
                    }
                }
                (k.index, det.detections_from_runs(&runs, k.width, k.height))
            })
            .collect();
        self.samples = Vec::new();
        self.kept_bytes = 0;
        self.ready = Some((det, palette));
        Ok(out)
    }
}

impl Detector for LearningColourDetector {
    fn push(&mut self, f: &FrameView) -> Result<Vec<FrameDetections>, crate::PluginError> {
        if let Some((det, _)) = &self.ready {
            return Ok(vec![(f.index, det.detect(f))]);
        }
        if self.sample_frames.binary_search(&f.index).is_ok() {
            self.sample(f);
        }
        let runs = table_runs(f, &self.screen, hat_radius_px(&self.settings));
        let mut colours = Vec::new();
        for r in &runs {
            let row = &f.bgr[3 * r.y * f.width..];
            for x in r.x0..r.x1 {
                colours.push(index_bgr(row[3 * x], row[3 * x + 1], row[3 * x + 2]) as u32);
            }
        }
        self.kept_bytes += runs.len() * std::mem::size_of::<Run>() + 4 * colours.len() + 64;
        self.kept.push(Kept {
            index: f.index,
            width: f.width,
            height: f.height,
            runs,
            colours,
        });
        let last = self.sample_frames.last().copied().unwrap_or(0);
        if f.index >= last || (self.kept_bytes > self.budget_bytes && !self.samples.is_empty()) {
            self.learn()
        } else {
            Ok(Vec::new())
        }
    }

    fn finish(&mut self) -> Result<Vec<FrameDetections>, crate::PluginError> {
        if self.ready.is_some() || self.kept.is_empty() {
            return Ok(Vec::new());
        }
        self.learn()
    }

    fn summary(&self) -> Vec<(String, f64)> {
        match self.palette() {
            Some(p) => vec![
                (
                    "hat_colours".into(),
                    p.hat.iter().filter(|h| **h).count() as f64,
                ),
                ("palette_colours".into(), p.colours as f64),
            ],
            None => Vec::new(),
        }
    }
}
