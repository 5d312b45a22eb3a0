//! A standing person's ground position from the box around the whole body, in any view (pure).
//!
//! The person is a vertical body on the ground surface, so the box lies along the image of the
//! vertical through them. The box's end away from the nadir's image is the body's top, its end
//! toward it the feet; each end, reached out by the body's horizontal extent seen along the
//! view, says where the person stands along that axis, and the box's centre says where across
//! it. The feet need no height and dominate in oblique views; the top carries the height's
//! error, scaled by the distance over the camera's height above the head, and dominates near
//! nadir, where the feet end is the limbs' reach as much as the feet. Solved by Gauss-Newton in
//! the ground position (and the height, when asked), with the covariance of each source.

use nalgebra::{Matrix2, Matrix6, Vector2, Vector3, Vector6};

use super::WorldPoint;
use crate::camera::Camera;
use crate::geom::Rigid3;
use crate::terrain::HeightSurface;

/// How far a body box reaches beyond the body's vertical axis, metres.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BodyShape {
    /// Seen from above: the limbs' reach at both ends of the box (a runner's swinging arms and
    /// legs).
    pub reach_m: f64,
    /// Seen from the side: the head's radius above the top of the head.
    pub head_radius_m: f64,
    /// Seen from the side: how far the box's bottom lies before the person's ground point (the
    /// nearer foot).
    pub feet_radius_m: f64,
    /// σ of where the feet are under the body (the stride), metres.
    pub feet_sd_m: f64,
}

impl BodyShape {
    /// The reach at the top and at the feet for a view `off_nadir_deg` from straight down:
    /// within 5° the limbs' reach bounds both ends, beyond 25° the head and the feet do, and
    /// between the two blend smoothly. (Seen `θ` off nadir, a point `d` below the head shows
    /// `d tan θ` nearer the feet: the shoulders, 0.25 m below the head and about 0.1 m wider,
    /// stop bounding the top near 20°, the hands, 0.8 m above the feet, the bottom sooner.
    /// Checked on the simulator's silhouettes 15°, 30° and 60° below the horizon.)
    pub fn reach_at(&self, off_nadir_deg: f64) -> (f64, f64) {
        let t = ((off_nadir_deg - 5.0) / 20.0).clamp(0.0, 1.0);
        let side = t * t * (3.0 - 2.0 * t);
        (
            self.reach_m + (self.head_radius_m - self.reach_m) * side,
            self.reach_m + (self.feet_radius_m - self.reach_m) * side,
        )
    }
}

/// Which ends of a box the image shows: an end cut by the image border says nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ends {
    pub top: bool,
    pub feet: bool,
}

/// One box's solution.
#[derive(Clone, Debug, PartialEq)]
pub struct BodyFix {
    /// The head's position (the ground point raised by the height) and its covariances.
    pub point: WorldPoint,
    /// The height the box says (only when asked, and both ends are seen).
    pub height: Option<BoxHeight>,
}

/// A person's height as one box says it, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxHeight {
    pub height_m: f64,
    /// From the box's pixel error, and the prior: random from box to box.
    pub var_random_m2: f64,
    /// From the body's reach (`REACH_SD_M` at each end): the same body in every box, so it
    /// does not average out over a track.
    pub var_shape_m2: f64,
}

/// σ of how far a body reaches beyond its axis, at either end of its box, metres: the body's
/// shape, which differs from person to person.
pub const REACH_SD_M: f64 = 0.1;

/// The camera, pose and surface a box is read against.
pub struct View<'a> {
    pub camera: &'a Camera,
    pub cam_from_world: &'a Rigid3,
    /// The pose increment's covariance (`pose::refine` convention), when known.
    pub pose_cov: Option<&'a Matrix6<f64>>,
    pub surface: &'a dyn HeightSurface,
    /// The frame's size, pixels.
    pub image_wh: (f64, f64),
}

/// What a box says, set up around a first guess: the axis, the ends along it, the centre
/// across it and each one's σ.
struct Setup {
    axis: Vector2<f64>,
    across: Vector2<f64>,
    far: f64,
    near: f64,
    centre_across: f64,
    reach_top_m: f64,
    reach_feet_m: f64,
    /// Pixels per metre of ground moved along the axis, at the top and at the feet.
    scale_top: f64,
    scale_feet: f64,
    /// Whitens the residuals (across, the top's, the feet's, those seen): the inverse of the
    /// Cholesky factor of their covariance, px.
    white: nalgebra::DMatrix<f64>,
    ends: Ends,
}

/// A box's error, px².
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxError {
    /// Of where the box is: shared by its centre and both its ends (a tracker's smoothed
    /// position's covariance, or a detection's).
    pub position_px2: Matrix2<f64>,
    /// Of the box's length along the body, at its feet end on its own (the top is where the
    /// position is taken: a head's error is the position's).
    pub length_px2: f64,
}

impl View<'_> {
    fn image(&self, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        self.camera.project(&self.cam_from_world.apply(p)).ok()
    }

    fn image_with(&self, pose: &Rigid3, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        self.camera.project(&pose.apply(p)).ok()
    }

    /// Which ends of `bbox`, along `axis` (from the feet to the top), touch the image border.
    pub fn ends_seen(&self, bbox: &[f64; 4], axis: &Vector2<f64>) -> Ends {
        // A detector's edges are a pixel or two off: within 1.5 px is touching.
        let tol = 1.5;
        let (w, h) = self.image_wh;
        let cut = |d: Vector2<f64>| {
            (d.x < -0.2 && bbox[0] <= tol)
                || (d.y < -0.2 && bbox[1] <= tol)
                || (d.x > 0.2 && bbox[0] + bbox[2] >= w - 1.0 - tol)
                || (d.y > 0.2 && bbox[1] + bbox[3] >= h - 1.0 - tol)
        };
        Ends {
            top: !cut(*axis),
            feet: !cut(-axis),
        }
    }
}

/// `[x, y, w, h]`'s centre.
fn box_centre(bbox: &[f64; 4]) -> Vector2<f64> {
    Vector2::new(bbox[0] + bbox[2] / 2.0, bbox[1] + bbox[3] / 2.0)
}

/// The ground position of the person boxed by `bbox`: `height` is the head's height above the
/// ground with its σ (systematic for a person), `error` the box's pixel error. With `estimate_height` and both ends seen the height is solved for too, `height`
/// then its prior. None when the box's rays miss the ground or neither end is seen.
pub fn ground_from_box(
    view: &View,
    shape: &BodyShape,
    bbox: &[f64; 4],
    error: &BoxError,
    height: (f64, f64),
    estimate_height: bool,
) -> Option<BodyFix> {
    let (h0, h_sd) = height;
    let start = super::intersect(
        view.camera,
        view.cam_from_world,
        view.surface,
        h0 / 2.0,
        &box_centre(bbox),
    )?
    .xy();
    let pose = view.cam_from_world;
    let prior = |free: bool, x: &Vector3<f64>| free.then(|| (x.z - h0) / h_sd);
    // Set up around the box's centre, solve, then again around that solution (the axis, the
    // scales and the reach depend on where the person is).
    let mut x = Vector3::new(start.x, start.y, h0);
    let mut last = None;
    for _ in 0..2 {
        let s = setup(view, shape, bbox, error, &x)?;
        let free = estimate_height && s.ends.top && s.ends.feet && h_sd > 0.0;
        x = gauss_newton(if free { 3 } else { 2 }, x, |y| {
            let mut r = s.residuals(view, pose, y, 0.0)?;
            r.extend(prior(free, y));
            Some(r)
        })?;
        last = Some((s, free));
    }
    let (s, free_height) = last?;
    let n = if free_height { 3 } else { 2 };
    let residuals = |pose: &Rigid3, x: &Vector3<f64>, dz: f64| -> Option<Vec<f64>> {
        let mut r = s.residuals(view, pose, x, dz)?;
        r.extend(prior(free_height, x));
        Some(r)
    };
    let j = jacobian(n, &x, &|y: &Vector3<f64>| residuals(pose, y, 0.0))?;
    let info = j.transpose() * &j;
    let cov = info.clone().try_inverse()?;
    let jg = j.columns(0, 2).into_owned();
    let info_g = jg.transpose() * &jg;
    let cov_g = info_g.clone().try_inverse()?;
    // How the solution moves with what is held fixed: the height (when not solved for), the
    // ground's height and the pose, each through the residuals' sensitivity to it.
    let moved_by = |dr: nalgebra::DVector<f64>| -> Vector2<f64> {
        let v = -(&cov_g * (jg.transpose() * dr));
        Vector2::new(v[0], v[1])
    };
    let diff = |f: &dyn Fn(f64) -> Option<Vec<f64>>, step: f64| -> Option<nalgebra::DVector<f64>> {
        let (a, b) = (f(step)?, f(-step)?);
        Some(nalgebra::DVector::from_iterator(
            a.len(),
            a.iter().zip(&b).map(|(p, q)| (p - q) / (2.0 * step)),
        ))
    };
    let ground = Vector2::new(x.x, x.y);
    let ground_sd_m = view.surface.height_sigma(&ground).unwrap_or(0.0);
    let mut cov_height = Matrix2::zeros();
    if !free_height && h_sd > 0.0 {
        let g = moved_by(diff(
            &|d| residuals(pose, &Vector3::new(x.x, x.y, x.z + d), 0.0),
            0.01,
        )?);
        cov_height += g * g.transpose() * (h_sd * h_sd);
    }
    if ground_sd_m > 0.0 {
        let g = moved_by(diff(&|d| residuals(pose, &x, d), 0.01)?);
        cov_height += g * g.transpose() * (ground_sd_m * ground_sd_m);
    }
    // The joint solution's spread split by where it comes from: `(JᵀJ)⁻¹ Jᵢᵀ Jᵢ (JᵀJ)⁻¹` for
    // the box's pixel rows (random from frame to frame) and for the height prior's last row
    // (the person's, the same in every frame).
    let cov_pixel = if free_height {
        let rows = j.nrows();
        let part = |a: usize, n: usize| -> Matrix2<f64> {
            let ji = j.rows(a, n);
            let m = &cov * (ji.transpose() * ji) * &cov;
            m.fixed_view::<2, 2>(0, 0).into_owned()
        };
        cov_height += part(rows - 1, 1);
        part(0, rows - 1)
    } else {
        cov_g.fixed_view::<2, 2>(0, 0).into_owned()
    };
    let cov_pose = match view.pose_cov {
        Some(pc) => {
            let mut jp = nalgebra::Matrix2x6::zeros();
            for k in 0..6 {
                let step = if k < 3 { 1e-6 } else { 1e-4 };
                let dr = diff(
                    &|d| {
                        let mut v = Vector6::zeros();
                        v[k] = d;
                        residuals(&pose.plus(&v), &x, 0.0)
                    },
                    step,
                )?;
                jp.set_column(k, &moved_by(dr));
            }
            jp * pc * jp.transpose()
        }
        None => Matrix2::zeros(),
    };
    let z = view.surface.height(&ground)? + x.z;
    Some(BodyFix {
        point: WorldPoint {
            position: Vector3::new(x.x, x.y, z),
            cov_pixel,
            cov_height,
            cov_pose,
        },
        height: free_height.then(|| {
            // How the height moves with each end's reach: dx = -cov Jᵀ dr.
            let by_reach = |row: usize, dr_px: f64| {
                let mut raw = nalgebra::DVector::zeros(3);
                raw[row] = dr_px;
                let mut dr = nalgebra::DVector::zeros(j.nrows());
                dr.rows_mut(0, 3).copy_from(&(&s.white * raw));
                -(&cov * (j.transpose() * dr))[2]
            };
            // Residual rows: across, the top's, the feet's (both ends are seen here).
            let top = by_reach(1, s.scale_top);
            let feet = by_reach(2, -s.scale_feet);
            // Those moves are damped by the prior as much as the box's own height is: undone,
            // so that the shape's share is the box's alone, as `combine_heights` takes it.
            let damping = (1.0 - cov[(2, 2)] / (h_sd * h_sd)).max(1e-6);
            BoxHeight {
                height_m: x.z,
                var_random_m2: cov[(2, 2)],
                var_shape_m2: (top * top + feet * feet) * REACH_SD_M * REACH_SD_M
                    / (damping * damping),
            }
        }),
    })
}

/// Minimises `|f|²` over the first `n` unknowns of `x`, from `x`.
fn gauss_newton(
    n: usize,
    mut x: Vector3<f64>,
    f: impl Fn(&Vector3<f64>) -> Option<Vec<f64>>,
) -> Option<Vector3<f64>> {
    for _ in 0..12 {
        let r0 = nalgebra::DVector::from_vec(f(&x)?);
        let j = jacobian(n, &x, &f)?;
        let step = (j.transpose() * &j).lu().solve(&-(j.transpose() * r0))?;
        for k in 0..n {
            x[k] += step[k];
        }
        if step.rows(0, 2).norm() < 1e-6 {
            return Some(x);
        }
    }
    None
}

/// The numerical Jacobian of `f` in the first `n` unknowns of `x` (metres: 1 mm steps).
fn jacobian(
    n: usize,
    x: &Vector3<f64>,
    f: &impl Fn(&Vector3<f64>) -> Option<Vec<f64>>,
) -> Option<nalgebra::DMatrix<f64>> {
    let m = f(x)?.len();
    let mut j = nalgebra::DMatrix::zeros(m, n);
    for k in 0..n {
        let mut a = *x;
        let mut b = *x;
        a[k] += 1e-3;
        b[k] -= 1e-3;
        let (ra, rb) = (f(&a)?, f(&b)?);
        for i in 0..m {
            j[(i, k)] = (ra[i] - rb[i]) / 2e-3;
        }
    }
    Some(j)
}

/// The box read around a first guess of where the person stands.
fn setup(
    view: &View,
    shape: &BodyShape,
    bbox: &[f64; 4],
    error: &BoxError,
    guess: &Vector3<f64>,
) -> Option<Setup> {
    if !(bbox[2] > 0.0 && bbox[3] > 0.0) {
        return None;
    }
    let c = box_centre(bbox);
    let (g, h0) = (guess.xy(), guess.z);
    let z0 = view.surface.height(&g)?;
    let feet = Vector3::new(g.x, g.y, z0);
    let top = Vector3::new(g.x, g.y, z0 + h0);
    let (uf, ut) = (view.image(&feet)?, view.image(&top)?);
    let axis = (ut - uf).try_normalize(1e-9)?;
    let across = Vector2::new(-axis.y, axis.x);
    // Pixels per metre moved on the ground along the axis: |Jᵀa| of the ground-to-image map.
    let scale = |p: &Vector3<f64>| -> Option<f64> {
        let mut jt = Vector2::zeros();
        for k in 0..2 {
            let mut d = Vector3::zeros();
            d[k] = 0.01;
            jt[k] = axis.dot(&(view.image(&(p + d))? - view.image(&(p - d))?)) / 0.02;
        }
        Some(jt.norm())
    };
    let (scale_top, scale_feet) = (scale(&top)?, scale(&feet)?);
    // How far from straight down the camera sees the person.
    let ray = feet - view.cam_from_world.centre();
    let off_nadir_deg = (ray.xy().norm()).atan2(-ray.z).to_degrees();
    let (reach_top_m, reach_feet_m) = shape.reach_at(off_nadir_deg);
    let half = axis.x.abs() * bbox[2] / 2.0 + axis.y.abs() * bbox[3] / 2.0;
    let (far, near) = (axis.dot(&c) + half, axis.dot(&c) - half);
    let ends = view.ends_seen(bbox, &axis);
    if !(ends.top || ends.feet) {
        return None;
    }
    // The rows' directions in the image: the position's error moves them all.
    let mut dirs = vec![across];
    let mut own = vec![0.0];
    if ends.top {
        dirs.push(axis);
        // A little of its own, so that the two ends are never one measurement.
        own.push(0.1);
    }
    if ends.feet {
        dirs.push(axis);
        own.push(error.length_px2 + (shape.feet_sd_m * scale_feet).powi(2));
    }
    let n = dirs.len();
    let mut cov = nalgebra::DMatrix::zeros(n, n);
    for i in 0..n {
        for k in 0..n {
            cov[(i, k)] = (dirs[i].transpose() * error.position_px2 * dirs[k])[0];
        }
        cov[(i, i)] += own[i];
    }
    let white = cov.cholesky()?.l().try_inverse()?;
    Some(Setup {
        axis,
        across,
        far,
        near,
        centre_across: across.dot(&c),
        reach_top_m,
        reach_feet_m,
        scale_top,
        scale_feet,
        white,
        ends,
    })
}

impl Setup {
    /// Whitened residuals of the ends seen and the centre across, for a person at `x` (east,
    /// north, height) seen from `pose`, with the ground raised by `dz`.
    fn residuals(&self, view: &View, pose: &Rigid3, x: &Vector3<f64>, dz: f64) -> Option<Vec<f64>> {
        let z0 = view.surface.height(&x.xy())? + dz;
        let at = |z: f64| view.image_with(pose, &Vector3::new(x.x, x.y, z));
        let (feet, top) = (at(z0)?, at(z0 + x.z)?);
        let mid = at(z0 + x.z / 2.0)?;
        let mut r = Vec::with_capacity(3);
        r.push(self.across.dot(&mid) - self.centre_across);
        if self.ends.top {
            r.push(self.axis.dot(&top) + self.reach_top_m * self.scale_top - self.far);
        }
        if self.ends.feet {
            r.push(self.axis.dot(&feet) - self.reach_feet_m * self.scale_feet - self.near);
        }
        Some(
            (&self.white * nalgebra::DVector::from_vec(r))
                .as_slice()
                .to_vec(),
        )
    }
}

/// A person's height from what each of their boxes says, with the prior `(height, σ)`: the
/// boxes' heights weighted by their random variance (each box's prior taken out), their shape
/// variance added once (it is the same body in every box), then the prior. The height and its
/// σ, metres.
pub fn combine_heights(prior: (f64, f64), boxes: &[BoxHeight]) -> (f64, f64) {
    let prior_info = 1.0 / prior.1.powi(2);
    let (mut num, mut den) = (0.0, 0.0);
    let mut shape = Vec::new();
    for b in boxes {
        let (h, var) = (b.height_m, b.var_random_m2);
        if !(var.is_finite() && var > 0.0 && h.is_finite() && b.var_shape_m2.is_finite()) {
            continue;
        }
        // Each box's solution includes the prior once; take it out.
        let info = 1.0 / var - prior_info;
        if info <= 0.0 {
            continue;
        }
        num += (h / var - prior.0 * prior_info) / info * info;
        den += info;
        shape.push(b.var_shape_m2);
    }
    if den <= 0.0 {
        return prior;
    }
    shape.sort_by(f64::total_cmp);
    let var_boxes = 1.0 / den + shape[shape.len() / 2];
    let info = prior_info + 1.0 / var_boxes;
    (
        (prior.0 * prior_info + num / den / var_boxes) / info,
        info.sqrt().recip(),
    )
}

/// How much more a person's boxes' heights scatter than their pixel error explains, m²: the
/// heights' sample variance less their mean random variance, at least 0. On real footage a
/// box's ends move with posture and with the detector's own fit from frame to frame, which no
/// pixel error model states. `None` with fewer than 5 boxes.
pub fn excess_height_var(boxes: &[BoxHeight]) -> Option<f64> {
    if boxes.len() < 5 {
        return None;
    }
    let n = boxes.len() as f64;
    let mean = boxes.iter().map(|b| b.height_m).sum::<f64>() / n;
    let var = boxes
        .iter()
        .map(|b| (b.height_m - mean).powi(2))
        .sum::<f64>()
        / (n - 1.0);
    let random = boxes.iter().map(|b| b.var_random_m2).sum::<f64>() / n;
    Some((var - random).max(0.0)).filter(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::Plane;
    use nalgebra::Rotation3;

    const SHAPE: BodyShape = BodyShape {
        reach_m: 0.55,
        head_radius_m: 0.1,
        feet_radius_m: 0.1,
        feet_sd_m: 0.0,
    };

    /// A camera at `centre` looking `depression_deg` below the horizon toward +north.
    fn looking_north(centre: Vector3<f64>, depression_deg: f64) -> Rigid3 {
        let t = depression_deg.to_radians();
        // Camera axes in the world: x east, y down the image, z forward.
        let z = Vector3::new(0.0, t.cos(), -t.sin());
        let x = Vector3::new(1.0, 0.0, 0.0);
        let y = z.cross(&x);
        let world_from_cam = nalgebra::Matrix3::from_columns(&[x, y, z]);
        let rotation = Rotation3::from_matrix_unchecked(world_from_cam.transpose());
        Rigid3 {
            rotation,
            translation: -(rotation * centre),
        }
    }

    /// The view of a 480×360 camera with an exact pose over `plane`.
    fn side_view<'a>(camera: &'a Camera, pose: &'a Rigid3, plane: &'a Plane) -> View<'a> {
        View {
            camera,
            cam_from_world: pose,
            pose_cov: None,
            surface: plane,
            image_wh: (480.0, 360.0),
        }
    }

    /// The box a body of `shape` makes standing at `g`, its top `h` m up: a cylinder of the
    /// reach at its two ends, the bounding box of its points' images.
    fn body_box(v: &View, g: Vector2<f64>, h: f64) -> [f64; 4] {
        let ray = Vector3::new(g.x, g.y, 0.0) - v.cam_from_world.centre();
        let off = ray.xy().norm().atan2(-ray.z).to_degrees();
        let (rt, rf) = SHAPE.reach_at(off);
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for (z, r) in [(0.0, rf), (h, rt)] {
            for k in 0..72 {
                let a = f64::from(k) * 5f64.to_radians();
                let p = Vector3::new(g.x + r * a.cos(), g.y + r * a.sin(), z);
                let uv = v.image(&p).unwrap();
                b = [
                    b[0].min(uv.x),
                    b[1].min(uv.y),
                    b[2].max(uv.x),
                    b[3].max(uv.y),
                ];
            }
        }
        [b[0], b[1], b[2] - b[0], b[3] - b[1]]
    }

    /// The box's position 1 px σ each way, its length at the feet 1 px σ.
    const UNIT: BoxError = BoxError {
        position_px2: Matrix2::new(1.0, 0.0, 0.0, 1.0),
        length_px2: 1.0,
    };

    #[test]
    fn a_box_gives_the_ground_point_seen_obliquely_and_from_above() {
        let camera = Camera::pinhole(740.0, 746.0, 240.0, 180.0);
        let plane = Plane::from_gradient(0.0, 0.0, 0.0);
        let oblique = looking_north(Vector3::new(0.0, 0.0, 7.0), 15.0);
        let above = looking_north(Vector3::new(0.0, 0.0, 30.0), 90.0);
        for (pose, g) in [
            (&oblique, Vector2::new(1.0, 25.0)),
            (&oblique, Vector2::new(-3.0, 18.0)),
            // From above, along the image's rows and columns: along a diagonal the box's corner
            // lies beyond the round body (the reach is what boxes reach, as fitted).
            (&above, Vector2::new(8.0, 0.0)),
            (&above, Vector2::new(0.0, -6.0)),
        ] {
            let v = side_view(&camera, pose, &plane);
            let bbox = body_box(&v, g, 1.7);
            let fix = ground_from_box(&v, &SHAPE, &bbox, &UNIT, (1.7, 0.1), false).unwrap();
            let err = (fix.point.position.xy() - g).norm();
            // The box is the bounding box of a shape, the model its ends: a few mm apart.
            assert!(err < 0.02, "{g}: {} off by {err}", fix.point.position);
            assert!((fix.point.position.z - 1.7).abs() < 1e-9);
            // A wrong height moves the point little from above, a lot from the side, and the
            // height's covariance says so.
            let wrong = ground_from_box(&v, &SHAPE, &bbox, &UNIT, (1.6, 0.1), false).unwrap();
            let moved = (wrong.point.position.xy() - fix.point.position.xy()).norm();
            let said = fix.point.cov_height.trace().sqrt();
            assert!(
                (moved - said).abs() < 0.3 * said + 0.005,
                "{g}: {moved} vs {said}"
            );
        }
    }

    #[test]
    fn seen_from_the_side_both_ends_give_the_height_and_a_cut_end_is_left_out() {
        let camera = Camera::pinhole(740.0, 746.0, 240.0, 180.0);
        let plane = Plane::from_gradient(0.0, 0.0, 0.0);
        let pose = looking_north(Vector3::new(0.0, 0.0, 7.0), 15.0);
        let v = side_view(&camera, &pose, &plane);
        let g = Vector2::new(1.0, 22.0);
        let bbox = body_box(&v, g, 1.85);
        // A loose prior: the box decides.
        let fix = ground_from_box(&v, &SHAPE, &bbox, &UNIT, (1.7, 1.0), true).unwrap();
        let b = fix.height.unwrap();
        assert!((b.height_m - 1.85).abs() < 0.01, "{b:?}");
        assert!(b.var_random_m2 > 0.0 && b.var_random_m2 < 0.01, "{b:?}");
        // Seen from the side, a body's reach hardly moves its height: its top is its head.
        assert!(b.var_shape_m2.sqrt() < 0.05, "{b:?}");
        // From above it would: the track's height then stays near the prior.
        let above = looking_north(Vector3::new(0.0, 0.0, 30.0), 90.0);
        let va = View {
            cam_from_world: &above,
            ..v
        };
        let g2 = Vector2::new(8.0, 5.0);
        let from_above = ground_from_box(
            &va,
            &SHAPE,
            &body_box(&va, g2, 1.85),
            &UNIT,
            (1.7, 0.1),
            true,
        )
        .unwrap()
        .height
        .unwrap();
        assert!(from_above.var_shape_m2.sqrt() > 0.1, "{from_above:?}");
        let (h, sd) = combine_heights((1.7, 0.1), &vec![from_above; 200]);
        assert!((h - 1.7).abs() < 0.08 && sd > 0.07, "{h} {sd}");
        let (h, sd) = combine_heights((1.7, 0.1), &vec![b; 200]);
        assert!((h - 1.85).abs() < 0.02 && sd < 0.05, "{h} {sd}");
        assert!((fix.point.position.xy() - g).norm() < 0.02);
        // With the height wrong and fixed, the point moves, and its height covariance says by
        // about how much.
        let fixed = ground_from_box(&v, &SHAPE, &bbox, &UNIT, (1.7, 0.1), false).unwrap();
        let moved = (fixed.point.position.xy() - g).norm();
        let said = fixed.point.cov_height.trace().sqrt() * 1.5 * 1.1;
        assert!(moved < said, "{moved} vs 0.15 m of height: {said}");
        // A nearer person whose feet are below the image: the box's bottom is the border, and
        // the top alone, at the given height, places them.
        let g = Vector2::new(0.5, 12.0);
        let mut cut = body_box(&v, g, 1.85);
        assert!(cut[1] + cut[3] > 360.0);
        cut[3] = 359.5 - cut[1];
        assert_eq!(
            v.ends_seen(&cut, &Vector2::new(0.0, -1.0)),
            Ends {
                top: true,
                feet: false
            }
        );
        let top_only = ground_from_box(&v, &SHAPE, &cut, &UNIT, (1.85, 0.1), true).unwrap();
        assert!(top_only.height.is_none());
        let err = (top_only.point.position.xy() - g).norm();
        assert!(err < 0.02, "{err}");
    }

    #[test]
    fn the_pixel_covariance_matches_the_spread_of_noisy_boxes() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let camera = Camera::pinhole(740.0, 746.0, 240.0, 180.0);
        let plane = Plane::from_gradient(0.0, 0.0, 0.0);
        let pose = looking_north(Vector3::new(0.0, 0.0, 7.0), 15.0);
        let v = side_view(&camera, &pose, &plane);
        let g = Vector2::new(2.0, 20.0);
        let bbox = body_box(&v, g, 1.7);
        let fix = ground_from_box(&v, &SHAPE, &bbox, &UNIT, (1.7, 0.0), false).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let mut gauss = || normal.sample(&mut rng);
        let n = 2000;
        let mut sum = Matrix2::zeros();
        for _ in 0..n {
            // The box moves by 1 px σ each way, its top by a little of its own (0.1 px²) and
            // its bottom by 1 px σ more, as `UNIT` and the model say.
            let (dx, dy, top, bottom) = (gauss(), gauss(), 0.1f64.sqrt() * gauss(), gauss());
            let b = [
                bbox[0] + dx,
                bbox[1] + dy + top,
                bbox[2],
                bbox[3] - top + bottom,
            ];
            let p = ground_from_box(&v, &SHAPE, &b, &UNIT, (1.7, 0.0), false).unwrap();
            let d = p.point.position.xy() - fix.point.position.xy();
            sum += d * d.transpose();
        }
        let empirical = sum / f64::from(n);
        for k in 0..2 {
            let (e, s) = (empirical[(k, k)], fix.point.cov_pixel[(k, k)]);
            assert!((e / s - 1.0).abs() < 0.15, "axis {k}: {e} vs {s}");
        }
    }

    #[test]
    fn the_boxes_height_scatter_beyond_their_pixel_error() {
        let boxes = |sd: f64, random_sd: f64| -> Vec<BoxHeight> {
            (0..40)
                .map(|k| BoxHeight {
                    height_m: 1.7 + if k % 2 == 0 { sd } else { -sd },
                    var_random_m2: random_sd * random_sd,
                    var_shape_m2: 0.0,
                })
                .collect()
        };
        // Spread 0.1 m, of which the pixel error explains 0.05 m: 0.1² · 40/39 − 0.05².
        let v = excess_height_var(&boxes(0.1, 0.05)).unwrap();
        assert!((v - (0.01 * 40.0 / 39.0 - 0.0025)).abs() < 1e-12, "{v}");
        // Less spread than the pixel error says: nothing beyond it.
        assert_eq!(excess_height_var(&boxes(0.02, 0.05)), Some(0.0));
        assert_eq!(excess_height_var(&boxes(0.1, 0.05)[..4]), None);
    }
}
