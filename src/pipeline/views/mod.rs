//! What a run shows besides its data: the report's plots (`plots/`), the rectified site image
//! (`site.tif`, `site.png`, `site_speed.png`) and the annotated video (`annotated.mp4`).

mod annotate;
mod plots;
mod site;

use std::path::Path;

use nalgebra::{Vector2, Vector3};

use super::project::{AnalysisSection, OutputSection};
use crate::camera::Camera;
use crate::export::{Trajectory, TrajectoryPoint};
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

/// Trajectories read one at a time.
pub type TrajectoryReader<'a> = Box<dyn Iterator<Item = Result<Trajectory, ViewError>> + 'a>;

/// The trajectories the views draw from, read afresh for each pass over them, one at a time in
/// identity order: a long video's are read back from the run's cache, never all in memory.
pub trait Trajectories {
    fn count(&self) -> usize;
    fn read(&self) -> Result<TrajectoryReader<'_>, ViewError>;

    /// Gives every trajectory to `f`, in order.
    fn each(
        &self,
        f: &mut dyn FnMut(&Trajectory) -> Result<(), ViewError>,
    ) -> Result<(), ViewError> {
        for t in self.read()? {
            f(&t?)?;
        }
        Ok(())
    }

    /// Gives every point's value of `value` (None: left out) to a pass of
    /// [`crate::analysis::select_ranks`] (group 0).
    fn each_value(
        &self,
        value: &dyn Fn(&TrajectoryPoint) -> Option<f64>,
        f: &mut dyn FnMut(usize, f64),
    ) -> Result<(), ViewError> {
        self.each(&mut |t| {
            t.points.iter().filter_map(value).for_each(|x| f(0, x));
            Ok(())
        })
    }
}

impl Trajectories for Vec<Trajectory> {
    fn count(&self) -> usize {
        self.len()
    }
    fn read(&self) -> Result<TrajectoryReader<'_>, ViewError> {
        Ok(Box::new(self.iter().cloned().map(Ok)))
    }
}

/// The trajectories frame by frame, frames in order, holding only those under way: a frame is
/// given once no trajectory not yet read can have a point in it (each one's first frame is known
/// from a first pass).
pub struct FrameSweep<'a> {
    src: TrajectoryReader<'a>,
    /// The earliest first frame of the trajectories from the k-th on.
    earliest_from: Vec<usize>,
    read: usize,
    /// The trajectories under way, in identity order, each with its next point.
    pub live: Vec<(Trajectory, usize)>,
}

impl<'a> FrameSweep<'a> {
    pub fn new(trajs: &'a dyn Trajectories) -> Result<FrameSweep<'a>, ViewError> {
        let mut firsts = Vec::with_capacity(trajs.count());
        trajs.each(&mut |t| {
            firsts.push(t.points.first().map_or(usize::MAX, |p| p.frame));
            Ok(())
        })?;
        let mut earliest_from = vec![usize::MAX; firsts.len() + 1];
        for k in (0..firsts.len()).rev() {
            earliest_from[k] = earliest_from[k + 1].min(firsts[k]);
        }
        Ok(FrameSweep {
            src: trajs.read()?,
            earliest_from,
            read: 0,
            live: Vec::new(),
        })
    }

    /// The next frame with someone in it, and who: `(index into live, index of the point)`,
    /// in identity order (valid until the next call).
    pub(crate) fn next_frame(&mut self) -> Result<Option<(usize, Vec<(usize, usize)>)>, ViewError> {
        self.live.retain(|(t, next)| *next < t.points.len());
        loop {
            let frame = self.live.iter().map(|(t, k)| t.points[*k].frame).min();
            let unread = self
                .earliest_from
                .get(self.read)
                .copied()
                .unwrap_or(usize::MAX);
            match frame {
                Some(f) if f < unread => {
                    let mut who = Vec::new();
                    for (i, (t, k)) in self.live.iter_mut().enumerate() {
                        if t.points[*k].frame == f {
                            who.push((i, *k));
                            *k += 1;
                        }
                    }
                    return Ok(Some((f, who)));
                }
                _ => match self.src.next() {
                    Some(t) => {
                        let t = t?;
                        self.read += 1;
                        if !t.points.is_empty() {
                            self.live.push((t, 0));
                        }
                    }
                    None => return Ok(None),
                },
            }
        }
    }
}

/// The `qs` quantiles of the points' finite speeds (as `analysis::quantile` gives them), in a
/// few passes.
pub(crate) fn speed_quantiles(
    trajs: &dyn Trajectories,
    qs: &[f64],
) -> Result<(Vec<f64>, u64), ViewError> {
    let queries: Vec<(usize, f64)> = qs.iter().map(|&q| (0, q)).collect();
    let speed = |p: &TrajectoryPoint| Some(p.velocity.norm()).filter(|s| s.is_finite());
    let (v, counts) =
        crate::analysis::quantiles_by_passes(1, &queries, &mut |f| trajs.each_value(&speed, f))?;
    Ok((v, counts[0]))
}

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
    pub trajs: &'a dyn Trajectories,
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
    pub(crate) fn image_point(&self, frame: usize, local: &Vector3<f64>) -> Option<Vector2<f64>> {
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
pub(crate) fn make_views(v: &Views, progress: &dyn Progress) -> Result<Made, ViewError> {
    let mut made = Made::default();
    let s = v.settings;
    if s.plots {
        let dir = v.out.join("plots");
        // A killed run's temporaries go with the folder's next use.
        std::fs::create_dir_all(&dir)
            .and_then(|_| crate::io::remove_stale_temps(&dir).map(|_| ()))
            .map_err(|source| ViewError::Io {
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
        None => walkable_area(v.analysis, v.ground, v.trajs)?.polygon,
    };
    // Frame by frame, a batch of frames at a time side by side.
    let mut m = Vec::new();
    let mut batch = Vec::new();
    let mut sweep = FrameSweep::new(v.trajs)?;
    let mut measure = |batch: Vec<(usize, crate::analysis::FramePeople)>| {
        m.extend(crate::analysis::measures_of_frames(
            batch,
            v.fps,
            &walkable,
            &measurement,
        ))
    };
    while let Some((frame, who)) = sweep.next_frame()? {
        let people = who
            .iter()
            .map(|&(i, k)| {
                let p = &sweep.live[i].0.points[k];
                (p.local.xy(), p.velocity.norm())
            })
            .collect();
        batch.push((frame, people));
        if batch.len() >= 256 {
            measure(std::mem::take(&mut batch));
        }
    }
    measure(batch);
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

/// A run's walkable area and where it came from.
pub(crate) struct Walkable {
    pub polygon: crate::analysis::ConvexPolygon,
    pub source: &'static str,
}

/// The walkable area the analysis and the exports share: `[analysis] walkable_area`; else the
/// ground's outline (a deck's) where it is convex (the Voronoi cells are clipped by convex
/// areas); else the trajectories' bounding box with the measurement area, 1 m wider.
pub(crate) fn walkable_area(
    analysis: &AnalysisSection,
    ground: &dyn HeightSurface,
    trajs: &dyn Trajectories,
) -> Result<Walkable, ViewError> {
    let (measurement, given) = analysis
        .polygons()
        .map_err(|(k, m)| ViewError::Failed(format!("[analysis] {k}: {m}")))?;
    if let Some(polygon) = given {
        return Ok(Walkable {
            polygon,
            source: "[analysis] walkable_area",
        });
    }
    let outline = ground
        .outline()
        .and_then(|o| crate::analysis::ConvexPolygon::new(o).ok())
        .filter(|o| {
            measurement
                .as_ref()
                .is_none_or(|m| m.vertices().iter().all(|v| o.contains(v)))
        });
    if let Some(polygon) = outline {
        return Ok(Walkable {
            polygon,
            source: "the deck's outline",
        });
    }
    Ok(Walkable {
        polygon: default_walkable(trajs, measurement.as_ref())?,
        source: "the trajectories' extent, 1 m wider",
    })
}

/// The trajectories' bounding box with the measurement area, 1 m wider on every side.
pub(crate) fn default_walkable(
    trajs: &dyn Trajectories,
    measurement: Option<&crate::analysis::ConvexPolygon>,
) -> Result<crate::analysis::ConvexPolygon, ViewError> {
    let (mut lo, mut hi) = (
        Vector2::repeat(f64::INFINITY),
        Vector2::repeat(f64::NEG_INFINITY),
    );
    trajs.each(&mut |t| {
        for p in &t.points {
            lo = lo.inf(&p.local.xy());
            hi = hi.sup(&p.local.xy());
        }
        Ok(())
    })?;
    for p in measurement.iter().flat_map(|m| m.vertices()) {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let (lo, hi) = (lo.add_scalar(-1.0), hi.add_scalar(1.0));
    crate::analysis::ConvexPolygon::new(vec![
        lo,
        Vector2::new(hi.x, lo.y),
        hi,
        Vector2::new(lo.x, hi.y),
    ])
    .map_err(|e| ViewError::Failed(e.to_string()))
}

/// A colour for `t` from 0 (dark blue) through green to 1 (yellow-red): perceptually ordered.
pub(crate) fn colour_scale(t: f64) -> [u8; 3] {
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
pub(crate) fn speed_range(trajs: &dyn Trajectories) -> Result<(f64, f64), ViewError> {
    let (q, _) = speed_quantiles(trajs, &[0.01, 0.99])?;
    let (lo, hi) = (q[0], q[1]);
    let lo = if lo.is_finite() { lo } else { 0.0 };
    Ok((lo, hi.max(lo + 0.5)))
}

/// A distinct, bright colour for an identity (golden-ratio hues).
pub(crate) fn id_colour(id: usize) -> [u8; 3] {
    let hue = (id as f64 * 0.618_033_988_75).fract();
    crate::image::hsv_to_rgb(hue, 0.85, 1.0).map(|u| (u * 255.0).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trajectory(id: usize, frames: &[usize]) -> Trajectory {
        Trajectory {
            id,
            height_m: 1.7,
            height_source: "default".into(),
            points: frames
                .iter()
                .map(|&f| TrajectoryPoint {
                    frame: f,
                    time_s: f as f64,
                    local: Vector3::new(id as f64, f as f64, 0.0),
                    crs: Vector3::zeros(),
                    velocity: Vector2::zeros(),
                    sigma_m: Vector2::zeros(),
                    cov: Default::default(),
                    observed: true,
                    score: Some(0.9),
                })
                .collect(),
        }
    }

    #[test]
    fn the_walkable_area_is_the_projects_else_the_decks_outline_else_the_extent() {
        use crate::terrain::{DeckProfile, Plane, VerticalAlignment};
        let trajs = vec![trajectory(2, &[0, 5]), trajectory(4, &[3])];
        let deck = DeckProfile {
            centre_line: vec![Vector2::new(-10.0, 2.0), Vector2::new(10.0, 2.0)],
            start_s: 0.0,
            width_m: 6.0,
            alignment: VerticalAlignment::Stations(vec![(0.0, 0.0), (20.0, 0.0)]),
        };
        let plane = Plane::from_gradient(0.0, 0.0, 0.0);
        let given = AnalysisSection {
            walkable_area: vec![[0.0, 0.0], [5.0, 0.0], [5.0, 5.0]],
            ..Default::default()
        };
        let w = walkable_area(&given, &deck, &trajs).unwrap();
        assert_eq!(
            (w.source, w.polygon.area()),
            ("[analysis] walkable_area", 12.5)
        );
        let none = AnalysisSection::default();
        let w = walkable_area(&none, &deck, &trajs).unwrap();
        assert_eq!((w.source, w.polygon.area()), ("the deck's outline", 120.0));
        // A measurement area off the deck: the outline cannot hold it.
        let off = AnalysisSection {
            measurement_area: vec![[0.0, 8.0], [1.0, 8.0], [1.0, 9.0]],
            ..Default::default()
        };
        let w = walkable_area(&off, &deck, &trajs).unwrap();
        assert_eq!(w.source, "the trajectories' extent, 1 m wider");
        // x from 0 to 4 (the area and the points), y from 0 to 9, each 1 m wider.
        assert!(
            (w.polygon.area() - 6.0 * 11.0).abs() < 1e-9,
            "{}",
            w.polygon.area()
        );
        let w = walkable_area(&none, &plane, &trajs).unwrap();
        assert!(
            (w.polygon.area() - 4.0 * 7.0).abs() < 1e-9,
            "{}",
            w.polygon.area()
        );
        assert!(walkable_area(&none, &plane, &Vec::<Trajectory>::new()).is_err());
    }

    #[test]
    fn the_frame_sweep_gives_every_point_frame_by_frame_holding_only_those_under_way() {
        // In identity order; the third starts before the second (its first detections were
        // not projected), one is empty, one is a single point, one has a gap.
        let trajs = vec![
            trajectory(1, &[0, 1, 2, 3]),
            trajectory(2, &[5, 6, 7]),
            trajectory(3, &[2, 3, 4, 5, 6]),
            trajectory(4, &[]),
            trajectory(5, &[6]),
            trajectory(6, &[9, 10, 12]),
        ];
        let mut by_frame: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
        for t in &trajs {
            for p in &t.points {
                by_frame.entry(p.frame).or_default().push(t.id);
            }
        }
        let mut sweep = FrameSweep::new(&trajs).unwrap();
        let mut got = std::collections::BTreeMap::new();
        let mut most_held = 0;
        while let Some((frame, who)) = sweep.next_frame().unwrap() {
            let ids: Vec<usize> = who
                .iter()
                .map(|&(i, k)| {
                    let t = &sweep.live[i].0;
                    assert_eq!(t.points[k].frame, frame);
                    t.id
                })
                .collect();
            assert!(got.insert(frame, ids).is_none(), "frame {frame} twice");
            most_held = most_held.max(sweep.live.len());
        }
        assert_eq!(got, by_frame);
        // Never all six at once.
        assert!(most_held <= 4, "{most_held} held");
    }

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
