//! Coded targets (ArUco and AprilTag markers): their dictionaries, which surveyed point each id
//! names, and a marker's centre refined to a fraction of a pixel from its four border edges
//! (pure; the markers are found and decoded by the OpenCV adapter, `aruco_cv`).

use std::collections::BTreeMap;

use nalgebra::{Matrix2, Vector2, Vector3};

use super::{Candidate, Gray};

/// A marker dictionary: the name `--dictionary` takes, OpenCV's number for it, the marker's
/// cells across (without the black border) and how many ids it has.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dictionary {
    pub name: &'static str,
    pub opencv_id: i32,
    pub cells: u8,
    pub ids: u32,
}

const fn dict(name: &'static str, opencv_id: i32, cells: u8, ids: u32) -> Dictionary {
    Dictionary {
        name,
        opencv_id,
        cells,
        ids,
    }
}

/// Every dictionary geostride reads: OpenCV's predefined ones.
pub const DICTIONARIES: [Dictionary; 21] = [
    dict("4x4_50", 0, 4, 50),
    dict("4x4_100", 1, 4, 100),
    dict("4x4_250", 2, 4, 250),
    dict("4x4_1000", 3, 4, 1000),
    dict("5x5_50", 4, 5, 50),
    dict("5x5_100", 5, 5, 100),
    dict("5x5_250", 6, 5, 250),
    dict("5x5_1000", 7, 5, 1000),
    dict("6x6_50", 8, 6, 50),
    dict("6x6_100", 9, 6, 100),
    dict("6x6_250", 10, 6, 250),
    dict("6x6_1000", 11, 6, 1000),
    dict("7x7_50", 12, 7, 50),
    dict("7x7_100", 13, 7, 100),
    dict("7x7_250", 14, 7, 250),
    dict("7x7_1000", 15, 7, 1000),
    dict("aruco_original", 16, 5, 1024),
    dict("apriltag_16h5", 17, 4, 30),
    dict("apriltag_25h9", 18, 5, 35),
    dict("apriltag_36h10", 19, 6, 2320),
    dict("apriltag_36h11", 20, 6, 587),
];

impl std::str::FromStr for Dictionary {
    type Err = String;
    fn from_str(s: &str) -> Result<Dictionary, String> {
        let key = s.trim().to_ascii_lowercase();
        DICTIONARIES
            .iter()
            .find(|d| d.name == key)
            .copied()
            .ok_or_else(|| {
                let names: Vec<&str> = DICTIONARIES.iter().map(|d| d.name).collect();
                format!("unknown dictionary '{s}': one of {}", names.join(", "))
            })
    }
}

/// A marker's cells, row by row from its top-left (north-west) cell, black as 1: `cells`²
/// bits, the border left out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MarkerCells {
    pub cells: u8,
    pub bits: u64,
}

impl MarkerCells {
    /// Whether the cell at `row`, `col` is black.
    pub fn black(&self, row: usize, col: usize) -> bool {
        let n = self.cells as usize;
        (self.bits >> (row * n + col)) & 1 == 1
    }
}

/// A decoded marker: its id and its outer corners (the black border's), in the detector's
/// order (clockwise in the image from the marker's own top-left).
#[derive(Clone, Debug, PartialEq)]
pub struct Marker {
    pub id: u32,
    pub corners: [Vector2<f64>; 4],
}

/// A code table or a marker that cannot be used.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CodeError {
    #[error("line {line}: {message}")]
    Line { line: usize, message: String },
    #[error("no 'id,name' line")]
    Empty,
    #[error("id {id} is not in dictionary {dictionary} (ids 0 to {last})")]
    NotInDictionary {
        id: u32,
        dictionary: &'static str,
        last: u32,
    },
    #[error("{0}")]
    UnknownDictionary(String),
    #[error(transparent)]
    Read(#[from] crate::io::FileError),
    #[error("{}: {error}", path.display())]
    In {
        path: std::path::PathBuf,
        error: Box<CodeError>,
    },
    #[error("drawing marker {id} of {dictionary}: {message}")]
    Draw {
        id: u32,
        dictionary: &'static str,
        message: String,
    },
}

/// Which surveyed point each marker id is.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CodeTable {
    pub names: BTreeMap<u32, String>,
}

impl CodeTable {
    /// Without a table: id `n` is the point named `n`, else the one point whose name ends in
    /// the number `n` ("GCP7", "T07").
    pub fn from_names(names: &[String]) -> CodeTable {
        let mut by_number: BTreeMap<u32, Vec<&String>> = BTreeMap::new();
        for name in names {
            let digits: String = name
                .chars()
                .rev()
                .take_while(char::is_ascii_digit)
                .collect::<Vec<_>>()
                .into_iter()
                .rev()
                .collect();
            if let Ok(n) = digits.parse::<u32>() {
                by_number.entry(n).or_default().push(name);
            }
        }
        let mut table = CodeTable::default();
        for (n, found) in by_number {
            let exact = found.iter().find(|s| s.as_str() == n.to_string());
            match (exact, found.as_slice()) {
                (Some(s), _) | (None, [s]) => {
                    table.names.insert(n, (*s).clone());
                }
                _ => {}
            }
        }
        table
    }

    /// The table in the file at `path` (see [`CodeTable::parse`]); errors name the file.
    pub fn read(
        path: &std::path::Path,
        names: &[String],
        dictionary: &Dictionary,
    ) -> Result<CodeTable, CodeError> {
        let text = crate::io::FileCtx { path }.read_small_text("a code table", 1 << 20)?;
        CodeTable::parse(&text, names, dictionary).map_err(|e| CodeError::In {
            path: path.to_path_buf(),
            error: Box::new(e),
        })
    }

    /// A table from CSV text (`id,name` a line; a header line and `#` comments allowed), every
    /// name checked against the surveyed `names` and every id against the dictionary. Errors
    /// name the line.
    pub fn parse(
        text: &str,
        names: &[String],
        dictionary: &Dictionary,
    ) -> Result<CodeTable, CodeError> {
        let mut table = CodeTable::default();
        for (i, raw) in text.lines().enumerate() {
            let line = i + 1;
            let at = |message: String| Err(CodeError::Line { line, message });
            let row = raw.trim();
            if row.is_empty() || row.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = row.split(',').map(str::trim).collect();
            if fields.len() != 2 {
                return at(format!(
                    "expected 'id,name' (two fields), got {} field(s)",
                    fields.len()
                ));
            }
            let Ok(id) = fields[0].parse::<u32>() else {
                if table.names.is_empty() && line == first_line(text) {
                    continue; // a header
                }
                return at(format!("id '{}' is not a whole number from 0", fields[0]));
            };
            if id >= dictionary.ids {
                return at(CodeError::NotInDictionary {
                    id,
                    dictionary: dictionary.name,
                    last: dictionary.ids - 1,
                }
                .to_string());
            }
            let name = fields[1];
            if !names.iter().any(|n| n == name) {
                return at(format!(
                    "'{name}' is not a point of the survey (it has {}); fix the name or add the \
                     point",
                    preview(names)
                ));
            }
            if let Some((other, _)) = table.names.iter().find(|(_, n)| n.as_str() == name) {
                return at(format!(
                    "'{name}' is already id {other}; a point has one marker"
                ));
            }
            if table.names.insert(id, name.to_string()).is_some() {
                return at(format!("id {id} is given twice"));
            }
        }
        if table.names.is_empty() {
            return Err(CodeError::Empty);
        }
        Ok(table)
    }
}

fn first_line(text: &str) -> usize {
    text.lines()
        .position(|l| !l.trim().is_empty() && !l.trim().starts_with('#'))
        .map_or(0, |i| i + 1)
}

fn preview(names: &[String]) -> String {
    let shown: Vec<&str> = names.iter().take(6).map(String::as_str).collect();
    if names.len() > shown.len() {
        format!("{}, … ({} in all)", shown.join(", "), names.len())
    } else {
        shown.join(", ")
    }
}

/// The marker's centre: each border edge is found again to a fraction of a pixel (the
/// gradient's peak across it at many places along it, a line fitted through them), the corners
/// are the lines' crossings and the centre the diagonals' (which a perspective view keeps). σ
/// is the spread of the centre over the edges' fits (their residuals through the crossing, and
/// a shift of a whole edge that no fit sees). `None` when an edge cannot be found.
pub fn refine(img: &Gray, m: &Marker) -> Option<Candidate> {
    let c = &m.corners;
    let side = (0..4)
        .map(|k| (c[(k + 1) % 4] - c[k]).norm())
        .fold(f64::MAX, f64::min);
    if !(side >= 8.0) {
        return None;
    }
    let mut lines = Vec::with_capacity(4);
    for k in 0..4 {
        lines.push(edge_line(img, &c[k], &c[(k + 1) % 4])?);
    }
    let corners: Vec<Vector2<f64>> = (0..4)
        .map(|k| cross(&lines[(k + 3) % 4].line, &lines[k].line))
        .collect::<Option<_>>()?;
    // A refined corner far from the detector's means an edge was taken for another.
    if corners
        .iter()
        .zip(c)
        .any(|(a, b)| (a - b).norm() > 0.15 * side + 2.0)
    {
        return None;
    }
    let centre_of = |l: &[Vector3<f64>]| -> Option<Vector2<f64>> {
        let q: Vec<Vector2<f64>> = (0..4)
            .map(|k| cross(&l[(k + 3) % 4], &l[k]))
            .collect::<Option<_>>()?;
        diagonals(&q)
    };
    let base: Vec<Vector3<f64>> = lines.iter().map(|l| l.line).collect();
    let centre = centre_of(&base)?;
    // Each line's offset moved by its σ: the centre's covariance, summed over the four.
    let mut cov = Matrix2::zeros();
    for k in 0..4 {
        let mut moved = base.clone();
        moved[k].z -= lines[k].offset_sd_px;
        let d = centre_of(&moved)? - centre;
        cov += d * d.transpose();
    }
    let sigma = (cov.trace() / 2.0).sqrt();
    let contrast = lines.iter().map(|l| l.contrast).fold(f64::MAX, f64::min);
    let d0 = corners[2] - corners[0];
    Some(Candidate {
        uv: centre,
        sigma_px: sigma,
        contrast,
        size_px: side,
        white_angle_rad: d0.y.atan2(d0.x),
    })
}

/// A border edge as a line `a x + b y = c` (unit normal `(a, b)` pointing out of the marker,
/// `z` holds c), the σ of its offset and the grey levels across it.
struct Edge {
    line: Vector3<f64>,
    offset_sd_px: f64,
    contrast: f64,
}

/// The border edge from `p` to `q` (the marker on its right in the image, as the detector's
/// clockwise order puts it): at points along its middle 80 %, the peak of the intensity's
/// derivative across it, to a fraction of a pixel by a parabola; a line fitted through them.
fn edge_line(img: &Gray, p: &Vector2<f64>, q: &Vector2<f64>) -> Option<Edge> {
    let along = (q - p).try_normalize(1e-9)?;
    let len = (q - p).norm();
    // Out of the marker: the detector goes clockwise (rows down), so the outside is on the left.
    let out = Vector2::new(along.y, -along.x);
    let reach = (0.12 * len).clamp(2.0, 6.0);
    let n = ((0.8 * len) as usize).clamp(6, 200);
    let mut pts = Vec::with_capacity(n);
    let mut levels = (0.0, 0.0);
    for i in 0..n {
        let t = 0.1 + 0.8 * (i as f64 + 0.5) / n as f64;
        let base = p + (q - p) * t;
        // The profile across the edge, every quarter pixel.
        let steps = (2.0 * reach / 0.25) as usize + 1;
        let prof: Vec<f64> = (0..steps)
            .map(|s| {
                let d = -reach + 0.25 * s as f64;
                let x = base + out * d;
                img.sample(x.x, x.y) as f64
            })
            .collect();
        // Dark inside, light outside: the derivative's largest positive peak.
        let (mut best, mut at) = (0.0, 0);
        for s in 1..steps - 1 {
            let g = prof[s + 1] - prof[s - 1];
            if g > best {
                (best, at) = (g, s);
            }
        }
        if at < 2 || at + 2 >= steps || best <= 0.0 {
            continue;
        }
        let g = |s: usize| prof[s + 1] - prof[s - 1];
        let (l, m, r) = (g(at - 1), g(at), g(at + 1));
        let den = l - 2.0 * m + r;
        let shift = if den < 0.0 { 0.5 * (l - r) / den } else { 0.0 };
        let d = -reach + 0.25 * (at as f64 + shift.clamp(-1.0, 1.0));
        pts.push(base + out * d);
        levels.0 += prof[0];
        levels.1 += prof[steps - 1];
    }
    if pts.len() < n / 2 || pts.len() < 5 {
        return None;
    }
    let k = pts.len() as f64;
    let contrast = (levels.1 - levels.0) / k;
    let mean = pts.iter().sum::<Vector2<f64>>() / k;
    let offsets: Vec<f64> = pts.iter().map(|x| out.dot(&(x - mean))).collect();
    let ts: Vec<f64> = pts.iter().map(|x| along.dot(&(x - mean))).collect();
    // Offset across the edge as a straight function of the distance along it.
    let stt: f64 = ts.iter().map(|t| t * t).sum();
    let slope = ts.iter().zip(&offsets).map(|(t, o)| t * o).sum::<f64>() / stt.max(1e-9);
    let intercept = offsets.iter().sum::<f64>() / k;
    let resid: f64 = ts
        .iter()
        .zip(&offsets)
        .map(|(t, o)| (o - intercept - slope * t).powi(2))
        .sum::<f64>();
    let sd = (resid / (k - 2.0).max(1.0)).sqrt();
    // The points' scatter averages down along the edge; what the sampling, the image's
    // compression and the print do to the whole edge does not: 0.15 px of it.
    const EDGE_SHIFT_PX: f64 = 0.15;
    let dir = (along + out * slope).normalize();
    let normal = Vector2::new(dir.y, -dir.x);
    let point = mean + out * intercept;
    Some(Edge {
        line: Vector3::new(normal.x, normal.y, normal.dot(&point)),
        offset_sd_px: (sd / k.sqrt()).hypot(EDGE_SHIFT_PX),
        contrast,
    })
}

/// Where two lines `a x + b y = c` cross.
fn cross(l1: &Vector3<f64>, l2: &Vector3<f64>) -> Option<Vector2<f64>> {
    let m = Matrix2::new(l1.x, l1.y, l2.x, l2.y);
    m.try_inverse().map(|inv| inv * Vector2::new(l1.z, l2.z))
}

/// Where a quadrilateral's diagonals cross.
fn diagonals(q: &[Vector2<f64>]) -> Option<Vector2<f64>> {
    let line = |a: &Vector2<f64>, b: &Vector2<f64>| {
        let d = (b - a).try_normalize(1e-12)?;
        let n = Vector2::new(-d.y, d.x);
        Some(Vector3::new(n.x, n.y, n.dot(a)))
    };
    cross(&line(&q[0], &q[2])?, &line(&q[1], &q[3])?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn ids_name_points_by_their_number_or_a_table() {
        let n = names(&["GCP1", "GCP2", "7", "T07", "A3", "B3"]);
        let t = CodeTable::from_names(&n);
        assert_eq!(t.names.get(&1).map(String::as_str), Some("GCP1"));
        // "7" exactly wins over "T07"; 3 is ambiguous (A3, B3) and left out.
        assert_eq!(t.names.get(&7).map(String::as_str), Some("7"));
        assert_eq!(t.names.get(&3), None);
        let d: Dictionary = "4x4_50".parse().unwrap();
        let t = CodeTable::parse("id,name\n# comment\n4, GCP2\n9,A3\n", &n, &d).unwrap();
        assert_eq!(t.names.len(), 2);
        let bad = |text: &str| CodeTable::parse(text, &n, &d).unwrap_err().to_string();
        assert!(
            bad("1,GCP9\n").contains("line 1: 'GCP9' is not a point"),
            "{}",
            bad("1,GCP9\n")
        );
        assert!(bad("1,GCP1\n2,GCP1\n").contains("line 2"));
        assert!(bad("1,GCP1\n1,GCP2\n").contains("id 1 is given twice"));
        assert!(bad("60,GCP1\n").contains("not in dictionary 4x4_50"));
        assert!(bad("1,GCP1,x\n").contains("two fields"));
        assert!(bad("id,name\nx,GCP1\n").contains("line 2: id 'x'"));
        assert!("4x4_51".parse::<Dictionary>().is_err());
    }

    /// A marker drawn with anti-aliased edges under a projective map: the centre back within
    /// a few hundredths of a pixel, σ stated alike.
    #[test]
    fn the_centre_is_refined_from_the_border_edges() {
        let (w, h) = (160usize, 140usize);
        // Image from marker coordinates (0..1 square): a homography.
        let hm = nalgebra::Matrix3::new(70.0, 12.0, 40.0, -8.0, 66.0, 35.0, 0.0006, 0.0009, 1.0);
        let inv = hm.try_inverse().unwrap();
        let mut pixels = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        let p = inv
                            * Vector3::new(
                                x as f64 + (sx as f64 + 0.5) / 4.0 - 0.5,
                                y as f64 + (sy as f64 + 0.5) / 4.0 - 0.5,
                                1.0,
                            );
                        let (u, v) = (p.x / p.z, p.y / p.z);
                        let inside = (0.0..1.0).contains(&u) && (0.0..1.0).contains(&v);
                        // The inner cells: a white square in the middle.
                        let inner = (0.35..0.65).contains(&u) && (0.35..0.65).contains(&v);
                        acc += if inside && !inner { 20.0 } else { 220.0 };
                    }
                }
                pixels[y * w + x] = acc / 16.0;
            }
        }
        let img = Gray {
            width: w,
            height: h,
            pixels,
        };
        let at = |u: f64, v: f64| {
            let p = hm * Vector3::new(u, v, 1.0);
            Vector2::new(p.x / p.z, p.y / p.z)
        };
        let truth = diagonals(&[at(0.0, 0.0), at(1.0, 0.0), at(1.0, 1.0), at(0.0, 1.0)]).unwrap();
        // The detector's corners, a pixel off each.
        let jitter = [(0.8, -0.6), (-0.7, 0.9), (0.6, 0.7), (-0.9, -0.5)];
        let corners: [Vector2<f64>; 4] = std::array::from_fn(|k| {
            let (u, v) = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)][k];
            at(u, v) + Vector2::new(jitter[k].0, jitter[k].1)
        });
        let c = refine(&img, &Marker { id: 3, corners }).unwrap();
        let err = (c.uv - truth).norm();
        assert!(err < 0.05, "centre {:?} truth {truth:?}: {err:.3} px", c.uv);
        assert!((0.05..=0.15).contains(&c.sigma_px), "{}", c.sigma_px);
        assert!(c.contrast > 150.0, "{}", c.contrast);
    }
}
