//! Synthetic checkerboard views with exact ground truth: random board poses that keep the whole
//! board in the image, exact corner projections, and rendered greyscale images (pure).

use nalgebra::{UnitQuaternion, Vector2, Vector3};
use rand::{Rng, RngExt};
use rand_distr::{Distribution, Normal};

use crate::calibration::board_points;
use crate::camera::{BoardSpec, Camera, ImageSize};
use crate::geom::Rigid3;
use crate::image::GrayImage;

/// Random board poses (`cam_from_board`) for calibration: the board fills 35-65 % of the image
/// width, is tilted 10-45° about a random axis in its plane, turned up to ±30° in plane, and every
/// corner (and the white border) projects at least `margin_px` inside the image.
pub fn random_board_poses(
    camera: &Camera,
    board: &BoardSpec,
    n: usize,
    rng: &mut impl Rng,
) -> Vec<Rigid3> {
    let size = camera.image_size.expect("the camera needs an image size");
    let (w, h) = (f64::from(size.width), f64::from(size.height));
    let margin_px = 0.04 * w;
    let object = board_points(board);
    let board_w = f64::from(board.cols + 1) * board.square_m;
    let centre = Vector3::new(
        f64::from(board.cols - 1) * board.square_m / 2.0,
        f64::from(board.rows - 1) * board.square_m / 2.0,
        0.0,
    );
    // Outer corners of the printed squares, which must stay in view for detection.
    let s = board.square_m;
    let outline = [
        Vector3::new(-s, -s, 0.0),
        Vector3::new(f64::from(board.cols) * s, -s, 0.0),
        Vector3::new(-s, f64::from(board.rows) * s, 0.0),
        Vector3::new(f64::from(board.cols) * s, f64::from(board.rows) * s, 0.0),
    ];
    let mut poses = Vec::with_capacity(n);
    let mut attempts = 0;
    while poses.len() < n {
        attempts += 1;
        assert!(attempts < 100_000, "cannot place the board in the image");
        let fraction = rng.random_range(0.35..0.65);
        let depth = camera.fx * board_w / (fraction * w);
        let axis_angle = rng.random_range(0.0..std::f64::consts::TAU);
        let tilt = rng.random_range(10f64.to_radians()..45f64.to_radians());
        let spin = rng.random_range(-30f64.to_radians()..30f64.to_radians());
        let axis = Vector3::new(axis_angle.cos(), axis_angle.sin(), 0.0);
        let rotation = UnitQuaternion::from_scaled_axis(axis * tilt)
            * UnitQuaternion::from_scaled_axis(Vector3::z() * spin);
        let target = Vector2::new(
            rng.random_range(0.15 * w..0.85 * w),
            rng.random_range(0.15 * h..0.85 * h),
        );
        let ray = Vector3::new(
            (target.x - camera.cx) / camera.fx,
            (target.y - camera.cy) / camera.fy,
            1.0,
        );
        let translation = ray * depth - rotation * centre;
        let pose = Rigid3::new(rotation.to_rotation_matrix(), translation);
        let inside = |x: &Vector3<f64>| {
            camera.project(&pose.apply(x)).is_ok_and(|uv| {
                uv.x > margin_px
                    && uv.y > margin_px
                    && uv.x < w - 1.0 - margin_px
                    && uv.y < h - 1.0 - margin_px
            })
        };
        if object.iter().all(inside) && outline.iter().all(inside) {
            poses.push(pose);
        }
    }
    poses
}

/// Exact corner pixels of the board seen from `cam_from_board`.
pub fn project_corners(
    camera: &Camera,
    board: &BoardSpec,
    cam_from_board: &Rigid3,
) -> Vec<Vector2<f64>> {
    board_points(board)
        .iter()
        .map(|x| {
            camera
                .project(&cam_from_board.apply(x))
                .expect("board corner in front of the camera")
        })
        .collect()
}

/// Adds independent Gaussian noise of `sigma_px` to each coordinate.
pub fn add_noise(points: &mut [Vector2<f64>], sigma_px: f64, rng: &mut impl Rng) {
    let normal = Normal::new(0.0, sigma_px).expect("sigma");
    for p in points {
        p.x += normal.sample(rng);
        p.y += normal.sample(rng);
    }
}

/// Renders board views through a distorted camera: each pixel is the mean of `ss`x`ss`
/// sub-samples whose rays are traced to the board plane (black and white squares on a white
/// border of one square, on a grey background), plus Gaussian noise of `noise` grey levels.
pub struct BoardRenderer {
    size: ImageSize,
    ss: usize,
    /// Undistorted normalised ray (x, y) of each sub-sample; NaN where undistortion fails.
    rays: Vec<[f64; 2]>,
}

impl BoardRenderer {
    pub fn new(camera: &Camera, ss: usize) -> Self {
        let size = camera.image_size.expect("the camera needs an image size");
        let (w, h) = (size.width as usize, size.height as usize);
        let mut rays = Vec::with_capacity(w * h * ss * ss);
        for row in 0..h {
            for sy in 0..ss {
                let v = row as f64 - 0.5 + (sy as f64 + 0.5) / ss as f64;
                for col in 0..w {
                    for sx in 0..ss {
                        let u = col as f64 - 0.5 + (sx as f64 + 0.5) / ss as f64;
                        let r = camera
                            .pixel_to_normalized(&Vector2::new(u, v))
                            .map_or([f64::NAN; 2], |p| [p.x, p.y]);
                        rays.push(r);
                    }
                }
            }
        }
        BoardRenderer { size, ss, rays }
    }

    pub fn render(
        &self,
        board: &BoardSpec,
        cam_from_board: &Rigid3,
        noise: f64,
        rng: &mut impl Rng,
    ) -> GrayImage {
        let (w, h, ss) = (self.size.width as usize, self.size.height as usize, self.ss);
        let board_from_cam = cam_from_board.inverse();
        let rot = board_from_cam.rotation;
        let origin = board_from_cam.translation;
        let s = board.square_m;
        let (cols, rows) = (f64::from(board.cols), f64::from(board.rows));
        let normal = Normal::new(0.0, noise.max(1e-12)).expect("noise");
        let mut pixels = vec![0u8; w * h];
        for row in 0..h {
            for col in 0..w {
                let mut sum = 0.0;
                for sy in 0..ss {
                    let base = ((row * ss + sy) * w + col) * ss;
                    for sx in 0..ss {
                        let [x, y] = self.rays[base + sx];
                        sum += if x.is_nan() {
                            0.0
                        } else {
                            // The ray from the camera centre in board coordinates hits z = 0.
                            let d = rot * Vector3::new(x, y, 1.0);
                            let lambda = -origin.z / d.z;
                            if lambda <= 0.0 {
                                0.35
                            } else {
                                let bx = origin.x + lambda * d.x;
                                let by = origin.y + lambda * d.y;
                                shade(bx / s, by / s, cols, rows)
                            }
                        };
                    }
                }
                let v = 255.0 * sum / (ss * ss) as f64
                    + if noise > 0.0 { normal.sample(rng) } else { 0.0 };
                pixels[row * w + col] = v.round().clamp(0.0, 255.0) as u8;
            }
        }
        GrayImage {
            width: self.size.width,
            height: self.size.height,
            pixels,
        }
    }
}

/// Brightness at board coordinates in squares (inner corners at integers 0..cols-1, 0..rows-1).
fn shade(x: f64, y: f64, cols: f64, rows: f64) -> f64 {
    let (black, white, background) = (0.08, 0.92, 0.35);
    let in_squares = x >= -1.0 && x < cols && y >= -1.0 && y < rows;
    if in_squares {
        let (i, j) = ((x + 1.0).floor() as i64, (y + 1.0).floor() as i64);
        if (i + j) % 2 == 0 { black } else { white }
    } else if x >= -2.0 && x < cols + 1.0 && y >= -2.0 && y < rows + 1.0 {
        white
    } else {
        background
    }
}
