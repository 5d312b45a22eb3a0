//! What a photo says about itself (pure; the `kamadak-exif` crate): EXIF make, model, focal
//! length (and its 35 mm equivalent), GPS position; DJI's XMP attributes (relative altitude,
//! gimbal angles, RTK standard deviations when present).

use std::io::{BufReader, Read, Seek};
use std::path::Path;

use exif::{In, Reader, Tag, Value};

use crate::io::FileError;

/// A GPS fix: WGS 84 latitude and longitude (degrees) and the altitude written by the camera
/// (metres; DJI: above mean sea level).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GpsFix {
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub alt_m: Option<f64>,
}

/// A photo's metadata; every field optional.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct PhotoMeta {
    pub make: Option<String>,
    pub model: Option<String>,
    pub focal_mm: Option<f64>,
    pub focal_35mm: Option<f64>,
    /// EXIF `FocalPlaneXResolution` in pixels a millimetre of the sensor, for an image
    /// `exif_width_px` wide (EXIF `PixelXDimension`) when that is given.
    pub focal_plane_px_per_mm: Option<f64>,
    pub exif_width_px: Option<u32>,
    pub gps: Option<GpsFix>,
    /// DJI XMP `RelativeAltitude`: above the take-off point, metres.
    pub relative_altitude_m: Option<f64>,
    /// DJI XMP gimbal yaw, pitch, roll, degrees.
    pub gimbal_ypr_deg: Option<[f64; 3]>,
    /// DJI XMP `RtkStdLon`, `RtkStdLat`, `RtkStdHgt`: the RTK fix's standard deviations,
    /// metres (RTK drones only).
    pub rtk_sigma_m: Option<[f64; 3]>,
}

fn rational(v: &Value, k: usize) -> Option<f64> {
    match v {
        Value::Rational(r) => r.get(k).map(|x| x.to_f64()),
        Value::SRational(r) => r.get(k).map(|x| x.to_f64()),
        Value::Short(s) => s.get(k).map(|x| f64::from(*x)),
        Value::Long(s) => s.get(k).map(|x| f64::from(*x)),
        _ => None,
    }
    .filter(|x| x.is_finite())
}

fn ascii(v: &Value) -> Option<String> {
    match v {
        Value::Ascii(a) => a.first().map(|s| {
            String::from_utf8_lossy(s)
                .trim_end_matches('\0')
                .trim()
                .to_string()
        }),
        _ => None,
    }
}

/// A DJI XMP attribute `drone-dji:NAME="+12.3"` as a number.
fn xmp_number(xmp: &str, name: &str) -> Option<f64> {
    let key = format!("drone-dji:{name}=\"");
    let start = xmp.find(&key)? + key.len();
    let end = xmp[start..].find('"')? + start;
    xmp[start..end]
        .trim()
        .parse()
        .ok()
        .filter(|x: &f64| x.is_finite())
}

/// The 35 mm-equivalent focal lengths of real lenses, millimetres: a fisheye to a long
/// telephoto. A value outside (EXIF's 0, 1 or 65535) is not a lens.
pub const FOCAL_35MM_RANGE: std::ops::RangeInclusive<f64> = 8.0..=1200.0;

/// The metadata of the photo at `path`. A photo without EXIF gives empty metadata; a file
/// that cannot be read is an error.
pub fn read_meta(path: &Path) -> Result<PhotoMeta, FileError> {
    let ctx = crate::io::FileCtx { path };
    let file =
        std::fs::File::open(path).map_err(|e| ctx.err(None, None, format!("cannot read: {e}")))?;
    meta_of(BufReader::new(file)).map_err(|e| ctx.err(None, None, format!("cannot read: {e}")))
}

/// The metadata of a photo held in memory (what [`read_meta`] reads from a file).
pub fn meta_from_bytes(bytes: &[u8]) -> PhotoMeta {
    meta_of(std::io::Cursor::new(bytes)).unwrap_or_default()
}

/// A photo's metadata from a reader at its start.
fn meta_of<R: std::io::BufRead + Seek>(mut file: R) -> std::io::Result<PhotoMeta> {
    let mut meta = PhotoMeta::default();
    // XMP sits in the first segments of a JPEG: 256 KiB is plenty.
    let mut head = Vec::new();
    (&mut file).take(256 << 10).read_to_end(&mut head)?;
    let text = String::from_utf8_lossy(&head);
    if let Some(i) = text.find("<x:xmpmeta") {
        let xmp = &text[i..];
        let xmp = &xmp[..xmp.find("</x:xmpmeta>").unwrap_or(xmp.len())];
        meta.relative_altitude_m = xmp_number(xmp, "RelativeAltitude");
        if let (Some(y), Some(p), Some(r)) = (
            xmp_number(xmp, "GimbalYawDegree"),
            xmp_number(xmp, "GimbalPitchDegree"),
            xmp_number(xmp, "GimbalRollDegree"),
        ) {
            meta.gimbal_ypr_deg = Some([y, p, r]);
        }
        // An RTK σ is a few centimetres to metres: 0 or a negative one is no σ.
        if let (Some(lon), Some(lat), Some(h)) = (
            xmp_number(xmp, "RtkStdLon"),
            xmp_number(xmp, "RtkStdLat"),
            xmp_number(xmp, "RtkStdHgt"),
        ) && [lon, lat, h].iter().all(|s| *s > 0.0 && *s <= 100.0)
        {
            meta.rtk_sigma_m = Some([lon, lat, h]);
        }
    }
    file.rewind()?;
    let Ok(exif) = Reader::new().read_from_container(&mut file) else {
        return Ok(meta);
    };
    let field = |t: Tag| exif.get_field(t, In::PRIMARY).map(|f| &f.value);
    meta.make = field(Tag::Make).and_then(ascii);
    meta.model = field(Tag::Model).and_then(ascii);
    meta.focal_mm = field(Tag::FocalLength)
        .and_then(|v| rational(v, 0))
        .filter(|f| *f > 0.0);
    meta.focal_35mm = field(Tag::FocalLengthIn35mmFilm)
        .and_then(|v| rational(v, 0))
        .filter(|f| *f > 0.0);
    // Pixels a unit of the sensor: the unit 2 inches (the default), 3 centimetres, and the
    // millimetres and micrometres some cameras write as 4 and 5.
    let unit = field(Tag::FocalPlaneResolutionUnit).and_then(|v| rational(v, 0));
    let mm_per_unit = match unit.map(|u| u.round() as i64) {
        None | Some(2) => Some(25.4),
        Some(3) => Some(10.0),
        Some(4) => Some(1.0),
        Some(5) => Some(1e-3),
        Some(_) => None,
    };
    meta.focal_plane_px_per_mm = field(Tag::FocalPlaneXResolution)
        .and_then(|v| rational(v, 0))
        .zip(mm_per_unit)
        .map(|(r, mm)| r / mm)
        .filter(|r| *r > 0.0 && r.is_finite());
    meta.exif_width_px = field(Tag::PixelXDimension)
        .and_then(|v| rational(v, 0))
        .filter(|w| *w >= 1.0 && *w <= f64::from(u32::MAX))
        .map(|w| w as u32);
    // Degrees, minutes, seconds: minutes and seconds under 60, or no position.
    let dms = |t: Tag| {
        let v = field(t)?;
        let (d, m, s) = (rational(v, 0)?, rational(v, 1)?, rational(v, 2)?);
        (d >= 0.0 && (0.0..60.0).contains(&m) && (0.0..60.0).contains(&s))
            .then(|| d + m / 60.0 + s / 3600.0)
    };
    let sign = |t: Tag, negative: &str| {
        field(t).and_then(ascii).map_or(1.0, |s| {
            if s.eq_ignore_ascii_case(negative) {
                -1.0
            } else {
                1.0
            }
        })
    };
    if let (Some(lat), Some(lon)) = (dms(Tag::GPSLatitude), dms(Tag::GPSLongitude)) {
        let (lat, lon) = (
            lat * sign(Tag::GPSLatitudeRef, "S"),
            lon * sign(Tag::GPSLongitudeRef, "W"),
        );
        if lat.abs() <= 90.0 && lon.abs() <= 180.0 && (lat, lon) != (0.0, 0.0) {
            let below =
                matches!(field(Tag::GPSAltitudeRef), Some(Value::Byte(b)) if b.first() == Some(&1));
            // Within the atmosphere a drone flies in: below it is a wrong number.
            let alt = field(Tag::GPSAltitude)
                .and_then(|v| rational(v, 0))
                .map(|a| if below { -a } else { a })
                .filter(|a| (-1000.0..=20_000.0).contains(a));
            meta.gps = Some(GpsFix {
                lat_deg: lat,
                lon_deg: lon,
                alt_m: alt,
            });
        }
    }
    Ok(meta)
}

/// Where a starting focal length came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FocalSource {
    /// EXIF `FocalLengthIn35mmFilm`: 36 mm across the longer side.
    Exif35mm,
    /// EXIF `FocalLength` in millimetres times `FocalPlaneXResolution` (a DSLR's EXIF).
    ExifFocalPlane,
    /// Nothing in the EXIF: COLMAP's guess, 1.2 times the longer side (a view about 45° wide).
    Guess,
}

impl FocalSource {
    /// As the report names it.
    pub fn name(self) -> &'static str {
        match self {
            FocalSource::Exif35mm => "exif",
            FocalSource::ExifFocalPlane => "exif-focal-plane",
            FocalSource::Guess => "guess",
        }
    }
}

/// The focal length a guess starts from, times the image's longer side.
pub const GUESS_FOCAL_PER_SIDE: f64 = 1.2;

/// A starting focal length in pixels for an image `width` × `height`, and its source: from the
/// 35 mm equivalent, else from the focal length on the sensor's pixel pitch (scaled to this
/// image when the EXIF states the width it describes), else a guess.
pub fn focal_px_from_exif(meta: &PhotoMeta, width: u32, height: u32) -> (f64, FocalSource) {
    let side = f64::from(width.max(height));
    if let Some(f35) = meta.focal_35mm {
        return (f35 / 36.0 * side, FocalSource::Exif35mm);
    }
    if let (Some(f_mm), Some(px_per_mm)) = (meta.focal_mm, meta.focal_plane_px_per_mm) {
        let scale = meta
            .exif_width_px
            .map_or(1.0, |w| f64::from(width) / f64::from(w));
        let f = f_mm * px_per_mm * scale;
        // A focal plane resolution that makes the view narrower than a long telephoto's or
        // wider than a fisheye's is a wrong tag, not a lens.
        let per_side = FOCAL_35MM_RANGE.start() / 36.0..=FOCAL_35MM_RANGE.end() / 36.0;
        if per_side.contains(&(f / side)) {
            return (f, FocalSource::ExifFocalPlane);
        }
    }
    (GUESS_FOCAL_PER_SIDE * side, FocalSource::Guess)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dji_xmp_numbers() {
        let xmp = r#"<x:xmpmeta> drone-dji:RelativeAltitude="+39.80"
            drone-dji:GimbalYawDegree="+45.00" drone-dji:GimbalPitchDegree="-89.90"
            drone-dji:GimbalRollDegree="+0.00" drone-dji:Bad="x" </x:xmpmeta>"#;
        assert_eq!(xmp_number(xmp, "RelativeAltitude"), Some(39.8));
        assert_eq!(xmp_number(xmp, "GimbalPitchDegree"), Some(-89.9));
        assert_eq!(xmp_number(xmp, "Bad"), None);
        assert_eq!(xmp_number(xmp, "RtkStdLon"), None);
    }

    #[test]
    fn a_file_without_exif_has_empty_metadata_and_a_missing_one_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.jpg");
        std::fs::write(&p, b"not a jpeg").unwrap();
        assert_eq!(read_meta(&p).unwrap(), PhotoMeta::default());
        let e = read_meta(&dir.path().join("nope.jpg"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("nope.jpg"), "{e}");
    }
}
