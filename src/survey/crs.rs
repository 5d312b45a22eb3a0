//! Coordinate reference systems through PROJ (adapter). PROJ objects are not `Send`: make one
//! [`Crs`] per thread.
//!
//! A [`Crs`] knows how to take its horizontal coordinates to latitude and longitude on its own
//! geodetic datum and back, without any datum change, and what its heights mean. Conversions
//! between two CRSs ([`Transform`]) may change datum; their accuracy is reported.

use std::cell::RefCell;
use std::collections::HashMap;
use std::ffi::{CStr, CString};
use std::ptr;
use std::rc::Rc;

use proj_sys as sys;
use thiserror::Error;

use crate::geom::geodesy::Ellipsoid;

#[derive(Debug, Error, Clone, PartialEq)]
#[error("CRS '{}': {message}", crate::io::clip(spec, 60))]
pub struct CrsError {
    pub spec: String,
    pub message: String,
}

/// What the third coordinate of a position means.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum HeightKind {
    /// Height above the ellipsoid of the horizontal datum.
    Ellipsoidal,
    /// Gravity-related height, with the vertical datum when known.
    Orthometric(Option<String>),
    /// The file does not say; pass `--height` to say it.
    Unknown,
}

impl std::fmt::Display for HeightKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            HeightKind::Ellipsoidal => f.write_str("ellipsoidal"),
            HeightKind::Orthometric(Some(d)) => write!(f, "orthometric ({d})"),
            HeightKind::Orthometric(None) => f.write_str("orthometric"),
            HeightKind::Unknown => f.write_str("unknown (the file does not say)"),
        }
    }
}

/// The kind of horizontal coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Horizontal {
    /// Longitude, latitude in degrees (axis order normalised to longitude first).
    Geographic,
    /// Easting, northing in the CRS's linear unit.
    Projected,
}

/// An owned PROJ object with the context it was made in.
struct Pj {
    ptr: *mut sys::PJ,
}

impl Drop for Pj {
    fn drop(&mut self) {
        if !self.ptr.is_null() {
            // SAFETY: a non-null object made here, destroyed once (its context outlives it).
            unsafe {
                sys::proj_destroy(self.ptr);
            }
        }
    }
}

/// A PROJ context, destroyed after every object made in it.
struct Context {
    ptr: *mut sys::PJ_CONTEXT,
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: every object made in the context holds it, so none is left; destroyed once.
        unsafe {
            sys::proj_context_destroy(self.ptr);
        }
    }
}

thread_local! {
    /// One PROJ context per thread: a context opens PROJ's database, which costs milliseconds.
    static CONTEXT: std::cell::OnceCell<Rc<Context>> = const { std::cell::OnceCell::new() };
    /// CRSs already made on this thread, by specification, and the specifications PROJ refused.
    static CACHE: RefCell<HashMap<String, Result<Crs, CrsError>>> = RefCell::new(HashMap::new());
}

/// The most CRSs kept per thread (a run uses two or three).
const CACHE_SIZE: usize = 64;

impl Context {
    fn new() -> Self {
        // SAFETY: takes nothing; a null result is PROJ's default context, which every call accepts.
        let ptr = unsafe { sys::proj_context_create() };
        // Quiet: errors are reported through our own messages.
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        unsafe {
            sys::proj_log_level(ptr, sys::PJ_LOG_LEVEL_PJ_LOG_NONE);
        }
        Context { ptr }
    }

    /// This thread's context. Objects made in it hold it, so it outlives them.
    fn shared() -> Rc<Context> {
        CONTEXT.with(|c| c.get_or_init(|| Rc::new(Context::new())).clone())
    }

    /// The CRSs of PROJ's database, listed once per thread: PROJ takes milliseconds to fail on
    /// an unknown code (it tries every other kind of object first) and to look a name up (its
    /// name search scans every table); a table lookup takes microseconds.
    fn with_catalogue<T>(&self, f: impl FnOnce(&Catalogue) -> T) -> T {
        thread_local! {
            static CATALOGUE: std::cell::OnceCell<Catalogue> = const { std::cell::OnceCell::new() };
        }
        CATALOGUE.with(|c| {
            f(c.get_or_init(|| {
                let mut cat = Catalogue::default();
                let mut n = 0;
                // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
                let list = unsafe {
                    sys::proj_get_crs_info_list_from_database(
                        self.ptr,
                        ptr::null(),
                        ptr::null(),
                        &mut n,
                    )
                };
                if list.is_null() {
                    return cat;
                }
                for i in 0..usize::try_from(n).unwrap_or(0) {
                    // SAFETY: `i` < `n`, the length PROJ returned with the list.
                    let info = unsafe { &**list.add(i) };
                    let (Some(a), Some(c)) = (c_str_opt(info.auth_name), c_str_opt(info.code))
                    else {
                        continue;
                    };
                    let code = format!("{a}:{c}");
                    cat.codes.insert(code.to_ascii_uppercase());
                    if let Some(name) = c_str_opt(info.name) {
                        // One code per name: EPSG's first, then one not deprecated.
                        let better = |old: &(String, bool)| {
                            (a == "EPSG" && !old.0.starts_with("EPSG:"))
                                || (old.1 && info.deprecated == 0)
                        };
                        let key = name.to_lowercase();
                        match cat.names.get(&key) {
                            Some(old) if !better(old) => {}
                            _ => {
                                cat.names.insert(key, (code, info.deprecated != 0));
                            }
                        }
                    }
                }
                // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
                unsafe { sys::proj_crs_info_list_destroy(list) };
                cat
            }))
        })
    }

    fn last_error(&self) -> String {
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        unsafe {
            let code = sys::proj_context_errno(self.ptr);
            let s = sys::proj_context_errno_string(self.ptr, code);
            if s.is_null() {
                format!("PROJ error {code}")
            } else {
                CStr::from_ptr(s).to_string_lossy().into_owned()
            }
        }
    }

    fn wrap(&self, ptr: *mut sys::PJ, spec: &str, what: &str) -> Result<Pj, CrsError> {
        if ptr.is_null() {
            Err(CrsError {
                spec: spec.to_string(),
                message: format!("{what}: {}", self.last_error()),
            })
        } else {
            Ok(Pj { ptr })
        }
    }
}

fn c_str_opt(p: *const std::os::raw::c_char) -> Option<String> {
    if p.is_null() {
        None
    } else {
        // SAFETY: a non-null, NUL-terminated string PROJ owns, copied at once.
        Some(unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
    }
}

/// Turns the spellings surveyors' files use into something PROJ parses: OpenDroneMap's
/// `WGS84 UTM 17N`, and PROJ strings without `+type=crs`.
pub fn normalise_spec(spec: &str) -> String {
    let s = spec.trim();
    let words: Vec<&str> = s.split_whitespace().collect();
    if words.len() == 3
        && words[0].eq_ignore_ascii_case("WGS84")
        && words[1].eq_ignore_ascii_case("UTM")
    {
        let zone = words[2];
        // The hemisphere is the last character, which need not be one byte.
        let hemi = zone.chars().last();
        let num = &zone[..zone.len() - hemi.map_or(0, char::len_utf8)];
        if let (Ok(z), Some(h)) = (num.parse::<u32>(), hemi)
            && (1..=60).contains(&z)
        {
            match h.to_ascii_uppercase() {
                'N' => return format!("EPSG:{}", 32600 + z),
                'S' => return format!("EPSG:{}", 32700 + z),
                _ => {}
            }
        }
    }
    if s.starts_with('+') && !s.contains("+type=crs") {
        return format!("{s} +type=crs");
    }
    s.to_string()
}

/// PROJ's CRSs: their `AUTH:CODE`s (upper case), and each name (lower case) with its code and
/// whether that code is deprecated.
#[derive(Default)]
struct Catalogue {
    codes: std::collections::HashSet<String>,
    names: HashMap<String, (String, bool)>,
}

/// Whether a name could be a CRS's: letters, digits, spaces and the punctuation of EPSG's names,
/// at most 200 bytes. Anything else is not looked up in PROJ's name search (a tenth of a second).
fn name_like(s: &str) -> bool {
    s.len() <= 200
        && s.chars()
            .all(|c| c.is_alphanumeric() || " /()._-+,'".contains(c))
}

/// `AUTH:CODE` split, when the specification is one (an authority PROJ's database knows).
fn auth_code(spec: &str) -> Option<(&str, &str)> {
    let (a, c) = spec.trim().split_once(':')?;
    let known = ["EPSG", "ESRI", "IGNF", "IAU_2015", "NKG", "OGC", "PROJ"];
    (known.iter().any(|k| k.eq_ignore_ascii_case(a))
        && !c.is_empty()
        && c.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'.'))
    .then_some((a, c))
}

/// Whether a specification is WKT: a keyword, then `[`.
fn is_wkt(spec: &str) -> bool {
    let s = spec.trim();
    s.find('[').is_some_and(|i| {
        i > 0
            && s[..i]
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_')
    })
}

/// Whether a specification is a CRS's name rather than `AUTH:CODE`, a URN, a PROJ string, WKT or
/// PROJJSON (which PROJ parses).
fn is_crs_name(spec: &str) -> bool {
    let s = spec.trim();
    let auth_code = s.split_once(':').is_some_and(|(a, c)| {
        !a.is_empty()
            && !c.is_empty()
            && a.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_')
            && c.bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'.')
    });
    !(auth_code
        || is_wkt(s)
        || s.starts_with('+')
        || s.contains("proj=")
        || s.starts_with('{')
        || s.to_ascii_lowercase().starts_with("urn:"))
}

/// A coordinate reference system: a cheap handle (made once per thread and specification).
#[derive(Clone)]
pub struct Crs(Rc<CrsData>);

impl std::ops::Deref for Crs {
    type Target = CrsData;
    fn deref(&self) -> &CrsData {
        &self.0
    }
}

/// A CRS's area of use, degrees (west may exceed east across the antimeridian).
#[derive(Clone, Debug, PartialEq)]
pub struct AreaOfUse {
    pub west: f64,
    pub south: f64,
    pub east: f64,
    pub north: f64,
    pub name: String,
}

impl AreaOfUse {
    /// How far (degrees) a longitude/latitude lies outside the area; 0 inside.
    pub fn distance_deg(&self, lon: f64, lat: f64) -> f64 {
        let dlat = (self.south - lat).max(lat - self.north).max(0.0);
        // Longitudes wrap: the distance to the band [west, east] going either way round.
        let width = if self.east >= self.west {
            self.east - self.west
        } else {
            self.east - self.west + 360.0
        };
        if width >= 360.0 {
            return dlat;
        }
        let from_west = (lon - self.west).rem_euclid(360.0);
        let dlon = if from_west <= width {
            0.0
        } else {
            (from_west - width).min(360.0 - from_west)
        };
        dlat.max(dlon)
    }
}

/// The longest CRS specification accepted: WKT of the most complex CRSs is a few kilobytes, and
/// PROJ's parser uses many times the text's size in memory.
pub const MAX_SPEC_BYTES: usize = 64 * 1024;

/// What a [`Crs`] knows.
pub struct CrsData {
    /// The specification as given (EPSG code, PROJ string, name, WKT).
    pub spec: String,
    /// PROJ's name for it.
    pub name: String,
    /// `AUTH:CODE` when PROJ knows one.
    pub id: Option<String>,
    pub horizontal: Horizontal,
    /// What heights mean according to the CRS itself (a compound or 3D CRS says; a 2D one does not).
    pub height_kind: HeightKind,
    /// Metres per unit of the horizontal axes of a projected CRS (1 for metres).
    pub unit_m: f64,
    pub ellipsoid: Ellipsoid,
    /// Name of the geodetic datum the horizontal coordinates are on.
    pub geodetic_name: String,
    /// WKT of the whole CRS, for GDAL outputs.
    pub wkt: String,
    /// WKT of the horizontal part (the CRS itself unless it is compound).
    horizontal_wkt: String,
    /// Where the CRS may be used: west, south, east, north in degrees (PROJ's area of use).
    pub area_of_use: Option<AreaOfUse>,
    // Conversions to and from latitude/longitude on the same datum, dropped before the context.
    to_geodetic: Pj,
    from_geodetic: Pj,
    ctx: Rc<Context>,
}

impl std::fmt::Debug for Crs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Crs({}: {})", self.spec, self.name)
    }
}

impl Crs {
    /// Parses a CRS: `EPSG:nnnn`, a PROJ string, a CRS name PROJ knows, WKT, or OpenDroneMap's
    /// `WGS84 UTM 17N`.
    pub fn new(spec: &str) -> Result<Crs, CrsError> {
        if spec.len() > MAX_SPEC_BYTES {
            return Err(CrsError {
                spec: crate::io::clip(spec, 60),
                message: format!(
                    "{} bytes long; a CRS is at most {} KiB of WKT (give an EPSG code such as EPSG:32631)",
                    spec.len(),
                    MAX_SPEC_BYTES / 1024
                ),
            });
        }
        if let Some(c) = CACHE.with(|c| c.borrow().get(spec).cloned()) {
            return c;
        }
        let crs = Crs::make(spec);
        CACHE.with(|c| {
            let mut c = c.borrow_mut();
            if c.len() >= CACHE_SIZE {
                c.clear();
            }
            c.insert(spec.to_string(), crs.clone());
        });
        crs
    }

    fn make(spec: &str) -> Result<Crs, CrsError> {
        let ctx = Context::shared();
        let err = |message: String| CrsError {
            spec: spec.to_string(),
            message,
        };
        let normalised = normalise_spec(spec);
        let c = CString::new(normalised.clone()).map_err(|_| err("contains a NUL byte".into()))?;
        // An AUTH:CODE (or urn:ogc:def:crs:AUTH::CODE) PROJ's database does not hold fails here.
        if let Some((auth, code)) = auth_code(&normalised)
            && !ctx.with_catalogue(|c| {
                c.codes
                    .contains(&format!("{auth}:{code}").to_ascii_uppercase())
            })
        {
            return Err(err(format!(
                "PROJ does not know it: its database has no CRS {}:{} (expected an EPSG code such as EPSG:32631)",
                crate::io::clip(auth, 40),
                crate::io::clip(code, 40)
            )));
        }
        // A PROJ string PROJ cannot parse, and WKT it cannot read, fail here: PROJ's own
        // fallback searches names approximately, a tenth of a second and never the right CRS.
        if normalised.starts_with('+')
            && !normalised.contains("proj=")
            && !normalised.contains("init=")
        {
            return Err(err(
                "a PROJ string needs +proj= (expected an EPSG code such as EPSG:32631, or a PROJ string such as +proj=utm +zone=31 +datum=WGS84)".into(),
            ));
        }
        let obj = create_object(&ctx, spec, &normalised, &c)?;
        let mut crs = obj;
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let mut ty = unsafe { sys::proj_get_type(crs.ptr) };
        if ty == sys::PJ_TYPE_PJ_TYPE_BOUND_CRS {
            crs = ctx.wrap(
                // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
                unsafe { sys::proj_get_source_crs(ctx.ptr, crs.ptr) },
                spec,
                "bound CRS without a source",
            )?;
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            ty = unsafe { sys::proj_get_type(crs.ptr) };
        }
        // PROJ strings make nameless ("unknown") CRSs: the specification is the better name.
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let name = c_str_opt(unsafe { sys::proj_get_name(crs.ptr) })
            .filter(|n| !n.is_empty() && n != "unknown")
            .unwrap_or_else(|| spec.trim().to_string());
        let id = match (
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            c_str_opt(unsafe { sys::proj_get_id_auth_name(crs.ptr, 0) }),
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            c_str_opt(unsafe { sys::proj_get_id_code(crs.ptr, 0) }),
        ) {
            (Some(a), Some(c)) => Some(format!("{a}:{c}")),
            _ => None,
        };
        let wkt_of = |pj: &Pj| -> Result<String, CrsError> {
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            c_str_opt(unsafe {
                sys::proj_as_wkt(ctx.ptr, pj.ptr, sys::PJ_WKT_TYPE_PJ_WKT2_2019, ptr::null())
            })
            .ok_or_else(|| err("cannot be written as WKT".into()))
        };
        let wkt = wkt_of(&crs)?;
        let area_of_use = area_of_use(&ctx, &crs);
        let (horizontal_crs, height_kind) = split_heights(&ctx, crs, ty, spec, &normalised)?;
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let hty = unsafe { sys::proj_get_type(horizontal_crs.ptr) };
        let horizontal = match hty {
            sys::PJ_TYPE_PJ_TYPE_PROJECTED_CRS => Horizontal::Projected,
            sys::PJ_TYPE_PJ_TYPE_GEOGRAPHIC_2D_CRS | sys::PJ_TYPE_PJ_TYPE_GEOGRAPHIC_3D_CRS => {
                Horizontal::Geographic
            }
            _ => {
                return Err(err(
                    "its horizontal part is neither geographic nor projected".into(),
                ));
            }
        };
        let (geodetic, geodetic_name, ellipsoid) = geodetic_of(&ctx, &horizontal_crs, spec)?;
        let unit_m = if horizontal == Horizontal::Projected {
            axis_unit(&ctx, &horizontal_crs).unwrap_or(1.0)
        } else {
            1.0
        };
        // The geodetic CRS of the same datum: no datum change, so no grid or Helmert involved.
        let to_geodetic = conversion(
            &ctx,
            spec,
            &horizontal_crs,
            &geodetic,
            "cannot convert to latitude/longitude",
        )?;
        let from_geodetic = conversion(
            &ctx,
            spec,
            &geodetic,
            &horizontal_crs,
            "cannot convert from latitude/longitude",
        )?;
        let horizontal_wkt = wkt_of(&horizontal_crs)?;
        Ok(Crs(Rc::new(CrsData {
            spec: spec.to_string(),
            name,
            id,
            horizontal,
            height_kind,
            unit_m,
            ellipsoid,
            geodetic_name,
            wkt,
            horizontal_wkt,
            area_of_use,
            to_geodetic,
            from_geodetic,
            ctx: ctx.clone(),
        })))
    }

    /// What PROJ should be given for the horizontal part: the specification as the user wrote it
    /// (so that PROJ picks the operations `cs2cs` picks for it), or the horizontal part's WKT for a
    /// compound CRS (heights are not transformed).
    fn horizontal_spec(&self) -> String {
        if self.height_kind == HeightKind::Unknown || self.height_kind == HeightKind::Ellipsoidal {
            normalise_spec(&self.spec)
        } else {
            self.horizontal_wkt.clone()
        }
    }

    /// Horizontal coordinates to (longitude, latitude) in degrees on this CRS's own datum.
    pub fn to_lon_lat(&self, x: f64, y: f64) -> Result<(f64, f64), CrsError> {
        if self.horizontal == Horizontal::Geographic {
            return Ok((x, y));
        }
        self.trans(&self.to_geodetic, x, y, "to latitude/longitude")
    }

    /// (longitude, latitude) in degrees on this CRS's datum to its horizontal coordinates.
    pub fn from_lon_lat(&self, lon: f64, lat: f64) -> Result<(f64, f64), CrsError> {
        if self.horizontal == Horizontal::Geographic {
            return Ok((lon, lat));
        }
        self.trans(&self.from_geodetic, lon, lat, "from latitude/longitude")
    }

    fn trans(&self, op: &Pj, x: f64, y: f64, what: &str) -> Result<(f64, f64), CrsError> {
        let c = sys::PJ_COORD {
            v: [x, y, 0.0, f64::INFINITY],
        };
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let v = unsafe { sys::proj_trans(op.ptr, sys::PJ_DIRECTION_PJ_FWD, c).v };
        if v[0].is_finite() && v[1].is_finite() {
            Ok((v[0], v[1]))
        } else {
            Err(CrsError {
                spec: self.spec.clone(),
                message: format!(
                    "cannot convert ({x}, {y}) {what}: {}",
                    self.ctx.last_error()
                ),
            })
        }
    }

    /// A short label: `EPSG:31370 (BD72 / Belgian Lambert 72)`.
    pub fn label(&self) -> String {
        match &self.id {
            Some(id) => format!("{id} ({})", self.name),
            None => self.name.clone(),
        }
    }
}

/// The PROJ object `spec` (normalised: `normalised`, as a C string `c`) names: WKT read as WKT, a
/// CRS's name looked up exactly, anything else given to `proj_create`.
fn create_object(ctx: &Context, spec: &str, normalised: &str, c: &CString) -> Result<Pj, CrsError> {
    let err = |message: String| CrsError {
        spec: spec.to_string(),
        message,
    };
    let unknown = "PROJ does not know it (expected an EPSG code such as EPSG:32631, a PROJ string, WKT or a CRS's exact name)";
    Ok(if is_wkt(normalised) {
        ctx.wrap(
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            unsafe {
                sys::proj_create_from_wkt(
                    ctx.ptr,
                    c.as_ptr(),
                    ptr::null(),
                    ptr::null_mut(),
                    ptr::null_mut(),
                )
            },
            spec,
            "PROJ cannot read it as WKT",
        )?
    } else if is_crs_name(normalised) {
        // A name is looked up exactly: PROJ's approximate matching takes a third of a
        // second and may pick another CRS of a similar name (Belge 1972 for BD72). Names in
        // the CRS list by their code; others (aliases) through PROJ's exact name search.
        let code = ctx.with_catalogue(|c| c.names.get(&normalised.to_lowercase()).cloned());
        if let Some((code, _)) = code {
            let cc = CString::new(code).map_err(|_| err("contains a NUL byte".into()))?;
            ctx.wrap(
                // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
                unsafe { sys::proj_create(ctx.ptr, cc.as_ptr()) },
                spec,
                unknown,
            )?
        } else {
            if !name_like(normalised) {
                return Err(err(unknown.into()));
            }
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            let list = unsafe {
                sys::proj_create_from_name(
                    ctx.ptr,
                    ptr::null(),
                    c.as_ptr(),
                    ptr::null(),
                    0,
                    0,
                    1,
                    ptr::null(),
                )
            };
            if list.is_null() {
                return Err(err(unknown.into()));
            }
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            let found = unsafe {
                if sys::proj_list_get_count(list) > 0 {
                    sys::proj_list_get(ctx.ptr, list, 0)
                } else {
                    ptr::null_mut()
                }
            };
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            unsafe { sys::proj_list_destroy(list) };
            ctx.wrap(found, spec, unknown)?
        }
    } else {
        ctx.wrap(
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            unsafe { sys::proj_create(ctx.ptr, c.as_ptr()) },
            spec,
            unknown,
        )?
    })
}

/// A CRS of type `ty` as its horizontal part and the kind of its heights: a compound CRS split,
/// a geocentric, engineering or vertical one refused.
fn split_heights(
    ctx: &Context,
    crs: Pj,
    ty: sys::PJ_TYPE,
    spec: &str,
    normalised: &str,
) -> Result<(Pj, HeightKind), CrsError> {
    let err = |message: String| CrsError {
        spec: spec.to_string(),
        message,
    };
    match ty {
    sys::PJ_TYPE_PJ_TYPE_COMPOUND_CRS => {
        let h = ctx.wrap(
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            unsafe { sys::proj_crs_get_sub_crs(ctx.ptr, crs.ptr, 0) },
            spec,
            "compound CRS without a horizontal part",
        )?;
        let v = ctx.wrap(
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            unsafe { sys::proj_crs_get_sub_crs(ctx.ptr, crs.ptr, 1) },
            spec,
            "compound CRS without a vertical part",
        )?;
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let vname = c_str_opt(unsafe { sys::proj_get_name(v.ptr) });
        let mut h = h;
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        if unsafe { sys::proj_get_type(h.ptr) } == sys::PJ_TYPE_PJ_TYPE_BOUND_CRS {
            h = ctx.wrap(
                // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
                unsafe { sys::proj_get_source_crs(ctx.ptr, h.ptr) },
                spec,
                "bound CRS without a source",
            )?;
        }
        Ok((h, HeightKind::Orthometric(vname)))
    }
    sys::PJ_TYPE_PJ_TYPE_GEOGRAPHIC_3D_CRS => Ok((crs, HeightKind::Ellipsoidal)),
    sys::PJ_TYPE_PJ_TYPE_GEOGRAPHIC_2D_CRS | sys::PJ_TYPE_PJ_TYPE_PROJECTED_CRS => {
        Ok((crs, HeightKind::Unknown))
    }
    sys::PJ_TYPE_PJ_TYPE_GEOCENTRIC_CRS => {
        Err(err("geocentric (ECEF) coordinates are not supported as a survey CRS; convert them to a geographic or projected CRS".into()))
    }
    sys::PJ_TYPE_PJ_TYPE_ENGINEERING_CRS | sys::PJ_TYPE_PJ_TYPE_VERTICAL_CRS => {
        Err(err("not a geographic, projected or compound CRS".into()))
    }
    _ => {
        Err(err(format!(
            "'{}' is not a coordinate reference system (append +type=crs to a PROJ string?)",
            crate::io::clip(normalised, 60)
        )))
    }
    }
}

/// The geodetic CRS of `horizontal_crs`, its datum's name (an ensemble's common name for WGS 84,
/// ETRS89: it says whether two CRSs share one) and its ellipsoid.
fn geodetic_of(
    ctx: &Context,
    horizontal_crs: &Pj,
    spec: &str,
) -> Result<(Pj, String, Ellipsoid), CrsError> {
    let err = |message: String| CrsError {
        spec: spec.to_string(),
        message,
    };
    let geodetic = ctx.wrap(
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        unsafe { sys::proj_crs_get_geodetic_crs(ctx.ptr, horizontal_crs.ptr) },
        spec,
        "no geodetic CRS",
    )?;
    // The datum (an ensemble's common name for WGS 84, ETRS89), which says whether two CRSs
    // share one.
    // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
    let datum = unsafe { sys::proj_crs_get_datum_forced(ctx.ptr, geodetic.ptr) };
    let geodetic_name = if datum.is_null() {
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        c_str_opt(unsafe { sys::proj_get_name(geodetic.ptr) }).unwrap_or_default()
    } else {
        let datum = Pj { ptr: datum };
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        c_str_opt(unsafe { sys::proj_get_name(datum.ptr) }).unwrap_or_default()
    };
    let ell = ctx.wrap(
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        unsafe { sys::proj_get_ellipsoid(ctx.ptr, geodetic.ptr) },
        spec,
        "no ellipsoid",
    )?;
    let (mut a, mut b, mut computed, mut inv_f) = (0.0, 0.0, 0, 0.0);
    // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
    let ok = unsafe {
        sys::proj_ellipsoid_get_parameters(
            ctx.ptr,
            ell.ptr,
            &mut a,
            &mut b,
            &mut computed,
            &mut inv_f,
        )
    };
    if ok == 0 || !(a > 0.0) {
        return Err(err("cannot read its ellipsoid".into()));
    }
    let ellipsoid = Ellipsoid::from_axes(a, b);
    Ok((geodetic, geodetic_name, ellipsoid))
}

/// The operation from `from` to `to`, axes in longitude, latitude (or easting, northing) order.
fn conversion(ctx: &Context, spec: &str, from: &Pj, to: &Pj, what: &str) -> Result<Pj, CrsError> {
    let raw = ctx.wrap(
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        unsafe {
            sys::proj_create_crs_to_crs_from_pj(
                ctx.ptr,
                from.ptr,
                to.ptr,
                ptr::null_mut(),
                ptr::null(),
            )
        },
        spec,
        what,
    )?;
    ctx.wrap(
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        unsafe { sys::proj_normalize_for_visualization(ctx.ptr, raw.ptr) },
        spec,
        what,
    )
}

fn area_of_use(ctx: &Context, obj: &Pj) -> Option<AreaOfUse> {
    let (mut w, mut s, mut e, mut n) = (0.0, 0.0, 0.0, 0.0);
    let mut name: *const std::os::raw::c_char = ptr::null();
    // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
    let ok = unsafe {
        sys::proj_get_area_of_use(ctx.ptr, obj.ptr, &mut w, &mut s, &mut e, &mut n, &mut name)
    };
    // PROJ answers -1000 for an unknown bound.
    (ok != 0 && [w, s, e, n].iter().all(|v| *v > -999.0)).then(|| AreaOfUse {
        west: w,
        south: s,
        east: e,
        north: n,
        name: c_str_opt(name).unwrap_or_default(),
    })
}

fn axis_unit(ctx: &Context, crs: &Pj) -> Option<f64> {
    // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
    let cs = unsafe { sys::proj_crs_get_coordinate_system(ctx.ptr, crs.ptr) };
    if cs.is_null() {
        return None;
    }
    let cs = Pj { ptr: cs };
    let mut factor = 0.0;
    // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
    let ok = unsafe {
        sys::proj_cs_get_axis_info(
            ctx.ptr,
            cs.ptr,
            0,
            ptr::null_mut(),
            ptr::null_mut(),
            ptr::null_mut(),
            &mut factor,
            ptr::null_mut(),
            ptr::null_mut(),
            ptr::null_mut(),
        )
    };
    (ok != 0 && factor > 0.0).then_some(factor)
}

/// The transformation PROJ used for a point: its name and stated accuracy.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct OperationInfo {
    pub name: String,
    /// Metres; `None` when PROJ does not know it (a ballpark transformation says nothing).
    pub accuracy_m: Option<f64>,
}

/// A conversion between two CRSs through the operation PROJ chooses for each point (the one
/// `cs2cs SOURCE TARGET` uses), possibly with a datum change whose accuracy PROJ reports.
/// Horizontal: the vertical part of a compound CRS is left out and the height given is carried
/// through the operation as an ellipsoidal height (a datum change moves it). Axes in GIS order
/// (easting or longitude first). Not `Send`: one per thread.
pub struct Transform {
    // Dropped before the context it was made in.
    op: Pj,
    ctx: Rc<Context>,
    pub source: String,
    pub target: String,
}

impl Transform {
    pub fn new(source: &Crs, target: &Crs) -> Result<Transform, CrsError> {
        let ctx = Context::shared();
        let fail = |ctx: &Context| CrsError {
            spec: target.spec.clone(),
            message: format!(
                "no conversion from {}: {}",
                source.label(),
                ctx.last_error()
            ),
        };
        let c_spec = |c: &Crs| {
            CString::new(c.horizontal_spec()).map_err(|_| CrsError {
                spec: c.spec.clone(),
                message: "contains a NUL byte".into(),
            })
        };
        let (src, dst) = (c_spec(source)?, c_spec(target)?);
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let raw = unsafe {
            sys::proj_create_crs_to_crs(ctx.ptr, src.as_ptr(), dst.as_ptr(), ptr::null_mut())
        };
        if raw.is_null() {
            return Err(fail(&ctx));
        }
        let raw = Pj { ptr: raw };
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let op = unsafe { sys::proj_normalize_for_visualization(ctx.ptr, raw.ptr) };
        if op.is_null() {
            return Err(fail(&ctx));
        }
        Ok(Transform {
            op: Pj { ptr: op },
            ctx,
            source: source.label(),
            target: target.label(),
        })
    }

    /// Horizontal coordinates in the target CRS; the height is taken as 0.
    pub fn apply(&self, x: f64, y: f64) -> Result<(f64, f64), CrsError> {
        self.apply_3d(x, y, 0.0).map(|(x, y, _)| (x, y))
    }

    /// `(x, y, h)` in the target CRS, `h` an ellipsoidal height carried through a datum change.
    pub fn apply_3d(&self, x: f64, y: f64, h: f64) -> Result<(f64, f64, f64), CrsError> {
        let c = sys::PJ_COORD {
            v: [x, y, h, f64::INFINITY],
        };
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let v = unsafe { sys::proj_trans(self.op.ptr, sys::PJ_DIRECTION_PJ_FWD, c).v };
        if v[..3].iter().all(|a| a.is_finite()) {
            Ok((v[0], v[1], v[2]))
        } else {
            Err(CrsError {
                spec: self.target.clone(),
                message: format!(
                    "cannot convert ({x}, {y}) from {}: {}",
                    self.source,
                    self.ctx.last_error()
                ),
            })
        }
    }

    /// The operation used for the last point converted.
    pub fn last_operation(&self) -> Option<OperationInfo> {
        self.last_used().map(|(_, info)| info)
    }

    /// The operation used for the last point converted, as an operation of its own (PROJ
    /// clones it: tens of microseconds).
    fn last_used(&self) -> Option<(Pj, OperationInfo)> {
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let op = unsafe { sys::proj_trans_get_last_used_operation(self.op.ptr) };
        if op.is_null() {
            return None;
        }
        let op = Pj { ptr: op };
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let name = c_str_opt(unsafe { sys::proj_get_name(op.ptr) }).unwrap_or_default();
        // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
        let acc = unsafe { sys::proj_coordoperation_get_accuracy(self.ctx.ptr, op.ptr) };
        Some((
            op,
            OperationInfo {
                name,
                accuracy_m: (acc >= 0.0).then_some(acc),
            },
        ))
    }

    /// `apply_3d`, noting in `used` the operation PROJ chose for the point. Asking PROJ for
    /// every point costs ~25 µs a point; instead the point is converted again by each operation
    /// already noted, and PROJ is asked only when none gives the same bits (an operation that
    /// gives the same numbers as a noted one is not told apart from it).
    pub fn apply_3d_noting(
        &self,
        x: f64,
        y: f64,
        h: f64,
        used: &mut UsedOperations,
    ) -> Result<(f64, f64, f64), CrsError> {
        let out = self.apply_3d(x, y, h)?;
        let same = |op: &Pj| {
            let c = sys::PJ_COORD {
                v: [x, y, h, f64::INFINITY],
            };
            // SAFETY: the context and objects are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`); strings are NUL-terminated `CString`s that outlive the call; PROJ copies what it keeps.
            let v = unsafe { sys::proj_trans(op.ptr, sys::PJ_DIRECTION_PJ_FWD, c).v };
            v[0].to_bits() == out.0.to_bits()
                && v[1].to_bits() == out.1.to_bits()
                && v[2].to_bits() == out.2.to_bits()
        };
        if !used.noted.iter().any(|(op, _)| same(op))
            && let Some((op, info)) = self.last_used()
        {
            used.noted.push((op, info));
        }
        Ok(out)
    }
}

/// The EGM96 geoid's height above the WGS 84 ellipsoid, from PROJ's 15' grid (Debian's
/// `proj-data`): DJI's consumer drones write their altitude above it. Not `Send`.
pub struct Egm96 {
    // Dropped before the context it was made in.
    op: Pj,
    ctx: Rc<Context>,
}

impl Egm96 {
    /// The grid under its current name, else under the older one; an error naming both when
    /// neither is installed (never a silent zero).
    pub fn new() -> Result<Egm96, CrsError> {
        let ctx = Context::shared();
        for grid in ["us_nga_egm96_15.tif", "egm96_15.gtx"] {
            let spec = format!(
                "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad +step +proj=vgridshift +grids={grid} +multiplier=1 +step +proj=unitconvert +xy_in=rad +xy_out=deg"
            );
            let c = CString::new(spec).expect("no NUL in a literal");
            // SAFETY: the context is a live handle made on this thread (`Context`: non-null, not `Send`); the string is a NUL-terminated `CString` that outlives the call; PROJ copies what it keeps.
            let raw = unsafe { sys::proj_create(ctx.ptr, c.as_ptr()) };
            if !raw.is_null() {
                return Ok(Egm96 {
                    op: Pj { ptr: raw },
                    ctx,
                });
            }
        }
        Err(CrsError {
            spec: "EGM96".into(),
            message: format!(
                "PROJ has no EGM96 geoid grid (us_nga_egm96_15.tif or egm96_15.gtx): install proj-data ({})",
                ctx.last_error()
            ),
        })
    }

    /// The geoid's height above the ellipsoid at `lon`, `lat` (degrees), metres.
    pub fn undulation_m(&self, lon: f64, lat: f64) -> Result<f64, CrsError> {
        let c = sys::PJ_COORD {
            v: [lon, lat, 0.0, f64::INFINITY],
        };
        // SAFETY: the context and object are live handles made on this thread (`Context`, `Pj`: non-null, not `Send`).
        let v = unsafe { sys::proj_trans(self.op.ptr, sys::PJ_DIRECTION_PJ_FWD, c).v };
        if v[2].is_finite() {
            Ok(v[2])
        } else {
            Err(CrsError {
                spec: "EGM96".into(),
                message: format!(
                    "no geoid height at longitude {lon}, latitude {lat}: {}",
                    self.ctx.last_error()
                ),
            })
        }
    }
}

/// The operations a `Transform` used over many points (`Transform::apply_3d_noting`). Not
/// `Send`, like the transform.
#[derive(Default)]
pub struct UsedOperations {
    noted: Vec<(Pj, OperationInfo)>,
}

impl UsedOperations {
    /// Each operation once, in the order first used.
    pub fn infos(&self) -> Vec<OperationInfo> {
        let mut out: Vec<OperationInfo> = Vec::new();
        for (_, info) in &self.noted {
            if !out.contains(info) {
                out.push(info.clone());
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn egm96_undulation_matches_the_published_geoid_heights() {
        let g = Egm96::new().unwrap();
        // NGA's EGM96 at 0°N 0°E: 17.16 m; near Munich the geoid is about 45.6 m up.
        assert!((g.undulation_m(0.0, 0.0).unwrap() - 17.16).abs() < 0.02);
        let munich = g.undulation_m(11.5, 48.1).unwrap();
        assert!((munich - 45.57).abs() < 0.05, "{munich}");
    }

    #[test]
    fn odm_utm_spelling() {
        assert_eq!(normalise_spec("WGS84 UTM 17N"), "EPSG:32617");
        assert_eq!(normalise_spec("WGS84 UTM 22S"), "EPSG:32722");
        assert_eq!(
            normalise_spec("+proj=utm +zone=22"),
            "+proj=utm +zone=22 +type=crs"
        );
        assert_eq!(normalise_spec("EPSG:31370"), "EPSG:31370");
        // Found by fuzzing: a zone ending in a character of two bytes panicked.
        assert_eq!(normalise_spec("WGS84 UTM 17é"), "WGS84 UTM 17é");
        assert_eq!(normalise_spec("WGS84 UTM é"), "WGS84 UTM é");
    }

    #[test]
    fn reads_kinds_and_heights() {
        let utm = Crs::new("WGS84 UTM 17N").unwrap();
        assert_eq!(utm.horizontal, Horizontal::Projected);
        assert_eq!(utm.height_kind, HeightKind::Unknown);
        assert_eq!(utm.id.as_deref(), Some("EPSG:32617"));
        assert!((utm.ellipsoid.a - 6_378_137.0).abs() < 1e-6);
        let compound = Crs::new("EPSG:6190").unwrap();
        assert!(
            matches!(compound.height_kind, HeightKind::Orthometric(Some(ref d)) if d.contains("Ostend"))
        );
        assert!(
            (compound.ellipsoid.a - 6_378_388.0).abs() < 1e-6,
            "International 1924"
        );
        assert_eq!(
            Crs::new("EPSG:4979").unwrap().height_kind,
            HeightKind::Ellipsoidal
        );
        let geo = Crs::new("EPSG:4326").unwrap();
        assert_eq!(geo.horizontal, Horizontal::Geographic);
        let proj_string =
            Crs::new("+proj=utm +zone=22 +south +datum=WGS84 +units=m +no_defs").unwrap();
        assert_eq!(proj_string.horizontal, Horizontal::Projected);
        let ft = Crs::new("EPSG:2227").unwrap(); // California zone 3, US survey feet
        assert!((ft.unit_m - 1200.0 / 3937.0).abs() < 1e-12, "{}", ft.unit_m);
    }

    #[test]
    fn unknown_crs_is_a_clear_error() {
        let e = Crs::new("EPSG:999999").unwrap_err();
        assert!(e.to_string().contains("EPSG:999999"), "{e}");
        assert!(Crs::new("not a crs at all").is_err());
        // PROJ makes something that is not a CRS of this: the message quotes it clipped (found
        // by make fuzz).
        let long = format!("+proj=utm +zone=22 +south {}+datum=", "[".repeat(8189));
        let e = Crs::new(&long).unwrap_err().to_string();
        assert!(e.len() < 400, "{} bytes: {e}", e.len());
        assert!(
            Crs::new("EPSG:4978")
                .unwrap_err()
                .message
                .contains("geocentric")
        );
    }

    #[test]
    fn names_are_matched_exactly() {
        assert!(is_crs_name("ETRS89 / Belgian Lambert 2008"));
        assert!(!is_crs_name("EPSG:3812") && !is_crs_name("+proj=utm +zone=31"));
        assert!(!is_crs_name("PROJCRS[\"x\"]") && !is_crs_name("urn:ogc:def:crs:EPSG::4326"));
        assert_eq!(
            Crs::new("ETRS89 / Belgian Lambert 2008")
                .unwrap()
                .id
                .as_deref(),
            Some("EPSG:3812")
        );
        assert_eq!(
            Crs::new("BD72 / Belgian Lambert 72").unwrap().id.as_deref(),
            Some("EPSG:31370")
        );
        // Close is not the same: Belge 1972 (EPSG:31300) is another CRS.
        assert!(Crs::new("Belgian Lambert 72").is_err());
        assert!(Crs::new("ETRS89 / Belgian Lambert 2009").is_err());
    }

    #[test]
    fn distance_to_the_area_of_use() {
        let a = |w, s, e, n| AreaOfUse {
            west: w,
            south: s,
            east: e,
            north: n,
            name: String::new(),
        };
        let world = a(-180.0, -90.0, 180.0, 90.0);
        assert_eq!(world.distance_deg(4.3, 50.8), 0.0);
        let utm31 = a(0.0, 0.0, 6.0, 84.0);
        assert_eq!(utm31.distance_deg(3.0, 50.0), 0.0);
        assert!((utm31.distance_deg(81.5, 50.0) - 75.5).abs() < 1e-9);
        assert!((utm31.distance_deg(-2.0, 50.0) - 2.0).abs() < 1e-9);
        assert!((utm31.distance_deg(3.0, -5.0) - 5.0).abs() < 1e-9);
        // Across the antimeridian (Fiji).
        let fiji = a(176.0, -20.0, -178.0, -12.0);
        assert_eq!(fiji.distance_deg(179.0, -15.0), 0.0);
        assert_eq!(fiji.distance_deg(-179.0, -15.0), 0.0);
        assert!((fiji.distance_deg(170.0, -15.0) - 6.0).abs() < 1e-9);
        let l72 = Crs::new("EPSG:31370").unwrap().area_of_use.clone().unwrap();
        assert!(l72.distance_deg(4.43, 51.07) == 0.0 && l72.distance_deg(20.0, 51.0) > 10.0);
    }

    #[test]
    fn lon_lat_round_trip_is_sub_millimetre() {
        let crs = Crs::new("EPSG:31370").unwrap();
        let (lon, lat) = crs.to_lon_lat(150_000.0, 170_000.0).unwrap();
        let (x, y) = crs.from_lon_lat(lon, lat).unwrap();
        assert!((x - 150_000.0).abs() < 1e-6 && (y - 170_000.0).abs() < 1e-6);
    }

    /// NAD27 to WGS 84 is a different transformation in each region (here without grids:
    /// regional Helmert shifts); the noted operations must be the ones PROJ reports point by
    /// point.
    #[test]
    fn noted_operations_are_those_used_point_by_point() {
        let t = Transform::new(
            &Crs::new("EPSG:4267").unwrap(),
            &Crs::new("EPSG:4326").unwrap(),
        )
        .unwrap();
        let mut used = UsedOperations::default();
        let mut asked: Vec<OperationInfo> = Vec::new();
        for i in 0..200 {
            // Florida to Alaska.
            let (lon, lat) = (-81.0 - 0.35 * f64::from(i), 27.0 + 0.17 * f64::from(i));
            let noted = t.apply_3d_noting(lon, lat, 0.0, &mut used).unwrap();
            assert_eq!(noted, t.apply_3d(lon, lat, 0.0).unwrap());
            let op = t.last_operation().unwrap();
            if !asked.contains(&op) {
                asked.push(op);
            }
        }
        assert!(asked.len() >= 2, "{asked:?}");
        assert_eq!(used.infos(), asked);
    }
}
