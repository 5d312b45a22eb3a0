//! The BAL format (Bundle Adjustment in the Large, Agarwal et al. 2010) and its camera (pure):
//! reader, writer, and the projection (its analytic Jacobians are [`BalIntrinsics`]'s).
//!
//! A BAL camera is nine numbers: a rotation as an angle-axis vector `w`, a translation `t`, a
//! focal length `f` and two radial distortion coefficients `k1`, `k2`. A point `X` projects as
//! `P = R(w)·X + t`, `p = −P.xy / P.z` (the camera looks down −z), `d = 1 + k1‖p‖² + k2‖p‖⁴`,
//! `u = f·d·p`, in pixels from the image centre with y up. The cost of a problem is
//! `½ Σ ‖u − observed‖²`, as Ceres reports it.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{SMatrix, Vector2, Vector3};

use super::ba::{BaError, BaSettings, BaSummary, Observation, Priors, Problem, Projection, adjust};
use crate::geom::so3::rotation;
use crate::io::{FileCtx, FileError};

/// One image measurement in BAL form (the engine's own).
pub type BalObservation = Observation;

/// A bundle adjustment problem in BAL form.
#[derive(Clone, Debug, PartialEq)]
pub struct BalProblem {
    /// Per camera: `[wx, wy, wz, tx, ty, tz, f, k1, k2]`.
    pub cameras: Vec<[f64; 9]>,
    pub points: Vec<[f64; 3]>,
    pub observations: Vec<BalObservation>,
}

/// Where a BAL camera sees a point, pixels.
pub fn project(camera: &[f64; 9], point: &[f64; 3]) -> Vector2<f64> {
    let w = Vector3::new(camera[0], camera[1], camera[2]);
    let p_cam =
        rotation(&w) * Vector3::from(*point) + Vector3::new(camera[3], camera[4], camera[5]);
    BalIntrinsics::pixel(&[camera[6], camera[7], camera[8]], &p_cam)
}

/// The BAL camera's intrinsic part (`f`, `k1`, `k2`) for the bundle adjustment engine.
pub struct BalIntrinsics;

impl BalIntrinsics {
    /// The same arithmetic as `project_with_jacobians`: the same bits.
    fn pixel(k: &[f64; 3], p_cam: &Vector3<f64>) -> Vector2<f64> {
        let iz = 1.0 / p_cam.z;
        let p = Vector2::new(-p_cam.x * iz, -p_cam.y * iz);
        let r2 = p.norm_squared();
        k[0] * (1.0 + k[1] * r2 + k[2] * r2 * r2) * p
    }
}

impl Projection<3> for BalIntrinsics {
    fn project(&self, k: &[f64; 3], p_cam: &Vector3<f64>) -> Option<Vector2<f64>> {
        Some(Self::pixel(k, p_cam))
    }

    fn project_with_jacobians(
        &self,
        k: &[f64; 3],
        p_cam: &Vector3<f64>,
    ) -> Option<(Vector2<f64>, SMatrix<f64, 2, 3>, SMatrix<f64, 2, 3>)> {
        let [f, k1, k2] = *k;
        let iz = 1.0 / p_cam.z;
        let p = Vector2::new(-p_cam.x * iz, -p_cam.y * iz);
        let r2 = p.norm_squared();
        let d = 1.0 + k1 * r2 + k2 * r2 * r2;
        // u = f d(p) p: ∂u/∂p = f (d I + 2 (k1 + 2 k2 r²) p pᵀ); p = −P.xy / P.z.
        let du_dp = f
            * (nalgebra::Matrix2::identity() * d + 2.0 * (k1 + 2.0 * k2 * r2) * p * p.transpose());
        let dp_dpc =
            SMatrix::<f64, 2, 3>::new(-iz, 0.0, p_cam.x * iz * iz, 0.0, -iz, p_cam.y * iz * iz);
        let mut j_intr = SMatrix::<f64, 2, 3>::zeros();
        j_intr.set_column(0, &(d * p));
        j_intr.set_column(1, &(f * r2 * p));
        j_intr.set_column(2, &(f * r2 * r2 * p));
        Some((Self::pixel(k, p_cam), du_dp * dp_dpc, j_intr))
    }
}

impl BalProblem {
    /// The problem for the engine: a pose and intrinsics per camera, nothing fixed.
    pub fn to_problem(&self) -> Problem<3> {
        Problem::new(
            self.cameras
                .iter()
                .map(|c| [c[0], c[1], c[2], c[3], c[4], c[5]])
                .collect(),
            self.cameras.iter().map(|c| [c[6], c[7], c[8]]).collect(),
            (0..self.cameras.len()).collect(),
            self.points.clone(),
            self.observations.clone(),
        )
    }

    /// Takes the cameras and points of an adjusted [`Self::to_problem`].
    pub fn update_from(&mut self, q: &Problem<3>) {
        for (i, c) in self.cameras.iter_mut().enumerate() {
            c[..6].copy_from_slice(&q.poses[i]);
            c[6..].copy_from_slice(&q.intrinsics[q.intrinsics_of[i]]);
        }
        self.points.clone_from(&q.points);
    }

    /// `½ Σ ‖u − observed‖²`, the cost as Ceres reports it.
    pub fn cost(&self) -> f64 {
        0.5 * self
            .observations
            .iter()
            .map(|o| {
                (project(&self.cameras[o.camera], &self.points[o.point]) - Vector2::from(o.xy))
                    .norm_squared()
            })
            .sum::<f64>()
    }
}

/// Adjusts a BAL problem's cameras and points in place.
pub fn bundle_adjust(p: &mut BalProblem, settings: &BaSettings) -> Result<BaSummary, BaError> {
    let mut q = p.to_problem();
    let summary = adjust(&mut q, &BalIntrinsics, &Priors::default(), settings)?;
    p.update_from(&q);
    Ok(summary)
}

/// Reads a BAL file (whitespace-separated numbers; line breaks do not matter).
pub fn read_bal(path: &Path) -> Result<BalProblem, FileError> {
    let text = FileCtx { path }.read_text("a BAL bundle adjustment problem")?;
    parse_bal(path, &text)
}

/// The whitespace-separated tokens of a file, with their line numbers.
struct Tokens<'a> {
    ctx: FileCtx<'a>,
    iter: Box<dyn Iterator<Item = (usize, &'a str)> + 'a>,
    last_line: usize,
}

impl<'a> Tokens<'a> {
    fn next(&mut self, what: &str) -> Result<(usize, &'a str), FileError> {
        self.iter.next().ok_or_else(|| {
            self.ctx.at(
                self.last_line,
                format!(
                    "the file ends where {what} was expected (a BAL file: header, observations, cameras, points)"
                ),
            )
        })
    }

    fn count(&mut self, what: &str) -> Result<usize, FileError> {
        let (line, t) = self.next(what)?;
        t.parse::<usize>().map_err(|_| {
            self.ctx.err(
                Some(line),
                Some(what),
                format!(
                    "expected a whole number, found '{}'",
                    crate::io::clip(t, 40)
                ),
            )
        })
    }

    fn number(&mut self, what: &str) -> Result<(usize, f64), FileError> {
        let (line, t) = self.next(what)?;
        Ok((line, self.ctx.number(t, line, what)?))
    }
}

/// Parses the text of a BAL file; errors name the line and what was expected there.
pub fn parse_bal(path: &Path, text: &str) -> Result<BalProblem, FileError> {
    let ctx = FileCtx { path };
    let mut tokens = Tokens {
        ctx,
        iter: Box::new(
            text.lines()
                .enumerate()
                .flat_map(|(i, l)| l.split_whitespace().map(move |t| (i + 1, t))),
        ),
        last_line: text.lines().count().max(1),
    };
    let (nc, np, no) = (
        tokens.count("number of cameras")?,
        tokens.count("number of points")?,
        tokens.count("number of observations")?,
    );
    if nc == 0 || np == 0 || no == 0 {
        return Err(ctx.at(
            1,
            format!("the header says {nc} cameras, {np} points, {no} observations: none may be 0"),
        ));
    }
    // Each number takes two bytes at least: no more room is reserved than the file can fill.
    let room = text.len() / 2 + 1;
    let mut observations = Vec::with_capacity(no.min(room / 4));
    for k in 0..no {
        let camera = tokens.count("camera index")?;
        let point = tokens.count("point index")?;
        let (_, x) = tokens.number("x")?;
        let (ly, y) = tokens.number("y")?;
        if camera >= nc || point >= np {
            return Err(ctx.at(
                ly,
                format!(
                    "observation {k}: camera {camera} of {nc} or point {point} of {np} does not exist (indices start at 0)"
                ),
            ));
        }
        observations.push(BalObservation {
            camera,
            point,
            xy: [x, y],
        });
    }
    // A point seen twice by one camera is a duplicated row (sorted, to keep memory low).
    let mut pairs: Vec<(usize, usize, usize)> = observations
        .iter()
        .enumerate()
        .map(|(k, o)| (o.camera, o.point, k))
        .collect();
    pairs.sort_unstable();
    if let Some(w) = pairs
        .windows(2)
        .find(|w| (w[0].0, w[0].1) == (w[1].0, w[1].1))
    {
        return Err(ctx.err(
            None,
            Some("observations"),
            format!(
                "observations {} and {} are both of point {} in camera {}: each camera sees a point once",
                w[0].2.min(w[1].2),
                w[0].2.max(w[1].2),
                w[0].1,
                w[0].0
            ),
        ));
    }
    drop(pairs);
    const CAMERA: [&str; 9] = ["wx", "wy", "wz", "tx", "ty", "tz", "f", "k1", "k2"];
    let mut cameras = Vec::with_capacity(nc.min(room / 9));
    for c in 0..nc {
        let mut cam = [0.0; 9];
        for (v, name) in cam.iter_mut().zip(CAMERA) {
            *v = tokens.number(&format!("camera {c} {name}"))?.1;
        }
        cameras.push(cam);
    }
    let mut points = Vec::with_capacity(np.min(room / 3));
    for p in 0..np {
        let mut x = [0.0; 3];
        for (v, name) in x.iter_mut().zip(["X", "Y", "Z"]) {
            *v = tokens.number(&format!("point {p} {name}"))?.1;
        }
        points.push(x);
    }
    if let Some((line, t)) = tokens.iter.next() {
        return Err(ctx.at(
            line,
            format!(
                "'{}' after the last point: the header's counts do not match the file",
                crate::io::clip(t, 40)
            ),
        ));
    }
    Ok(BalProblem {
        cameras,
        points,
        observations,
    })
}

/// The BAL text of a problem (full precision).
pub fn bal_text(p: &BalProblem) -> String {
    let mut s = String::with_capacity(40 * (p.observations.len() + 9 * p.cameras.len()));
    let _ = writeln!(
        s,
        "{} {} {}",
        p.cameras.len(),
        p.points.len(),
        p.observations.len()
    );
    for o in &p.observations {
        let _ = writeln!(s, "{} {} {:e} {:e}", o.camera, o.point, o.xy[0], o.xy[1]);
    }
    for c in &p.cameras {
        for v in c {
            let _ = writeln!(s, "{v:e}");
        }
    }
    for x in &p.points {
        for v in x {
            let _ = writeln!(s, "{v:e}");
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    fn numeric(camera: &[f64; 9], point: &[f64; 3]) -> (SMatrix<f64, 2, 9>, SMatrix<f64, 2, 3>) {
        let mut jc = SMatrix::<f64, 2, 9>::zeros();
        let mut jp = SMatrix::<f64, 2, 3>::zeros();
        for k in 0..9 {
            let h = 1e-6 * camera[k].abs().max(1e-3);
            let (mut a, mut b) = (*camera, *camera);
            a[k] += h;
            b[k] -= h;
            jc.set_column(k, &((project(&a, point) - project(&b, point)) / (2.0 * h)));
        }
        for k in 0..3 {
            let h = 1e-6 * point[k].abs().max(1e-3);
            let (mut a, mut b) = (*point, *point);
            a[k] += h;
            b[k] -= h;
            jp.set_column(
                k,
                &((project(camera, &a) - project(camera, &b)) / (2.0 * h)),
            );
        }
        (jc, jp)
    }

    #[test]
    fn jacobians_agree_with_finite_differences() {
        let cases = [
            (
                [
                    0.0157, -0.0128, -0.0044, -0.034, -0.107, 1.12, 399.75, -3.2e-7, 5.9e-13,
                ],
                [-0.612, 0.572, -1.847],
            ),
            // A larger rotation and strong distortion.
            (
                [0.9, -0.4, 1.3, 0.2, -0.1, -4.0, 800.0, -0.2, 0.05],
                [0.3, -0.2, 1.0],
            ),
            // No rotation at all: the small-angle branch.
            (
                [0.0, 0.0, 0.0, 0.1, 0.2, -3.0, 500.0, 0.01, -0.001],
                [0.5, 0.4, 0.7],
            ),
        ];
        for (cam, pt) in cases {
            let q = BalProblem {
                cameras: vec![cam],
                points: vec![pt],
                observations: vec![BalObservation {
                    camera: 0,
                    point: 0,
                    xy: [0.0, 0.0],
                }],
            }
            .to_problem();
            let (u, j_pose, j_intr, jp) =
                crate::optim::ba::linearise(&q, &BalIntrinsics, &q.observations[0]).unwrap();
            let mut jc = SMatrix::<f64, 2, 9>::zeros();
            jc.fixed_view_mut::<2, 6>(0, 0).copy_from(&j_pose);
            jc.fixed_view_mut::<2, 3>(0, 6).copy_from(&j_intr);
            assert!((u - project(&cam, &pt)).norm() < 1e-12);
            let (nc, np) = numeric(&cam, &pt);
            for (a, n) in jc.iter().zip(nc.iter()).chain(jp.iter().zip(np.iter())) {
                // Central differences of a projection of a few hundred pixels: about 1e-5.
                assert!(
                    (a - n).abs() <= 2e-5 * (1.0 + n.abs()),
                    "{jc}\n{nc}\n{jp}\n{np}"
                );
            }
        }
        // Rodrigues against the first-order branch's limit.
        let w = Vector3::new(1e-9, -2e-9, 3e-9);
        assert!((rotation(&w) - (Matrix3::identity() + w.cross_matrix())).norm() < 1e-17);
        let r = rotation(&Vector3::new(0.3, -0.2, 0.5));
        assert!((r * r.transpose() - Matrix3::identity()).norm() < 1e-14);
    }

    #[test]
    fn reads_and_writes_bal_and_names_bad_lines() {
        let path = Path::new("tiny.txt");
        let text = "2 1 2\n0 0 -1.5 2.5\n1 0 3.0e1 -4\n0 0 0 0 0 -5 500 0 0\n0.1 0 0 1 0 -5 500 0 0\n0.1 0.2 0.3";
        let p = parse_bal(path, text).unwrap();
        assert_eq!(
            (p.cameras.len(), p.points.len(), p.observations.len()),
            (2, 1, 2)
        );
        assert_eq!(p.observations[1].xy, [30.0, -4.0]);
        assert_eq!(p.cameras[1][0], 0.1);
        let again = parse_bal(path, &bal_text(&p)).unwrap();
        assert_eq!(again, p);
        let err = |t: &str| parse_bal(path, t).unwrap_err().to_string();
        assert!(err("2 1 2\n0 0 -1.5 2.5\n1 0 x -4\n").contains("tiny.txt:3: field 'x'"));
        assert!(err("2 1 2\n0 0 -1.5 2.5\n2 0 3 -4\n").contains("camera 2 of 2"));
        assert!(err("2 1 2\n0 0 -1.5 2.5\n").contains("ends where"));
        assert!(err(&format!("{text} 7")).contains("after the last point"));
        assert!(err("0 1 2\n").contains("none may be 0"));
        assert!(err("9999999999 1 2\n0 0 1 2\n").contains("ends where camera index"));
    }
}
