//! EXIF written into a JPEG for tests: a small big-endian TIFF block (IFD0 with the 35 mm focal
//! length and a GPS IFD) as an APP1 segment after SOI, and DJI-style XMP when asked. Enough for
//! photos whose metadata a test chooses (a GPS position on another continent, a focal length of
//! 1 mm), which no camera writes on purpose.
#![allow(dead_code)]

/// What to write.
#[derive(Clone, Debug, Default)]
pub struct Exif {
    pub focal_35mm: Option<u16>,
    /// `FocalLength`, millimetres.
    pub focal_mm: Option<f64>,
    /// `FocalPlaneXResolution` and its `FocalPlaneResolutionUnit` (2 inches, 3 centimetres).
    pub focal_plane_x: Option<(f64, u16)>,
    /// `PixelXDimension`: the width the focal plane resolution is of.
    pub pixel_x_dimension: Option<u32>,
    /// Latitude, longitude in degrees (signed), altitude in metres.
    pub gps: Option<(f64, f64, f64)>,
    /// DJI XMP: `RtkStdLon`, `RtkStdLat`, `RtkStdHgt`.
    pub rtk_sigma_m: Option<[f64; 3]>,
}

const SHORT: u16 = 3;
const RATIONAL: u16 = 5;
const ASCII: u16 = 2;
const BYTE: u16 = 1;
const LONG: u16 = 4;

/// An IFD entry: tag, type, count, and its value bytes (inline when 4 or fewer).
struct Entry {
    tag: u16,
    kind: u16,
    count: u32,
    value: Vec<u8>,
}

fn rational(v: f64, den: u32) -> Vec<u8> {
    let mut b = ((v * den as f64).round() as u32).to_be_bytes().to_vec();
    b.extend(den.to_be_bytes());
    b
}

/// One IFD at `at` (offset in the TIFF block) with its out-of-line values after it; `next` the
/// next IFD's offset (0: none).
fn ifd(entries: &[Entry], at: u32, next: u32) -> Vec<u8> {
    let table = 2 + 12 * entries.len() as u32 + 4;
    let mut data = Vec::new();
    let mut out = (entries.len() as u16).to_be_bytes().to_vec();
    for e in entries {
        out.extend(e.tag.to_be_bytes());
        out.extend(e.kind.to_be_bytes());
        out.extend(e.count.to_be_bytes());
        if e.value.len() <= 4 {
            let mut v = e.value.clone();
            v.resize(4, 0);
            out.extend(v);
        } else {
            out.extend((at + table + data.len() as u32).to_be_bytes());
            data.extend(&e.value);
            if data.len() % 2 == 1 {
                data.push(0);
            }
        }
    }
    out.extend(next.to_be_bytes());
    out.extend(data);
    out
}

/// The TIFF block of `e` (what follows `Exif\0\0` in APP1).
pub fn tiff_block(e: &Exif) -> Vec<u8> {
    let mut gps_entries = Vec::new();
    if let Some((lat, lon, alt)) = e.gps {
        let dms = |v: f64| {
            let v = v.abs();
            let d = v.floor();
            let m = ((v - d) * 60.0).floor();
            let s = (v - d - m / 60.0) * 3600.0;
            let mut b = rational(d, 1);
            b.extend(rational(m, 1));
            b.extend(rational(s, 10_000));
            b
        };
        let r = |s: &str| {
            let mut b = s.as_bytes().to_vec();
            b.push(0);
            b
        };
        gps_entries = vec![
            Entry {
                tag: 1,
                kind: ASCII,
                count: 2,
                value: r(if lat < 0.0 { "S" } else { "N" }),
            },
            Entry {
                tag: 2,
                kind: RATIONAL,
                count: 3,
                value: dms(lat),
            },
            Entry {
                tag: 3,
                kind: ASCII,
                count: 2,
                value: r(if lon < 0.0 { "W" } else { "E" }),
            },
            Entry {
                tag: 4,
                kind: RATIONAL,
                count: 3,
                value: dms(lon),
            },
            Entry {
                tag: 5,
                kind: BYTE,
                count: 1,
                value: vec![u8::from(alt < 0.0)],
            },
            Entry {
                tag: 6,
                kind: RATIONAL,
                count: 1,
                value: rational(alt.abs(), 1000),
            },
        ];
    }
    // IFD0 points to an Exif IFD (the focal lengths, in tag order) and to the GPS IFD.
    let mut exif_entries: Vec<Entry> = Vec::new();
    if let Some(f) = e.focal_mm {
        exif_entries.push(Entry {
            tag: 0x920A,
            kind: RATIONAL,
            count: 1,
            value: rational(f, 1000),
        });
    }
    if let Some(w) = e.pixel_x_dimension {
        exif_entries.push(Entry {
            tag: 0xA002,
            kind: LONG,
            count: 1,
            value: w.to_be_bytes().to_vec(),
        });
    }
    if let Some((r, unit)) = e.focal_plane_x {
        exif_entries.push(Entry {
            tag: 0xA20E,
            kind: RATIONAL,
            count: 1,
            value: rational(r, 1000),
        });
        exif_entries.push(Entry {
            tag: 0xA210,
            kind: SHORT,
            count: 1,
            value: unit.to_be_bytes().to_vec(),
        });
    }
    if let Some(f) = e.focal_35mm {
        exif_entries.push(Entry {
            tag: 0xA405,
            kind: SHORT,
            count: 1,
            value: f.to_be_bytes().to_vec(),
        });
    }
    let mut pointers = Vec::new();
    if !exif_entries.is_empty() {
        pointers.push((0x8769u16, exif_entries));
    }
    if !gps_entries.is_empty() {
        pointers.push((0x8825u16, gps_entries));
    }
    let mut ifd0: Vec<Entry> = pointers
        .iter()
        .map(|(tag, _)| Entry {
            tag: *tag,
            kind: LONG,
            count: 1,
            value: vec![0; 4],
        })
        .collect();
    // The sub-IFDs follow IFD0 in order.
    let mut at = 8 + ifd(&ifd0, 8, 0).len() as u32;
    let mut tail = Vec::new();
    for (k, (_, entries)) in pointers.iter().enumerate() {
        ifd0[k].value = at.to_be_bytes().to_vec();
        let block = ifd(entries, at, 0);
        at += block.len() as u32;
        tail.extend(block);
    }
    let mut b = b"MM\0\x2a".to_vec();
    b.extend(8u32.to_be_bytes());
    b.extend(ifd(&ifd0, 8, 0));
    b.extend(tail);
    b
}

/// `jpeg` (a whole JPEG file) with `e` as its EXIF (and XMP), inserted after SOI.
pub fn with_exif(jpeg: &[u8], e: &Exif) -> Vec<u8> {
    assert!(jpeg.starts_with(&[0xFF, 0xD8]), "not a JPEG");
    let mut app1 = b"Exif\0\0".to_vec();
    app1.extend(tiff_block(e));
    let mut out = vec![0xFF, 0xD8, 0xFF, 0xE1];
    out.extend(((app1.len() + 2) as u16).to_be_bytes());
    out.extend(app1);
    if let Some([lon, lat, h]) = e.rtk_sigma_m {
        let xmp = format!(
            "http://ns.adobe.com/xap/1.0/\0<x:xmpmeta xmlns:x=\"adobe:ns:meta/\"><rdf:Description drone-dji:RtkStdLon=\"{lon}\" drone-dji:RtkStdLat=\"{lat}\" drone-dji:RtkStdHgt=\"{h}\"/></x:xmpmeta>"
        );
        out.extend([0xFF, 0xE1]);
        out.extend(((xmp.len() + 2) as u16).to_be_bytes());
        out.extend(xmp.as_bytes());
    }
    out.extend(&jpeg[2..]);
    out
}
