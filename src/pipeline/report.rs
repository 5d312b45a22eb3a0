//! The run's report (`report.json`, `report.md`) and how a run shows its progress stage by stage.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::provenance::InputRecord;
use crate::progress::Progress;

/// Whether a stage's result was computed by this run or reused from the output folder's cache.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum StageStatus {
    Computed,
    Reused,
    /// Some of the stage's pieces (the scan's chunks) reused, the others computed.
    #[serde(rename = "partly reused")]
    PartlyReused,
}

impl std::fmt::Display for StageStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            StageStatus::Computed => "computed",
            StageStatus::Reused => "reused",
            StageStatus::PartlyReused => "partly reused",
        })
    }
}

/// Shows progress per stage.
pub trait StageProgress {
    fn stage(&self, name: &str) -> Box<dyn Progress>;
    /// Called once a stage's result is stored in the run's cache (a run killed from now on
    /// resumes after this stage).
    fn stored(&self, _stage: &str) {}
}

/// Shows nothing.
pub struct Silent;

impl StageProgress for Silent {
    fn stage(&self, _: &str) -> Box<dyn Progress> {
        Box::new(crate::progress::NoProgress)
    }
}

impl StageRecord {
    /// The stage's numbers as `key value, ...`: whole numbers without decimals, others with
    /// `decimals`.
    pub fn numbers(&self, decimals: usize) -> String {
        self.counts
            .iter()
            .map(|(k, v)| {
                if v.fract() == 0.0 && v.abs() < 1e12 {
                    format!("{k} {v:.0}")
                } else {
                    format!("{k} {v:.decimals$}")
                }
            })
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// One stage of a run.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct StageRecord {
    pub name: String,
    pub status: StageStatus,
    pub seconds: f64,
    pub counts: BTreeMap<String, f64>,
}

/// The run report.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunReport {
    pub project: String,
    pub geostride_version: String,
    pub inputs: Vec<InputRecord>,
    pub parameters: super::project::Project,
    pub site_frame: String,
    pub output_crs: String,
    /// How GeoJSON's WGS 84 coordinates were made from the output CRS: PROJ's operations.
    #[serde(default)]
    pub wgs84_transformations: Vec<String>,
    pub stages: Vec<StageRecord>,
    pub outputs: Vec<String>,
    /// The plots, site images and video: (title, file in the output folder).
    #[serde(default)]
    pub views: Vec<(String, String)>,
    /// The project file the run read (`geostride render` reads it again).
    #[serde(default)]
    pub project_file: String,
    pub warnings: Vec<String>,
}

/// The report as Markdown.
pub(crate) fn report_markdown(r: &RunReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "# geostride run: {}\n", r.project);
    let _ = writeln!(
        s,
        "geostride {}; site frame: {}; output CRS: {}\n",
        r.geostride_version, r.site_frame, r.output_crs
    );
    let _ = writeln!(
        s,
        "## Inputs\n\n| role | file | bytes | SHA-256 |\n|---|---|---|---|"
    );
    for i in &r.inputs {
        let _ = writeln!(
            s,
            "| {} | {} | {} | `{}` |",
            i.role, i.path, i.bytes, i.sha256
        );
    }
    let _ = writeln!(
        s,
        "\n## Stages\n\n| stage | status | seconds | numbers |\n|---|---|---|---|"
    );
    for st in &r.stages {
        let _ = writeln!(
            s,
            "| {} | {} | {:.2} | {} |",
            st.name,
            st.status,
            st.seconds,
            st.numbers(4)
        );
    }
    let _ = writeln!(s, "\n## Outputs\n");
    for o in &r.outputs {
        let _ = writeln!(s, "- `{o}`");
    }
    if !r.wgs84_transformations.is_empty() {
        let _ = writeln!(s, "\nWGS 84 (GeoJSON) through PROJ:\n");
        for t in &r.wgs84_transformations {
            let _ = writeln!(s, "- {t}");
        }
    }
    if !r.views.is_empty() {
        let _ = writeln!(s, "\n## Views\n");
        for (title, file) in &r.views {
            if file.ends_with(".png") {
                let _ = writeln!(s, "### {title}\n\n![{title}]({file})\n");
            } else {
                let _ = writeln!(s, "- {title}: [`{file}`]({file})");
            }
        }
    }
    if !r.warnings.is_empty() {
        let _ = writeln!(s, "\n## Warnings\n");
        for w in &r.warnings {
            let _ = writeln!(s, "- {w}");
        }
    }
    let _ = writeln!(
        s,
        "\n## Parameters\n\n```toml\n{}```",
        toml::to_string(&r.parameters).unwrap_or_default()
    );
    s
}
