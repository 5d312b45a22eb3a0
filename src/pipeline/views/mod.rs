//! What a run shows besides its data: the report's plots (`plots/`), the rectified site image
//! (`site.tif`, `site.png`, `site_speed.png`) and the annotated video (`annotated.mp4`).

mod annotate;
mod plots;
mod site;

use std::path::Path;

use nalgebra::{Vector2, Vector3};

use super::project::{AnalysisSection, OutputSection};
use crate::camera::Camera;
use crate::export::Trajectory;
use crate::geom::Rigid3;
use crate::progress::Progress;
use crate::terrain::HeightSurface;

pub use site::SiteAffine;

/// Why a view could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    #[error("{0}: {1}")]
    Image(String, #[source] crate::imageio::ImageError),
    #[error(transparent)]
    Video(#[from] crate::video::VideoError),
    #[error(transparent)]
    Gis(#[from] crate::gis::GisError),
    #[error("{}: {source}", path.display())]
    Io {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{0}")]
    Failed(String),
}

/// A ground control point to mark.
#[derive(Clone, Debug)]
pub struct GcpMark {
    pub name: String,
    /// Site frame, metres.
    pub local: Vector3<f64>,
    pub control: bool,
}

/// The site frame's horizontal position to the output CRS's (exact: PROJ).
pub type SiteToCrs<'b> = dyn Fn(&Vector2<f64>) -> Option<Vector2<f64>> + 'b;

/// Everything the views draw from.
pub struct Views<'a> {
    pub out: &'a Path,
    pub video: &'a Path,
    pub title: String,
    pub fps: f64,
    pub size: (u32, u32),
    /// Frames in the run.
    pub frames: usize,
    pub camera: &'a Camera,
    /// `cam_from_world` (the site frame) of each frame, by frame number.
    pub poses: &'a [Option<Rigid3>],
    pub key_frames: &'a [usize],
    pub trajs: &'a [Trajectory],
    pub gcps: Vec<GcpMark>,
    /// The ground (heads are above it).
    pub ground: &'a dyn HeightSurface,
    /// Site frame to the output CRS, near the site; None without a CRS.
    pub to_crs: Option<&'a SiteToCrs<'a>>,
    pub crs_wkt: String,
    pub crs_label: String,
    pub settings: &'a OutputSection,
    pub analysis: &'a AnalysisSection,
}

impl Views<'_> {
    /// Where a site-frame point is in frame `frame`'s image (in front of the camera).
    pub fn image_point(&self, frame: usize, local: &Vector3<f64>) -> Option<Vector2<f64>> {
        let pose = self.poses.get(frame)?.as_ref()?;
        let p = pose.apply(local);
        if p.z <= 0.0 {
            return None;
        }
        self.camera.project(&p).ok()
    }
}

/// What the views made: (title, file relative to the output folder), and warnings.
#[derive(Default)]
pub struct Made {
    pub files: Vec<(String, String)>,
    pub warnings: Vec<String>,
}

/// Makes the views the settings ask for.
pub fn make_views(v: &Views, progress: &dyn Progress) -> Result<Made, ViewError> {
    let mut made = Made::default();
    let s = v.settings;
    if s.plots {
        let dir = v.out.join("plots");
        std::fs::create_dir_all(&dir).map_err(|source| ViewError::Io {
            path: dir.clone(),
            source,
        })?;
        made.files.push(plots::speed_plot(v)?);
        made.files.push(plots::people_plot(v)?);
        made.files.push(plots::sigma_plot(v)?);
        match fundamental(v)? {
            Some(f) => made.files.extend(f),
            None => made.warnings.push(
                "no fundamental diagram: [analysis] measurement_area is not set (a convex polygon in the site frame)".into(),
            ),
        }
    }
    if s.site_image {
        let (files, warnings) = site::site_image(v)?;
        made.files.extend(files);
        made.warnings.extend(warnings);
    }
    if s.video {
        made.files.push(annotate::annotated_video(v, progress)?);
    }
    Ok(made)
}

/// The measures in the measurement area (`measures.csv`) and their plot.
fn fundamental(v: &Views) -> Result<Option<Vec<(String, String)>>, ViewError> {
    let (measurement, walkable) = v
        .analysis
        .polygons()
        .map_err(|(k, m)| ViewError::Failed(format!("[analysis] {k}: {m}")))?;
    let Some(measurement) = measurement else {
        return Ok(None);
    };
    let walkable = match walkable {
        Some(w) => w,
        None => default_walkable(v.trajs, &measurement)?,
    };
    let m = crate::analysis::measures(v.trajs, v.fps, &walkable, &measurement);
    let csv = plots::measures_csv(&m);
    crate::io::write_atomic(&v.out.join("measures.csv"), csv.as_bytes()).map_err(|source| {
        ViewError::Io {
            path: v.out.join("measures.csv"),
            source,
        }
    })?;
    Ok(Some(vec![
        plots::fundamental_plot(v, &m, measurement.area())?,
        (
            "Density and speed, frame by frame".into(),
            "measures.csv".into(),
        ),
    ]))
}

/// The trajectories' bounding box with the measurement area, 1 m wider on every side.
pub fn default_walkable(
    trajs: &[Trajectory],
    measurement: &crate::analysis::ConvexPolygon,
) -> Result<crate::analysis::ConvexPolygon, ViewError> {
    let (mut lo, mut hi) = (
        Vector2::repeat(f64::INFINITY),
        Vector2::repeat(f64::NEG_INFINITY),
    );
    let points = trajs
        .iter()
        .flat_map(|t| t.points.iter().map(|p| p.local.xy()))
        .chain(measurement.vertices().iter().copied());
    for p in points {
        lo = lo.inf(&p);
        hi = hi.sup(&p);
    }
    let (lo, hi) = (lo.add_scalar(-1.0), hi.add_scalar(1.0));
    crate::analysis::ConvexPolygon::new(vec![
        lo,
        Vector2::new(hi.x, lo.y),
        hi,
        Vector2::new(lo.x, hi.y),
    ])
    .map_err(ViewError::Failed)
}

/// A colour for `t` from 0 (dark blue) through green to 1 (yellow-red): perceptually ordered.
pub fn colour_scale(t: f64) -> [u8; 3] {
    // Stops of a viridis-like ramp, then to red for the top.
    crate::draw::ramp_colour(
        &[
            [68.0, 1.0, 84.0],
            [59.0, 82.0, 139.0],
            [33.0, 145.0, 140.0],
            [94.0, 201.0, 98.0],
            [253.0, 231.0, 37.0],
            [220.0, 50.0, 32.0],
        ],
        t,
    )
}

/// The speeds the site image's colours span: the 1st to the 99th percentile of the trajectory
/// points' speeds (at least 0.5 m/s apart), so that a stream's differences show.
pub fn speed_range(trajs: &[Trajectory]) -> (f64, f64) {
    let mut speeds: Vec<f64> = trajs
        .iter()
        .flat_map(|t| t.points.iter().map(|p| p.velocity.norm()))
        .filter(|s| s.is_finite())
        .collect();
    let lo = crate::analysis::quantile(&mut speeds, 0.01);
    let hi = crate::analysis::quantile(&mut speeds, 0.99);
    let lo = if lo.is_finite() { lo } else { 0.0 };
    (lo, hi.max(lo + 0.5))
}

/// A distinct, bright colour for an identity (golden-ratio hues).
pub fn id_colour(id: usize) -> [u8; 3] {
    let h = (id as f64 * 0.618_033_988_75).fract() * 6.0;
    let (s, v) = (0.85, 1.0);
    let c = v * s;
    let x = c * (1.0 - ((h % 2.0) - 1.0).abs());
    let (r, g, b) = match h as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    let q = |u: f64| ((u + m) * 255.0).round() as u8;
    [q(r), q(g), q(b)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours() {
        assert_eq!(colour_scale(0.0), [68, 1, 84]);
        assert_eq!(colour_scale(1.0), [220, 50, 32]);
        assert_eq!(colour_scale(f64::NAN), [68, 1, 84]);
        // Neighbouring identities differ clearly.
        for id in 0..50 {
            let (a, b) = (id_colour(id), id_colour(id + 1));
            let d: i32 = (0..3)
                .map(|k| (i32::from(a[k]) - i32::from(b[k])).abs())
                .sum();
            assert!(d > 60, "{id}: {a:?} {b:?}");
        }
    }
}
