//! One image's GCP targets found and named: the layout designs (checker, X, cross) identified
//! from their layout, coded markers by their ids. Shared by `geostride gcp find`, the picking
//! page and `[picks] auto = true`.

use nalgebra::Vector2;

use super::codes::{CodeTable, Dictionary};
use super::{
    Gray, Identification, LayoutSettings, Rejected, TargetSettings, find_targets,
    identify_by_layout,
};

/// What to look for, and the surveyed points to name.
#[derive(Clone, Debug)]
pub struct Search {
    /// The surveyed points' names and ground positions (east, north), in one order.
    pub names: Vec<String>,
    pub ground: Vec<Vector2<f64>>,
    pub targets: TargetSettings,
    pub layout: LayoutSettings,
    /// Whether designs told apart by their layout are looked for (checker, X, cross).
    pub by_layout: bool,
    /// Coded markers: their dictionary and which point each id is.
    pub coded: Option<(Dictionary, CodeTable)>,
}

/// A target found.
#[derive(Clone, Debug, PartialEq)]
pub struct Found {
    pub uv: Vector2<f64>,
    pub sigma_px: f64,
    pub contrast: f64,
    pub size_px: f64,
    /// The surveyed point it is (an index into [`Search::names`]), when identified.
    pub point: Option<usize>,
    /// Its residual against the layout's homography (layout designs).
    pub residual_px: Option<f64>,
    /// A coded marker's id.
    pub code: Option<u32>,
}

/// One image's outcome.
#[derive(Clone, Debug, Default)]
pub struct Outcome {
    pub found: Vec<Found>,
    /// The identified ones (indices into `found`) in the order they were named: the markers
    /// as detected, then the layout's assignment.
    pub named: Vec<usize>,
    /// Why nothing was identified, when so.
    pub not_identified: Option<String>,
    pub rejected: Vec<Rejected>,
}

impl Search {
    /// The targets of one image, and which point each is: coded markers by their ids, the
    /// other designs by their layout (a point a marker named keeps the marker's pick).
    pub fn run(&self, gray: &Gray) -> Outcome {
        let (mut found, mut rejected) = self.coded_targets(gray);
        let (mut laid, refused) = if self.by_layout {
            find_targets(gray, &self.targets)
        } else {
            Default::default()
        };
        rejected.extend(refused);
        // A marker's cells make saddles of their own: what lies on a marker is the marker.
        let on_marker =
            |uv: &Vector2<f64>| found.iter().any(|t| (t.uv - uv).norm() < 0.8 * t.size_px);
        laid.retain(|c| !on_marker(&c.uv));
        rejected.retain(|r| !on_marker(&r.uv));
        let coded = found.len();
        let mut named: Vec<usize> = (0..coded).filter(|&k| found[k].point.is_some()).collect();
        let by_code = named.len();
        let centres: Vec<(Vector2<f64>, f64)> = laid.iter().map(|c| (c.uv, c.sigma_px)).collect();
        found.extend(laid.iter().map(|c| Found {
            uv: c.uv,
            sigma_px: c.sigma_px,
            contrast: c.contrast,
            size_px: c.size_px,
            point: None,
            residual_px: None,
            code: None,
        }));
        let mut why = None;
        if !centres.is_empty() {
            match identify_by_layout(&self.ground, &centres, &self.layout) {
                Identification::Found { identified, .. } => {
                    for i in &identified {
                        if found[..coded].iter().any(|t| t.point == Some(i.point)) {
                            continue;
                        }
                        let t = &mut found[coded + i.target];
                        t.point = Some(i.point);
                        t.residual_px = Some(i.residual_px);
                        named.push(coded + i.target);
                    }
                }
                Identification::NotIdentified(w) => why = Some(w),
            }
        } else if by_code == 0 {
            why = Some("no target found".to_string());
        }
        Outcome {
            not_identified: if named.is_empty() { why } else { None },
            found,
            named,
            rejected,
        }
    }

    /// The coded markers of one image, each named by its id when the table has it; refused
    /// places with why.
    fn coded_targets(&self, gray: &Gray) -> (Vec<Found>, Vec<Rejected>) {
        let (mut found, mut rejected) = (Vec::new(), Vec::new());
        let Some((dictionary, table)) = &self.coded else {
            return (found, rejected);
        };
        let markers = match detect_markers(gray, dictionary, self.targets.min_size_px) {
            Ok(m) => m,
            Err(e) => {
                rejected.push(Rejected {
                    uv: Vector2::zeros(),
                    reason: e,
                });
                return (found, rejected);
            }
        };
        for m in &markers {
            let centre = m.corners.iter().sum::<Vector2<f64>>() / 4.0;
            let Some(c) = super::codes::refine(gray, m) else {
                rejected.push(Rejected {
                    uv: centre,
                    reason: format!("marker {}: its border edges are not clear", m.id),
                });
                continue;
            };
            let point = table
                .names
                .get(&m.id)
                .and_then(|n| self.names.iter().position(|p| p == n));
            let reason = if point.is_none() {
                Some(format!("marker {} names no surveyed point", m.id))
            } else if markers.iter().filter(|o| o.id == m.id).count() > 1 {
                // The same id twice: neither can be trusted.
                Some(format!("marker {} is seen more than once", m.id))
            } else {
                None
            };
            if let Some(reason) = reason {
                rejected.push(Rejected { uv: c.uv, reason });
                continue;
            }
            found.push(Found {
                uv: c.uv,
                sigma_px: c.sigma_px,
                contrast: c.contrast,
                size_px: c.size_px,
                point,
                residual_px: None,
                code: Some(m.id),
            });
        }
        (found, rejected)
    }
}

#[cfg(feature = "opencv")]
fn detect_markers(
    gray: &Gray,
    d: &Dictionary,
    min_side_px: f64,
) -> Result<Vec<super::codes::Marker>, String> {
    super::aruco_cv::detect_markers(gray, d, min_side_px)
        .map_err(|e| format!("the marker detector failed: {e}"))
}

#[cfg(not(feature = "opencv"))]
fn detect_markers(_: &Gray, _: &Dictionary, _: f64) -> Result<Vec<super::codes::Marker>, String> {
    Err("coded markers are decoded by OpenCV, which this build leaves out".into())
}
