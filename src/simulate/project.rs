//! The project of a simulated scene, as a typed [`Project`]: what `geostride demo` runs and
//! the benchmarks time. The simulator writes its inputs beside the project file (`gcps.csv`,
//! `picks.csv`, `video.mp4`); the site frame's origin is the scene's, so that the results
//! compare with the simulator's truth.

use crate::pipeline::project::{
    AnalysisSection, CameraSection, ExportSection, GroundSection, OutputSection, PicksSection,
    Project, ProjectionSection, SurveySection, VideoSection,
};
use crate::pipeline::settings::{
    AssociationSection, BoxesSection, ColourSection, DetectSection, KalmanRtsSection, KltSection,
    ModelSettings, PoseSection, SmoothSection, TrackSection,
};
use crate::simulate::scene::{Ground, Motion, Scene};
use crate::survey::crs::{Crs, CrsError};

/// The hat scene's project: the colour detector (magenta hats), association tracking and the
/// Kalman/RTS smoother. `calibration` is a file beside the project or a preset name; `heights`
/// an optional heights CSV beside it.
pub fn hats_project(
    scene: &Scene,
    calibration: &str,
    heights: Option<&str>,
) -> Result<Project, CrsError> {
    let crs = Crs::new(&scene.site.crs)?;
    let o = scene.site.origin;
    let (lon, lat) = crs.to_lon_lat(o[0], o[1])?;
    Ok(Project {
        name: scene.name.clone(),
        camera: CameraSection {
            calibration: calibration.into(),
        },
        survey: SurveySection {
            gcps: "gcps.csv".into(),
            picks: vec!["picks.csv".into()],
            height: Some("ellipsoidal".into()),
            origin: Some(format!("{lat:.10},{lon:.10},{}", o[2])),
            ..SurveySection::new("gcps.csv")
        },
        video: VideoSection::new("video.mp4"),
        picks: PicksSection::default(),
        pose: PoseSection::default(),
        ground: ground(scene),
        detect: DetectSection::Colour(ColourSection {
            colour: [255, 0, 255],
            ..ColourSection::default()
        }),
        track: TrackSection::Association(AssociationSection::default()),
        projection: ProjectionSection {
            head_height_m: 1.7,
            head_height_sd_m: 0.1,
            heights: heights.map(str::to_string),
        },
        smooth: SmoothSection::KalmanRts(KalmanRtsSection::default()),
        export: ExportSection::default(),
        output: OutputSection::default(),
        analysis: analysis_areas(scene),
    })
}

/// `project` taking its picks from the video's first frame (`[picks] auto = true`: the targets
/// found and identified from their layout) instead of the simulator's `picks.csv`. The heading
/// is the hovering camera's, as a pilot would give it: the demos' targets are laid out in a
/// grid, which their layout alone cannot orient.
pub fn with_auto_picks(mut project: Project, scene: &Scene) -> Project {
    project.survey.picks = Vec::new();
    project.picks = PicksSection {
        auto: true,
        heading_deg: match &scene.camera.motion {
            Motion::Hover { heading_deg, .. } => Some(*heading_deg),
            _ => None,
        },
        ..PicksSection::default()
    };
    project
}

/// The scene's measurement and walkable areas (site frame): on a deck, its middle 8 m and the
/// whole deck; on a track, 10 m of the right-hand straight (15 to 25 m before its middle,
/// where the group demo's runners pass) and that straight's lanes; a measurement line across
/// the middle of the measurement area.
pub(crate) fn analysis_areas(scene: &Scene) -> AnalysisSection {
    let rect = |centre: [f64; 2], heading_deg: f64, along: [f64; 2], lateral: [f64; 2]| {
        let h = heading_deg.to_radians();
        let (a, l) = ([h.sin(), h.cos()], [-h.cos(), h.sin()]);
        let at = |u: f64, v: f64| {
            let p = [
                centre[0] + a[0] * u + l[0] * v,
                centre[1] + a[1] * u + l[1] * v,
            ];
            p.map(|x| (x * 1000.0).round() / 1000.0)
        };
        vec![
            at(along[0], lateral[0]),
            at(along[1], lateral[0]),
            at(along[1], lateral[1]),
            at(along[0], lateral[1]),
        ]
    };
    // A rectangle of no length is a line across the flow: its first and third corners.
    let across = |r: Vec<[f64; 2]>| [r[0], r[2]];
    match &scene.ground {
        Ground::Deck {
            centre,
            heading_deg,
            width_m,
            length_m,
            ..
        } => {
            let lateral = [-width_m / 2.0, width_m / 2.0];
            AnalysisSection {
                measurement_area: rect(*centre, *heading_deg, [-4.0, 4.0], lateral),
                measurement_lines: vec![across(rect(*centre, *heading_deg, [0.0, 0.0], lateral))],
                walkable_area: rect(
                    *centre,
                    *heading_deg,
                    [-length_m / 2.0, length_m / 2.0],
                    lateral,
                ),
            }
        }
        Ground::Track {
            centre,
            heading_deg,
            lanes,
            lane_width_m,
            straight_m,
            radius_m,
        } => {
            let lateral = [-(radius_m + f64::from(*lanes) * lane_width_m), -radius_m];
            AnalysisSection {
                measurement_area: rect(*centre, *heading_deg, [-25.0, -15.0], lateral),
                measurement_lines: vec![across(rect(
                    *centre,
                    *heading_deg,
                    [-20.0, -20.0],
                    lateral,
                ))],
                walkable_area: rect(
                    *centre,
                    *heading_deg,
                    [-straight_m / 2.0, straight_m / 2.0],
                    lateral,
                ),
            }
        }
    }
}

/// The group scene's project (a moving camera): every frame placed in the reference model
/// `model` (`geostride sfm` of the survey flight's photos in `model_images`; each key frame
/// matched with the photos nearest its telemetry) and checked against the drone's telemetry
/// (`video.SRT`, its heights ellipsoidal), the ground the model's local planes (2 m windows), the
/// hats' colour detector and association tracking.
pub fn group_project(
    scene: &Scene,
    calibration: &str,
    model: &str,
    model_images: &str,
    heights: Option<&str>,
) -> Result<Project, CrsError> {
    let hats = hats_project(scene, calibration, heights)?;
    Ok(Project {
        survey: SurveySection {
            picks: Vec::new(),
            ..hats.survey.clone()
        },
        video: VideoSection {
            telemetry: Some("video.SRT".into()),
            // The simulator writes ellipsoidal heights.
            telemetry_height: Some("ellipsoidal".into()),
            ..hats.video.clone()
        },
        pose: PoseSection::Model(ModelSettings {
            model: model.into(),
            model_images: model_images.into(),
            ..ModelSettings::default()
        }),
        ground: GroundSection::LocalPlanes {
            model: model.into(),
            window_m: 2.0,
        },
        ..hats
    })
}

/// The group scene's project with no survey flight: the model built by the run from the
/// video's own frames and the GCP picks on them (`picks-frames.csv`, every second's frame), its
/// points the local planes' ground; otherwise [`group_project`]'s.
pub fn group_video_project(scene: &Scene, calibration: &str) -> Result<Project, CrsError> {
    let mut project = group_project(scene, calibration, "", "", None)?;
    project.survey.picks = vec!["picks-frames.csv".into()];
    // A frame a second (the picked ones): the drone follows runners at under 4 m/s, so
    // neighbours overlap by over 80 %.
    if let PoseSection::Model(m) = &mut project.pose {
        m.frames_every_s = 1.0;
    }
    project.ground = GroundSection::LocalPlanes {
        model: String::new(),
        window_m: 2.0,
    };
    Ok(project)
}

/// The crowd scene's project: an external detector's boxes (`boxes`, a MOTChallenge file beside
/// the project; `shadow_samples` `[frame, x, y, w, h]` patches of shadow) and KLT tracking.
pub fn crowd_project(
    scene: &Scene,
    calibration: &str,
    boxes: &str,
    shadow_samples: &[[f64; 5]],
) -> Result<Project, CrsError> {
    Ok(Project {
        detect: DetectSection::Boxes(BoxesSection {
            boxes: boxes.into(),
            shadow_samples: shadow_samples.iter().map(|s| s.map(f64::round)).collect(),
            ..BoxesSection::default()
        }),
        track: TrackSection::Klt(KltSection::default()),
        ..hats_project(scene, calibration, None)?
    })
}

/// A deck's centre line in the site CRS (the scene's origin is the deck's middle), with its
/// profile fitted to the control GCPs on it; any other ground a plane fitted to them.
fn ground(scene: &Scene) -> GroundSection {
    match &scene.ground {
        Ground::Deck {
            heading_deg,
            width_m,
            length_m,
            ..
        } => {
            let o = scene.site.origin;
            let (dx, dy) = (
                heading_deg.to_radians().sin() * length_m / 2.0,
                heading_deg.to_radians().cos() * length_m / 2.0,
            );
            // Millimetres, as the project file has always given them.
            let mm = |v: f64| (v * 1000.0).round() / 1000.0;
            GroundSection::Deck {
                centre_line: vec![
                    [mm(o[0] - dx), mm(o[1] - dy)],
                    [mm(o[0] + dx), mm(o[1] + dy)],
                ],
                width_m: *width_m,
                stations: Vec::new(),
                degree: 2,
            }
        }
        _ => GroundSection::Plane { height_m: None },
    }
}

/// The project file's text: a comment, then every key of every section (the defaults written
/// out, so that the file shows what can be set).
pub fn project_text(project: &Project, comment: &str) -> Result<String, toml::ser::Error> {
    let mut text = String::new();
    for line in comment.lines() {
        text.push_str("# ");
        text.push_str(line);
        text.push('\n');
    }
    text.push('\n');
    text.push_str(&toml::to_string(project)?);
    Ok(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scene_project_reads_back_as_written() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("surveys/bridge-stream/scene.toml");
        let scene = Scene::load(&path).unwrap();
        let p = crowd_project(
            &scene,
            "mini3pro",
            "boxes.txt",
            &[[0.0, 10.2, 20.0, 5.0, 6.0]],
        )
        .unwrap();
        let text = project_text(&p, "a test\nof two lines").unwrap();
        assert!(text.starts_with("# a test\n# of two lines\n"));
        let back: Project = toml::from_str(&text).unwrap();
        assert_eq!(back, p);
        assert!(text.contains("kind = \"boxes\""));
        assert!(text.contains("kind = \"klt\""));
    }
}
