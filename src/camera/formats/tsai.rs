//! The Tsai camera calibration (R. Y. Tsai 1987, in R. Willson's implementation), in which PETS
//! 2009 and the ETH pedestrian sets publish their fixed cameras: the XML `<Camera>` with
//! `<Geometry>`, `<Intrinsic>` and `<Extrinsic>` elements, or the same 19 numbers one per line
//! (`w h ncx nfx dx dy dpx dpy cx cy sx f kappa1 tx ty tz rx ry rz`).
//!
//! Tsai's model, world point `Xw` (the file's world unit: millimetres in PETS and ETH) to frame
//! buffer pixels:
//!
//! ```text
//! Xc = R Xw + T,  R = Rz(rz) Ry(ry) Rx(rx)
//! Xu = f Xc/Zc,  Yu = f Yc/Zc                      (sensor millimetres, undistorted)
//! Xu = Xd (1 + κ1 r²),  Yu = Yd (1 + κ1 r²),  r² = Xd² + Yd²
//! u = sx Xd / dpx + cx,  v = Yd / dpy + cy
//! ```
//!
//! In OpenCV terms `fx = f sx / dpx`, `fy = f / dpy`, `cx`, `cy` as they are (frame buffer pixels,
//! the top-left pixel's centre at (0, 0)), no skew. Tsai's distortion goes from distorted to
//! undistorted, the inverse of Brown–Conrady's: k1, k2, k3 are fitted to it over the image and
//! the largest pixel difference is reported (and refused beyond [`FIT_TOLERANCE_PX`]).

use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};

use super::{Ctx, FormatError};
use crate::camera::{Calibration, Camera, Extrinsics};
use crate::geom::Rigid3;

/// The numbers of a Tsai calibration, in the file's order.
pub const NAMES: [&str; 19] = [
    "width", "height", "ncx", "nfx", "dx", "dy", "dpx", "dpy", "cx", "cy", "sx", "focal", "kappa1",
    "tx", "ty", "tz", "rx", "ry", "rz",
];

/// Largest pixel difference accepted between Tsai's distortion and the fitted k1..k3.
pub const FIT_TOLERANCE_PX: f64 = 0.05;

/// The world unit of a Tsai calibration's extrinsics, metres: PETS 2009 and ETH use millimetres.
pub const WORLD_UNIT_M: f64 = 1e-3;

/// A Tsai calibration as the file gives it.
#[derive(Clone, Debug, PartialEq)]
pub struct Tsai {
    pub width: f64,
    pub height: f64,
    pub ncx: f64,
    pub nfx: f64,
    pub dx: f64,
    pub dy: f64,
    pub dpx: f64,
    pub dpy: f64,
    pub cx: f64,
    pub cy: f64,
    pub sx: f64,
    /// Effective focal length, millimetres.
    pub focal: f64,
    /// Radial distortion, 1/mm².
    pub kappa1: f64,
    pub t: Vector3<f64>,
    /// Euler angles, radians: `R = Rz(rz) Ry(ry) Rx(rx)`.
    pub r: Vector3<f64>,
    /// Whether the file gives the pose (`t`, `r`): an XML file may hold the intrinsics only.
    pub has_pose: bool,
}

impl Tsai {
    fn from_numbers(v: &[f64; 19]) -> Tsai {
        Tsai {
            width: v[0],
            height: v[1],
            ncx: v[2],
            nfx: v[3],
            dx: v[4],
            dy: v[5],
            dpx: v[6],
            dpy: v[7],
            cx: v[8],
            cy: v[9],
            sx: v[10],
            focal: v[11],
            kappa1: v[12],
            t: Vector3::new(v[13], v[14], v[15]),
            r: Vector3::new(v[16], v[17], v[18]),
            has_pose: true,
        }
    }

    /// Tsai's rotation, world to camera.
    pub fn rotation(&self) -> Rotation3<f64> {
        let (sa, ca) = self.r.x.sin_cos();
        let (sb, cb) = self.r.y.sin_cos();
        let (sg, cg) = self.r.z.sin_cos();
        Rotation3::from_matrix_unchecked(Matrix3::new(
            cb * cg,
            cg * sa * sb - ca * sg,
            sa * sg + ca * cg * sb,
            cb * sg,
            sa * sb * sg + ca * cg,
            ca * sb * sg - cg * sa,
            -sb,
            cb * sa,
            ca * cb,
        ))
    }

    /// `cam_from_world` with the world in metres (the file's unit taken as [`WORLD_UNIT_M`]).
    pub fn cam_from_world(&self) -> Rigid3 {
        Rigid3::new(self.rotation(), self.t * WORLD_UNIT_M)
    }

    /// Focal lengths in pixels.
    fn f_px(&self) -> (f64, f64) {
        (self.focal * self.sx / self.dpx, self.focal / self.dpy)
    }

    /// A normalised distorted radius to its undistorted one (Tsai's direction).
    fn undistort_radius(&self, rho_d: f64) -> f64 {
        rho_d * (1.0 + self.kappa1 * self.focal * self.focal * rho_d * rho_d)
    }

    /// The distorted radius of an undistorted one: the root of `κ f² ρd³ + ρd − ρu` nearest
    /// `ρu` (Newton; the map is monotonic over the image, which [`Tsai::check`] makes sure of).
    fn distort_radius(&self, rho_u: f64) -> f64 {
        let a = self.kappa1 * self.focal * self.focal;
        let mut r = rho_u;
        for _ in 0..50 {
            let g = a * r * r * r + r - rho_u;
            let step = g / (3.0 * a * r * r + 1.0);
            r -= step;
            if step.abs() < 1e-15 {
                break;
            }
        }
        r
    }

    /// Tsai's own projection of a world point (the file's units) to frame buffer pixels; `None`
    /// behind the camera. For checks: the run uses the fitted [`Camera`].
    pub fn project(&self, world: &Vector3<f64>) -> Option<Vector2<f64>> {
        let c = self.rotation() * world + self.t;
        if c.z <= 0.0 {
            return None;
        }
        let u = c.xy() / c.z;
        let rho_u = u.norm();
        let scale = if rho_u > 0.0 {
            self.distort_radius(rho_u) / rho_u
        } else {
            1.0
        };
        let (fx, fy) = self.f_px();
        Some(Vector2::new(
            fx * u.x * scale + self.cx,
            fy * u.y * scale + self.cy,
        ))
    }

    /// The largest normalised distorted radius in the image (its farthest corner).
    fn max_rho_d(&self) -> f64 {
        let (fx, fy) = self.f_px();
        [
            (0.0, 0.0),
            (self.width - 1.0, 0.0),
            (0.0, self.height - 1.0),
        ]
        .into_iter()
        .chain([(self.width - 1.0, self.height - 1.0)])
        .map(|(u, v)| Vector2::new((u - self.cx) / fx, (v - self.cy) / fy).norm())
        .fold(0.0, f64::max)
    }

    /// Values no camera has: the field and why.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        let side = 1.0..=f64::from(crate::camera::MAX_IMAGE_SIDE);
        for (name, v) in [("width", self.width), ("height", self.height)] {
            if !side.contains(&v) || v.fract() != 0.0 {
                return Err((
                    name,
                    format!(
                        "{v}: expected a whole number of pixels from 1 to {}",
                        crate::camera::MAX_IMAGE_SIDE
                    ),
                ));
            }
        }
        for (name, v) in [
            ("ncx", self.ncx),
            ("nfx", self.nfx),
            ("dx", self.dx),
            ("dy", self.dy),
            ("dpx", self.dpx),
            ("dpy", self.dpy),
            ("focal", self.focal),
        ] {
            if !(v > 0.0) {
                return Err((name, format!("{v}: expected a positive number")));
            }
        }
        // The horizontal scale factor corrects a frame grabber's timing: close to 1.
        if !(0.5..=2.0).contains(&self.sx) {
            return Err((
                "sx",
                format!(
                    "{}: the horizontal scale factor is a correction near 1 (0.5 to 2 accepted)",
                    self.sx
                ),
            ));
        }
        let (fx, fy) = self.f_px();
        for (name, f) in [("focal", fx), ("focal", fy)] {
            if !(1.0..=crate::camera::MAX_FOCAL_PX).contains(&f) {
                return Err((
                    name,
                    format!(
                        "focal length {} mm gives {f:.1} px (from dpx, dpy and sx): expected 1 \
                         to {} px",
                        self.focal,
                        crate::camera::MAX_FOCAL_PX
                    ),
                ));
            }
        }
        let margin = 2.0 * self.width.max(self.height);
        for (name, v, size) in [("cx", self.cx, self.width), ("cy", self.cy, self.height)] {
            if !(-margin..=size + margin).contains(&v) {
                return Err((
                    name,
                    format!("{v}: the principal point is far outside the {size}-pixel image"),
                ));
            }
        }
        // Barrel distortion (κ1 < 0) folds back beyond ρd² = 1 / (3 |κ1| f²): the image must lie
        // inside.
        let a = self.kappa1 * self.focal * self.focal;
        let rho = self.max_rho_d();
        if a < 0.0 && 3.0 * -a * rho * rho >= 1.0 {
            return Err((
                "kappa1",
                format!(
                    "{}: so strong a barrel distortion folds the image back on itself before its \
                     corners",
                    self.kappa1
                ),
            ));
        }
        for (name, v) in [("rx", self.r.x), ("ry", self.r.y), ("rz", self.r.z)] {
            if v.abs() > 4.0 * std::f64::consts::PI {
                return Err((name, format!("{v}: expected an angle in radians")));
            }
        }
        Ok(())
    }

    /// The Brown–Conrady camera that projects as Tsai's does (k1..k3 fitted over the image),
    /// and the largest pixel difference of the fit.
    pub fn camera(&self) -> (Camera, f64) {
        let (fx, fy) = self.f_px();
        // ρd/ρu − 1 = k1 ρu² + k2 ρu⁴ + k3 ρu⁶, least squares over the image's radii.
        let rho_u_max = self.undistort_radius(self.max_rho_d() * 1.02);
        let n = 400;
        let mut ata = Matrix3::<f64>::zeros();
        let mut atb = Vector3::<f64>::zeros();
        let samples: Vec<(f64, f64)> = (1..=n)
            .map(|i| {
                let ru = rho_u_max * i as f64 / n as f64;
                (ru, self.distort_radius(ru))
            })
            .collect();
        for &(ru, rd) in &samples {
            let r2 = ru * ru;
            let row = Vector3::new(r2, r2 * r2, r2 * r2 * r2);
            ata += row * row.transpose();
            atb += row * (rd / ru - 1.0);
        }
        let k = ata
            .try_inverse()
            .map_or(Vector3::zeros(), |inverse| inverse * atb);
        let f = fx.max(fy);
        let worst = samples
            .iter()
            .map(|&(ru, rd)| {
                let r2 = ru * ru;
                let fitted = ru * (1.0 + k.x * r2 + k.y * r2 * r2 + k.z * r2 * r2 * r2);
                (fitted - rd).abs() * f
            })
            .fold(0.0, f64::max);
        let camera = Camera::pinhole(fx, fy, self.cx, self.cy)
            .with_distortion(&[k.x, k.y, 0.0, 0.0, k.z])
            .with_image_size(self.width as u32, self.height as u32);
        (camera, worst)
    }
}

/// The XML form: the numbers of `<Geometry>`, `<Intrinsic>` and `<Extrinsic>`, each with its
/// line; and whether `<Extrinsic>` is there (its numbers zero when not).
fn xml_numbers(ctx: &Ctx, text: &str) -> Result<([f64; 19], bool), FormatError> {
    let doc = super::parse_xml(ctx, text)?;
    let root = doc.root_element();
    let line = |n: roxmltree::Node| doc.text_pos_at(n.range().start).row as usize;
    let mut v = [0.0; 19];
    let mut has_pose = true;
    for (element, names) in [
        (
            "Geometry",
            &["width", "height", "ncx", "nfx", "dx", "dy", "dpx", "dpy"][..],
        ),
        ("Intrinsic", &["focal", "kappa1", "cx", "cy", "sx"][..]),
        ("Extrinsic", &["tx", "ty", "tz", "rx", "ry", "rz"][..]),
    ] {
        let Some(node) = root.children().find(|n| n.has_tag_name(element)) else {
            if element == "Extrinsic" {
                has_pose = false;
                continue;
            }
            return Err(ctx.err(
                Some(line(root)),
                Some(element),
                format!(
                    "missing <{element}>: a Tsai calibration has <Geometry>, <Intrinsic> and \
                     <Extrinsic>"
                ),
            ));
        };
        for name in names {
            let text = node.attribute(*name).ok_or_else(|| {
                ctx.err(
                    Some(line(node)),
                    Some(name),
                    format!("<{element}> has no {name} attribute"),
                )
            })?;
            let k = NAMES.iter().position(|n| n == name).expect("a Tsai name");
            v[k] = ctx.number(text, line(node), name)?;
        }
    }
    Ok((v, has_pose))
}

/// The text form: 19 numbers, one per line.
fn text_numbers(ctx: &Ctx, text: &str) -> Result<[f64; 19], FormatError> {
    let mut v = [0.0; 19];
    let mut k = 0;
    for (i, l) in text.lines().enumerate() {
        let t = l.trim();
        if t.is_empty() {
            continue;
        }
        if k == 19 {
            return Err(ctx.err(
                Some(i + 1),
                None,
                "more than the 19 numbers of a Tsai calibration",
            ));
        }
        v[k] = ctx.number(t, i + 1, NAMES[k])?;
        k += 1;
    }
    if k < 19 {
        return Err(ctx.err(
            None,
            Some(NAMES[k]),
            format!(
                "{k} numbers: a Tsai calibration has 19, one per line ({})",
                NAMES.join(" ")
            ),
        ));
    }
    Ok(v)
}

/// Whether `text` looks like a Tsai calibration: the XML with `<Geometry` and `<Intrinsic`, or
/// 19 lines that each hold one number.
pub fn looks_like(text: &str) -> bool {
    let t = text.trim_start_matches('\u{feff}').trim_start();
    if t.starts_with('<') {
        return t.contains("<Geometry") && t.contains("<Intrinsic");
    }
    let lines: Vec<&str> = t.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    lines.len() == 19 && lines.iter().all(|l| l.parse::<f64>().is_ok())
}

/// Reads the Tsai calibration as it is (for its own projection).
pub fn parse_tsai(ctx: &Ctx, text: &str) -> Result<Tsai, FormatError> {
    let t = text.trim_start_matches('\u{feff}').trim_start();
    let (v, has_pose) = if t.starts_with('<') {
        xml_numbers(ctx, t)?
    } else {
        (text_numbers(ctx, text)?, true)
    };
    let tsai = Tsai {
        has_pose,
        ..Tsai::from_numbers(&v)
    };
    tsai.check()
        .map_err(|(field, message)| ctx.err(None, Some(field), message))?;
    Ok(tsai)
}

pub(super) fn parse(ctx: &Ctx, text: &str) -> Result<Calibration, FormatError> {
    let tsai = parse_tsai(ctx, text)?;
    let (camera, worst_px) = tsai.camera();
    if worst_px > FIT_TOLERANCE_PX {
        return Err(ctx.err(
            None,
            Some("kappa1"),
            format!(
                "Tsai's distortion kappa1 = {} is not matched by OpenCV's k1..k3 within {} px \
                 (largest difference {worst_px:.3} px)",
                tsai.kappa1, FIT_TOLERANCE_PX
            ),
        ));
    }
    Ok(Calibration {
        camera,
        covariance: None,
        summary: None,
        notes: vec![
            format!(
                "Tsai calibration: distortion kappa1 = {} refitted as k1..k3 (largest pixel \
                 difference {worst_px:.4} px)",
                tsai.kappa1
            ),
            if tsai.has_pose {
                "Tsai extrinsics: world coordinates taken as millimetres (the PETS 2009 and ETH \
                 convention), converted to metres"
                    .into()
            } else {
                "Tsai calibration without <Extrinsic>: no camera pose".into()
            },
        ],
        extrinsics: tsai.has_pose.then(|| Extrinsics {
            cam_from_world: tsai.cam_from_world(),
            world: "the Tsai calibration's world frame, metres".into(),
        }),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// A camera like PETS 2009's View_001 (768×576, 7 m up, looking across a plaza).
    const VIEW: &str = "768\n576\n795\n752\n4.85e-03\n4.65e-03\n5.1273271277e-03\n4.65e-03\n\
        324.22149053\n282.56650051\n1.0937855397\n5.5549183034\n5.1113043639e-03\n828.73214225\n\
        -3175.4796051\n35469.298547\n2.0405458695\n-0.89337703748\n-0.43056124791\n";

    fn ctx() -> Ctx<'static> {
        Ctx {
            path: Path::new("View_001.txt"),
        }
    }

    fn xml(extrinsic: bool, sx: &str) -> String {
        format!(
            "<?xml version=\"1.0\"?>\n<Camera name=\"v\">\n\
             <Geometry width=\"768\" height=\"576\" ncx=\"795\" nfx=\"752\" dx=\"4.85e-03\" \
             dy=\"4.65e-03\" dpx=\"5.1273271277e-03\" dpy=\"4.65e-03\"/>\n\
             <Intrinsic focal=\"5.5549183034\" kappa1=\"5.1113043639e-03\" cx=\"324.22149053\" \
             cy=\"282.56650051\" sx=\"{sx}\"/>\n{}</Camera>\n",
            if extrinsic {
                "<Extrinsic tx=\"828.73214225\" ty=\"-3175.4796051\" tz=\"35469.298547\" \
                 rx=\"2.0405458695\" ry=\"-0.89337703748\" rz=\"-0.43056124791\"/>\n"
            } else {
                ""
            }
        )
    }

    #[test]
    fn both_forms_read_the_same_camera_and_the_fit_matches_tsai_over_the_image() {
        let a = parse_tsai(&ctx(), VIEW).unwrap();
        let b = parse_tsai(&ctx(), &xml(true, "1.0937855397")).unwrap();
        assert_eq!(a, b);
        assert!(looks_like(VIEW) && looks_like(&xml(true, "1")));
        let (camera, worst) = a.camera();
        assert!(worst < 0.01, "{worst} px");
        // Tsai's projection and the fitted camera's agree on points seen all over the image.
        let pose = a.cam_from_world();
        let mut n = 0;
        for i in -10..=10 {
            for j in -10..=30 {
                let w_mm = Vector3::new(1000.0 * i as f64, 1000.0 * j as f64, 0.0);
                let Some(t) = a.project(&w_mm) else { continue };
                if t.x < 0.0 || t.y < 0.0 || t.x > 767.0 || t.y > 575.0 {
                    continue;
                }
                let c = camera.project(&pose.apply(&(w_mm * WORLD_UNIT_M))).unwrap();
                assert!((c - t).norm() < 0.01, "{c} vs {t}");
                n += 1;
            }
        }
        assert!(n > 50, "{n} points in view");
        // The camera stands about 7 m above the ground.
        let centre = pose.centre();
        assert!((centre.z - 7.07).abs() < 0.01, "{centre}");
    }

    #[test]
    fn impossible_values_and_missing_parts_are_named() {
        let err = |text: &str| parse_tsai(&ctx(), text).unwrap_err();
        // No <Extrinsic>: the intrinsics, and no pose.
        let no_pose = parse(&ctx(), &xml(false, "1.0937855397")).unwrap();
        assert!(no_pose.extrinsics.is_none());
        assert!(parse_tsai(&ctx(), &xml(false, "1.09")).is_ok_and(|t| !t.has_pose));
        let e = err(&xml(true, "1.09").replace("<Intrinsic", "<Intrinsics"));
        assert_eq!(e.field.as_deref(), Some("Intrinsic"), "{e}");
        let e = err(&xml(true, "7"));
        assert_eq!(e.field.as_deref(), Some("sx"), "{e}");
        let e = err(&VIEW.replace("5.1273271277e-03", "-5.1e-03"));
        assert_eq!(e.field.as_deref(), Some("dpx"), "{e}");
        let e = err(&VIEW.replace("5.1113043639e-03", "-0.5"));
        assert_eq!(e.field.as_deref(), Some("kappa1"), "{e}");
        assert!(e.to_string().contains("folds"), "{e}");
        let e = err(&VIEW.replacen("768\n", "", 1));
        assert!(e.to_string().contains("18 numbers"), "{e}");
        let e = err(&VIEW.replace("795", "lots"));
        assert_eq!((e.line, e.field.as_deref()), (Some(3), Some("ncx")), "{e}");
        let e = err(&xml(true, "1.09").replace("rz=", "rq="));
        assert_eq!(e.field.as_deref(), Some("rz"), "{e}");
    }

    #[test]
    fn the_pose_survives_a_conversion_to_json_and_tsai_is_not_written() {
        let cal = parse(&ctx(), VIEW).unwrap();
        let json = super::super::render(&cal, super::super::Format::Json, Path::new("v.json"));
        let back = super::super::parse(Path::new("v.json"), &json.unwrap(), None).unwrap();
        assert_eq!(back.camera, cal.camera);
        let (a, b) = (
            cal.extrinsics.as_ref().unwrap().cam_from_world,
            back.extrinsics.as_ref().unwrap().cam_from_world,
        );
        let p = Vector3::new(3.0, -20.0, 1.7);
        assert!((a.apply(&p) - b.apply(&p)).norm() < 1e-9);
        assert_eq!(
            super::super::Format::detect(VIEW),
            Some(super::super::Format::Tsai)
        );
        let e = super::super::render(&back, super::super::Format::Tsai, Path::new("v.txt"));
        assert!(e.unwrap_err().to_string().contains("does not write"));
    }
}
