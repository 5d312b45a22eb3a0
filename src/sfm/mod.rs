//! Structure from motion (issue 17, in progress). Pure, but for the feature adapter
//! (`sfm::sift`, OpenCV's SIFT).
//!
//! So far: features (`Features`: keypoints at full resolution, RootSIFT descriptors, a cap per
//! image spread over a grid of cells), their matching (`matching`: mutual nearest neighbours
//! with a ratio test), tracks (`tracks`), and an incremental reconstruction with one known
//! camera (`reconstruct`). The two-view geometry is in `estimate::essential`.

pub mod cache;
pub mod colmap;
pub mod colmap_convert;
pub mod colmap_model;
pub mod exif;
pub mod georef;
#[cfg(feature = "opencv")]
pub mod georef_job;
#[cfg(feature = "opencv")]
pub mod job;
pub mod matching;
pub mod reconstruct;
#[cfg(feature = "opencv")]
pub mod reference;
pub mod register;
#[cfg(feature = "opencv")]
pub mod register_job;
#[cfg(feature = "opencv")]
pub mod sift;
#[cfg(feature = "opencv")]
pub mod topview;
pub mod tracks;
pub mod video_pose;

/// Descriptor length (SIFT).
pub const DESCRIPTOR_LEN: usize = 128;

/// A keypoint in full-resolution pixels (pixel centres at integers).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Keypoint {
    pub x: f64,
    pub y: f64,
    /// Detector scale (diameter of the meaningful neighbourhood), full-resolution pixels.
    pub size: f64,
    /// Degrees, as the detector reports it.
    pub angle_deg: f64,
    pub response: f64,
}

/// The features of one image: keypoints and their descriptors (`DESCRIPTOR_LEN` floats each,
/// unit length), in the same order.
#[derive(Clone, Debug, Default)]
pub struct Features {
    pub width: u32,
    pub height: u32,
    pub keypoints: Vec<Keypoint>,
    pub descriptors: Vec<f32>,
}

impl Features {
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    pub fn descriptor(&self, i: usize) -> &[f32] {
        &self.descriptors[i * DESCRIPTOR_LEN..(i + 1) * DESCRIPTOR_LEN]
    }
}

/// How features are found.
#[derive(Clone, Debug)]
pub struct FeatureSettings {
    /// Images are searched at this largest side, pixels (keypoints are reported at full
    /// resolution); `None`: at full resolution.
    pub working_size_px: Option<u32>,
    /// At most this many features an image, spread over the grid.
    pub max_features: usize,
    /// Columns of the grid (rows in the image's proportion).
    pub grid_cols: usize,
    /// SIFT's contrast threshold (OpenCV's, divided by the 3 layers per octave inside):
    /// Lowe's 0.04 leaves weak texture (a façade's plaster, grass) without features.
    pub contrast_threshold: f64,
}

impl Default for FeatureSettings {
    fn default() -> Self {
        FeatureSettings {
            working_size_px: Some(2000),
            max_features: 8192,
            grid_cols: 8,
            contrast_threshold: 0.04,
        }
    }
}

/// RootSIFT (Arandjelović and Zisserman, 2012): the descriptor L1-normalised, then the square
/// root of each entry, so that the Euclidean distance of the results compares descriptors like
/// the Hellinger kernel. The result has unit Euclidean length (zero stays zero).
pub fn root_sift(d: &mut [f32]) {
    let l1: f32 = d.iter().map(|v| v.abs()).sum();
    if l1 <= 0.0 {
        return;
    }
    for v in d.iter_mut() {
        *v = (v.abs() / l1).sqrt();
    }
}

/// The memory a reconstruction's adjustments may take: this machine's (`MemTotal`), else no
/// limit. `BaSettings`'s 2 GiB default guards `geostride ba`'s single problem file; a survey of
/// 500 photos needs about 2 GB for its final adjustment alone.
pub fn adjustment_memory_limit() -> u64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|t| mem_total_bytes(&t))
        .unwrap_or(u64::MAX)
}

/// `MemTotal` of a `/proc/meminfo` text, bytes.
fn mem_total_bytes(meminfo: &str) -> Option<u64> {
    let v = meminfo.lines().find_map(|l| l.strip_prefix("MemTotal:"))?;
    let kb: u64 = v.trim().strip_suffix("kB")?.trim().parse().ok()?;
    kb.checked_mul(1024)
}

/// Which of `keypoints` to keep: at most `cap`, spread over a `cols`-column grid on a `width` ×
/// `height` image. Each cell gives its strongest first; the cap is filled rank by rank (every
/// cell's best, then every cell's second, ...), so that a cell of weak texture keeps its few
/// features beside a cell full of strong ones. Indices in ascending order.
pub fn grid_cap(
    keypoints: &[Keypoint],
    width: u32,
    height: u32,
    cap: usize,
    cols: usize,
) -> Vec<usize> {
    if keypoints.len() <= cap {
        return (0..keypoints.len()).collect();
    }
    let cols = cols.max(1);
    let rows =
        ((cols as f64 * f64::from(height) / f64::from(width.max(1))).round() as usize).max(1);
    let cell_of = |k: &Keypoint| {
        let c = ((k.x + 0.5) / f64::from(width.max(1)) * cols as f64).floor();
        let r = ((k.y + 0.5) / f64::from(height.max(1)) * rows as f64).floor();
        (r.clamp(0.0, (rows - 1) as f64) as usize) * cols + c.clamp(0.0, (cols - 1) as f64) as usize
    };
    let mut cells: Vec<Vec<usize>> = vec![Vec::new(); rows * cols];
    for (i, k) in keypoints.iter().enumerate() {
        cells[cell_of(k)].push(i);
    }
    // (rank in its cell, −response, index): the order in which the cap is filled.
    let mut order: Vec<(usize, f64, usize)> = Vec::with_capacity(keypoints.len());
    for cell in &mut cells {
        cell.sort_by(|&a, &b| {
            keypoints[b]
                .response
                .total_cmp(&keypoints[a].response)
                .then(a.cmp(&b))
        });
        order.extend(
            cell.iter()
                .enumerate()
                .map(|(rank, &i)| (rank, -keypoints[i].response, i)),
        );
    }
    order.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut keep: Vec<usize> = order[..cap].iter().map(|o| o.2).collect();
    keep.sort_unstable();
    keep
}

/// Each keypoint's relative localisation σ: its detector scale over the median scale of every
/// image's keypoints (0.25 to 8). A feature found at a coarser scale is located less precisely,
/// in proportion to its scale; weighting by it made Herz-Jesu's cameras 3.9 → 3.0 mm RMSE
/// (`docs/sfm.md`).
pub fn keypoint_sigmas(features: &[Features]) -> Vec<Vec<f64>> {
    let mut sizes: Vec<f64> = features
        .iter()
        .flat_map(|f| f.keypoints.iter().map(|k| k.size))
        .filter(|s| *s > 0.0 && s.is_finite())
        .collect();
    if sizes.is_empty() {
        return features.iter().map(|f| vec![1.0; f.len()]).collect();
    }
    let mid = sizes.len() / 2;
    let median = *sizes.select_nth_unstable_by(mid, f64::total_cmp).1;
    features
        .iter()
        .map(|f| {
            f.keypoints
                .iter()
                .map(|k| {
                    let r = k.size / median;
                    if r.is_finite() {
                        r.clamp(0.25, 8.0)
                    } else {
                        1.0
                    }
                })
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kp(x: f64, y: f64, response: f64) -> Keypoint {
        Keypoint {
            x,
            y,
            size: 2.0,
            angle_deg: 0.0,
            response,
        }
    }

    #[test]
    fn root_sift_is_unit_and_hellinger() {
        let mut a = vec![3.0f32, 0.0, 1.0, 4.0];
        root_sift(&mut a);
        let n: f32 = a.iter().map(|v| v * v).sum();
        assert!((n - 1.0).abs() < 1e-6);
        assert!((a[0] - (3.0f32 / 8.0).sqrt()).abs() < 1e-7);
        let mut z = vec![0.0f32; 4];
        root_sift(&mut z);
        assert_eq!(z, vec![0.0; 4]);
    }

    #[test]
    fn the_machines_memory_is_read_from_meminfo() {
        let t = "MemTotal:       24589012 kB\nMemFree:         1000 kB\n";
        assert_eq!(mem_total_bytes(t), Some(24_589_012 * 1024));
        assert_eq!(mem_total_bytes("MemFree: 1 kB\n"), None);
        assert_eq!(mem_total_bytes("MemTotal: lots\n"), None);
        assert!(adjustment_memory_limit() > 0);
    }
    /// A strong corner of the image must not take the whole cap from a weak one.
    #[test]
    fn the_cap_is_spread_over_the_grid() {
        let mut kps = Vec::new();
        // 1000 strong features in the top-left cell, 10 weak ones in every other cell.
        for i in 0..1000 {
            kps.push(kp(
                f64::from(i % 40),
                f64::from(i / 40),
                100.0 + f64::from(i),
            ));
        }
        for c in 1..4 {
            for i in 0..10 {
                kps.push(kp(
                    100.0 * f64::from(c) + f64::from(i),
                    10.0,
                    1.0 + f64::from(i),
                ));
            }
        }
        // 4 × 1 grid on 400 × 100.
        let keep = grid_cap(&kps, 400, 100, 100, 4);
        assert_eq!(keep.len(), 100);
        let weak = keep.iter().filter(|&&i| i >= 1000).count();
        assert_eq!(weak, 30, "every weak feature kept");
        // The strong cell keeps its 70 strongest.
        let strong: Vec<usize> = keep.iter().copied().filter(|&i| i < 1000).collect();
        assert_eq!(strong, (930..1000).collect::<Vec<_>>());
        // Under the cap: everything.
        assert_eq!(grid_cap(&kps[..50], 400, 100, 100, 4).len(), 50);
    }
}
