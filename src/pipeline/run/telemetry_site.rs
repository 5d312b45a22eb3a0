//! The drone's telemetry (`[video] telemetry`) in the run's site frame: each frame's SRT
//! position as east, north and, where the project states the datum of DJI's `abs_alt`
//! (`telemetry_height`), up in the survey's height kind (EGM96 through PROJ's geoid grid).

use nalgebra::Vector3;

use super::RunError;
use crate::survey::crs::{Crs, Egm96, HeightKind, Transform};
use crate::survey::load::Framed;
use crate::telemetry::srt::SrtFile;

/// What DJI's `abs_alt` is above: the project says (`[video] telemetry_height`); DJI's files
/// do not.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum AltitudeDatum {
    /// Above the WGS 84 ellipsoid (RTK drones, the simulator).
    Ellipsoidal,
    /// Above the EGM96 geoid ("above mean sea level": DJI's consumer drones).
    Egm96,
}

/// The telemetry of a run and what the project says of it.
pub(super) struct Telemetry {
    pub srt: SrtFile,
    /// σ of the horizontal positions about their common offset, metres.
    pub sigma_m: f64,
    /// σ of the heights about their common offset, metres.
    pub sigma_vertical_m: f64,
    /// `None`: heights are not compared.
    pub datum: Option<AltitudeDatum>,
}

/// One frame's telemetry in the site frame.
#[derive(Clone, Copy, Debug)]
pub(super) struct Fix {
    /// The SRT block's counter.
    pub block: u64,
    /// East, north, up, metres; up is NaN where heights are not compared.
    pub site: Vector3<f64>,
}

/// `abs_alt` + `sign` × the geoid's undulation is the survey's kind of height.
struct Heights {
    geoid: Option<Egm96>,
    sign: f64,
}

/// The telemetry placed in the site frame.
pub(super) struct SiteTelemetry<'a> {
    telemetry: &'a Telemetry,
    framed: &'a Framed,
    fps: f64,
    to_survey: Transform,
    /// How `abs_alt` becomes the survey's kind of height (None: no heights).
    heights: Option<Heights>,
    /// Why heights are not compared, for the report.
    pub heights_note: String,
}

impl<'a> SiteTelemetry<'a> {
    /// `Ok(Err(why))` when the survey has no CRS to place latitudes and longitudes in. Without
    /// `with_heights` only east and north are placed.
    pub fn new(
        telemetry: &'a Telemetry,
        framed: &'a Framed,
        fps: f64,
        with_heights: bool,
    ) -> Result<Result<SiteTelemetry<'a>, String>, RunError> {
        let Some(crs) = &framed.frame.crs else {
            return Ok(Err(
                "the survey is in its own local frame, with no CRS to place latitudes and longitudes".into(),
            ));
        };
        let wgs84 = Crs::new("EPSG:4326").map_err(RunError::Crs)?;
        let to_survey = Transform::new(&wgs84, crs).map_err(RunError::Crs)?;
        // The survey's heights: ellipsoidal, or gravity-related (EGM96 then differs from its
        // vertical datum by an offset that is constant over a site, removed with the common one).
        let datum = telemetry.datum.filter(|_| with_heights);
        let (heights, heights_note) = match (datum, &framed.frame.height) {
            (None, _) => (
                None,
                "heights not compared: say what abs_alt is above with [video] telemetry_height"
                    .into(),
            ),
            (Some(_), HeightKind::Unknown) => (
                None,
                "heights not compared: the survey's height kind is unknown ([survey] height)"
                    .into(),
            ),
            (Some(d), kind) => {
                let survey_ellipsoidal = *kind == HeightKind::Ellipsoidal;
                // abs_alt + sign × N is the survey's kind of height.
                let sign = match (d, survey_ellipsoidal) {
                    (AltitudeDatum::Egm96, true) => 1.0,
                    (AltitudeDatum::Ellipsoidal, false) => -1.0,
                    _ => 0.0,
                };
                let geoid = if sign == 0.0 {
                    None
                } else {
                    Some(Egm96::new().map_err(RunError::Crs)?)
                };
                let from = match d {
                    AltitudeDatum::Ellipsoidal => "ellipsoidal",
                    AltitudeDatum::Egm96 => "above EGM96",
                };
                let note = format!(
                    "abs_alt {from}, compared as the survey's {kind} heights{}",
                    if geoid.is_some() {
                        " through the EGM96 geoid"
                    } else {
                        ""
                    }
                );
                (Some(Heights { geoid, sign }), note)
            }
        };
        Ok(Ok(SiteTelemetry {
            telemetry,
            framed,
            fps,
            to_survey,
            heights,
            heights_note,
        }))
    }

    /// Whether heights are compared.
    pub fn has_heights(&self) -> bool {
        self.heights.is_some()
    }

    /// Frame `frame`'s telemetry (the block whose time holds it); `None` when that block has no
    /// position.
    pub fn at(&self, frame: usize) -> Result<Option<Fix>, RunError> {
        let Some(r) = self.telemetry.srt.record_of_frame(frame, self.fps) else {
            return Ok(None);
        };
        let (Some(lat), Some(lon)) = (r.latitude_deg, r.longitude_deg) else {
            return Ok(None);
        };
        let (e, n) = self.to_survey.apply(lon, lat).map_err(RunError::Crs)?;
        let h = match (&self.heights, r.abs_alt_m) {
            (Some(hs), Some(alt)) => match &hs.geoid {
                Some(g) => alt + hs.sign * g.undulation_m(lon, lat).map_err(RunError::Crs)?,
                None => alt,
            },
            _ => f64::NAN,
        };
        let site = self
            .framed
            .frame
            .local_from_source(&Vector3::new(e, n, h))
            .map_err(RunError::Crs)?;
        Ok(Some(Fix {
            block: r.index,
            site,
        }))
    }
}
