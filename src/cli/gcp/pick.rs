//! `geostride gcp pick`: the picking page, served by geostride on 127.0.0.1. A person confirms,
//! moves or rejects automatic picks and places the missing ones; each change is fitted at once
//! (a pose with a calibration, else the ground plane's homography) and its residuals shown.

use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};

use anyhow::Context;
use nalgebra::{Matrix3, Vector2, Vector3};
use serde::Deserialize;
use serde_json::{Value, json};

use super::http::{Request, Response, foreign, read_request, write_response};
use super::{Searcher, load_bgr};
use crate::cli::survey::{ReadArgs, read_framed};
use crate::cli::{bad_input, check_output_file};
use geostride::camera::Camera;
use geostride::estimate::homography::homography_dlt;
use geostride::pose::refine::project_pose;
use geostride::pose::{GcpObservation, PoseSettings, solve_pose};
use geostride::survey::Role;
use geostride::targets::Gray;

const PAGE: &str = include_str!("pick_page.html");

/// σ given to a pick placed or moved by hand, pixels: a careful click in the loupe.
const HAND_SIGMA_PX: f64 = 0.5;

#[derive(clap::Args)]
pub struct PickArgs {
    /// Photos (any format OpenCV reads) or videos (the frame --frame is shown)
    #[arg(required = true, value_name = "IMAGE-OR-VIDEO")]
    inputs: Vec<PathBuf>,
    /// Ground control points: any survey file `geostride survey` reads
    #[arg(long, value_name = "FILE")]
    gcps: PathBuf,
    #[command(flatten)]
    read: ReadArgs,
    /// The video frame to show; its picks are named 'VIDEO#N' as `pose` reads them
    #[arg(long, default_value = "0", value_name = "N")]
    frame: usize,
    /// Camera calibration (as `pose --camera`): residuals against a solved pose. Without one,
    /// against the homography of the ground taken as a plane
    #[arg(long, value_name = "CAL")]
    camera: Option<String>,
    /// Search each image without picks for targets first (--heading, --min-contrast, --design
    /// below), as `gcp find` does
    #[arg(long)]
    find: bool,
    // With --find: how targets are searched for, as `gcp find`.
    #[command(flatten)]
    search: super::SearchArgs,
    /// The picks CSV the page saves to (the page may name another; never an input)
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Port on 127.0.0.1 (0: any free one; the page's address is printed)
    #[arg(long, default_value = "0", value_name = "N")]
    port: u16,
}

struct PageImage {
    path: PathBuf,
    name: String,
    width: usize,
    height: usize,
}

struct Site {
    names: Vec<String>,
    roles: Vec<Role>,
    local: Vec<Vector3<f64>>,
    world_cov: Vec<Matrix3<f64>>,
    images: Vec<PageImage>,
    picks: Vec<Value>,
    /// One calibration for each image size, when given.
    cameras: Vec<Option<Camera>>,
    inputs: Vec<PathBuf>,
    out: PathBuf,
    frame: usize,
}

pub fn pick(args: &PickArgs) -> anyhow::Result<()> {
    let mut inputs: Vec<PathBuf> = args.inputs.clone();
    inputs.push(args.gcps.clone());
    inputs.extend(args.read.picks.iter().cloned());
    check_output_file(&args.out, &inputs)?;
    let framed = read_framed(&args.gcps, &args.read, None).map_err(bad_input)?;
    for path in &args.inputs {
        super::check_area(&framed, &args.gcps, path)?;
    }
    let points = &framed.survey.points;
    let mut site = Site {
        names: points.iter().map(|p| p.name.clone()).collect(),
        roles: points.iter().map(|p| p.role).collect(),
        local: framed.local.clone(),
        world_cov: points
            .iter()
            .map(|p| {
                let s = p.sigma_m.unwrap_or(Vector3::from_element(0.02));
                framed
                    .frame
                    .local_covariance(&p.position, &s)
                    .unwrap_or_else(|_| Matrix3::from_diagonal(&s.component_mul(&s)))
            })
            .collect(),
        images: Vec::new(),
        picks: Vec::new(),
        cameras: Vec::new(),
        inputs,
        out: args.out.clone(),
        frame: args.frame,
    };
    let searcher = match args.find {
        true => Some(Searcher::new(&framed, &args.search)?),
        false => None,
    };
    for path in &args.inputs {
        let (bgr, width, height, name) = load_bgr(path, args.frame)?;
        let from_file: Vec<Value> = points
            .iter()
            .flat_map(|p| p.observations.iter().map(move |o| (p, o)))
            .filter(|(_, o)| o.image == name)
            .map(|(p, o)| {
                json!({"name": p.name, "image": name, "u": o.uv.x, "v": o.uv.y,
                       "sigma": o.sigma_px.unwrap_or(1.0), "status": "file"})
            })
            .collect();
        if let Some(searcher) = searcher.as_ref().filter(|_| from_file.is_empty()) {
            site.picks
                .extend(find_picks(searcher, &bgr, width, height, &name, path));
        }
        site.picks.extend(from_file);
        let camera = match &args.camera {
            Some(spec) => {
                let size = (width as u32, height as u32);
                Some(crate::cli::pose::camera_for(spec, Some(size))?.0)
            }
            None => None,
        };
        site.cameras.push(camera);
        site.images.push(PageImage {
            path: path.clone(),
            name,
            width,
            height,
        });
    }
    serve(&site, args.port)
}

/// Picks from target detection, marked "auto" for the person to confirm.
fn find_picks(
    searcher: &Searcher,
    bgr: &[u8],
    width: usize,
    height: usize,
    name: &str,
    path: &Path,
) -> Vec<Value> {
    let gray = Gray::from_bgr(bgr, width, height);
    let report = searcher.search(&gray, name.to_string(), path);
    if let Some(why) = &report.not_identified {
        println!("{name}: no automatic picks ({why})");
    }
    report
        .targets
        .iter()
        .filter_map(|t| {
            let n = t.name.as_ref()?;
            Some(json!({"name": n, "image": name, "u": t.u, "v": t.v,
                        "sigma": t.sigma_px, "status": "auto"}))
        })
        .collect()
}

fn serve(site: &Site, port: u16) -> anyhow::Result<()> {
    let listener = TcpListener::bind(("127.0.0.1", port))
        .with_context(|| format!("cannot listen on 127.0.0.1:{port} (in use? try --port 0)"))?;
    let port = listener.local_addr()?.port();
    println!(
        "Picking page: http://127.0.0.1:{port}/  ({} image(s), {} points; Quit in the page or Ctrl-C ends)",
        site.images.len(),
        site.names.len()
    );
    use std::io::Write as _;
    let _ = std::io::stdout().flush();
    for stream in listener.incoming() {
        let Ok(stream) = stream else { continue };
        if handle(site, port, &stream) {
            break;
        }
    }
    println!("Picking page closed");
    Ok(())
}

/// Answers one connection; true when the page asked to quit.
fn handle(site: &Site, port: u16, stream: &TcpStream) -> bool {
    let req = match read_request(stream) {
        Ok(r) => r,
        Err((status, message)) => {
            write_response(stream, &Response::error(status, message));
            return false;
        }
    };
    if let Some(why) = foreign(&req, port) {
        eprintln!("refused {} {}: {why}", req.method, req.path);
        write_response(stream, &Response::error(403, why));
        return false;
    }
    let quit = req.method == "POST" && req.path == "/api/quit";
    let response = route(site, &req);
    write_response(stream, &response);
    quit
}

fn route(site: &Site, req: &Request) -> Response {
    let path = req.path.split('?').next().unwrap_or("");
    match (req.method.as_str(), path) {
        ("GET", "/") => Response {
            status: 200,
            content_type: "text/html; charset=utf-8",
            body: PAGE.as_bytes().to_vec(),
        },
        ("GET", "/api/state") => Response::json(200, &state(site)),
        ("GET", p) if p.starts_with("/api/image/") => image(site, &p["/api/image/".len()..]),
        ("POST", "/api/fit") => match serde_json::from_slice::<FitRequest>(&req.body) {
            Ok(f) => fit(site, &f),
            Err(e) => Response::error(400, format!("a fit request: {e}")),
        },
        ("POST", "/api/save") => match serde_json::from_slice::<SaveRequest>(&req.body) {
            Ok(s) => save(site, &s),
            Err(e) => Response::error(400, format!("a save request: {e}")),
        },
        ("POST", "/api/quit") => Response::json(200, &json!({"quit": true})),
        ("GET" | "POST", _) => Response::error(404, format!("no page '{path}'")),
        _ => Response::error(405, format!("method {} not served", req.method)),
    }
}

fn state(site: &Site) -> Value {
    let gcps: Vec<Value> = (0..site.names.len())
        .map(|i| {
            let p = site.local[i];
            json!({"name": site.names[i], "role": site.roles[i].to_string(),
                   "e": p.x, "n": p.y, "h": p.z})
        })
        .collect();
    let images: Vec<Value> = site
        .images
        .iter()
        .map(|im| json!({"name": im.name, "width": im.width, "height": im.height}))
        .collect();
    json!({
        "images": images,
        "gcps": gcps,
        "picks": site.picks,
        "out": site.out.display().to_string(),
        "model": if site.cameras.iter().any(Option::is_some) { "pose" } else { "homography" },
        "hand_sigma_px": HAND_SIGMA_PX,
    })
}

fn image(site: &Site, index: &str) -> Response {
    let Some(im) = index.parse::<usize>().ok().and_then(|i| site.images.get(i)) else {
        return Response::error(404, format!("no image {index}"));
    };
    let encoded = load_bgr(&im.path, site.frame).and_then(|(bgr, w, h, _)| {
        geostride::imageio::encode_bgr_png(&bgr, w, h).map_err(anyhow::Error::from)
    });
    match encoded {
        Ok(body) => Response {
            status: 200,
            content_type: "image/png",
            body,
        },
        Err(e) => Response::error(500, format!("{}: {e:#}", im.name)),
    }
}

#[derive(Deserialize)]
struct PagePick {
    name: String,
    #[serde(default)]
    image: String,
    u: f64,
    v: f64,
    sigma: f64,
}

#[derive(Deserialize)]
struct FitRequest {
    image: usize,
    picks: Vec<PagePick>,
}

/// Every point's predicted position and every pick's residual against a fit of this image's
/// control picks.
fn fit(site: &Site, f: &FitRequest) -> Response {
    let Some(im) = site.images.get(f.image) else {
        return Response::error(400, format!("no image {}", f.image));
    };
    let mut picked: Vec<(usize, Vector2<f64>, f64)> = Vec::new();
    for p in &f.picks {
        let Some(i) = site.names.iter().position(|n| *n == p.name) else {
            return Response::error(400, format!("no surveyed point '{}'", p.name));
        };
        if !(p.u.is_finite() && p.v.is_finite() && p.sigma > 0.0) {
            return Response::error(400, format!("the pick of '{}' is not finite", p.name));
        }
        picked.push((i, Vector2::new(p.u, p.v), p.sigma));
    }
    let control: Vec<&(usize, Vector2<f64>, f64)> = picked
        .iter()
        .filter(|(i, _, _)| site.roles[*i] == Role::Control && site.local[*i].z.is_finite())
        .collect();
    let predict: Result<Predictions, String> = match &site.cameras[f.image] {
        Some(camera) => pose_predictions(site, camera, &control),
        None => homography_predictions(site, &control),
    };
    let (predicted, outliers) = match predict {
        Ok(p) => p,
        Err(message) => return Response::json(200, &json!({"fitted": false, "message": message})),
    };
    let mut sq = Vec::new();
    let points: Vec<Value> = (0..site.names.len())
        .map(|i| {
            let pred = predicted[i].filter(|p| {
                p.x > -0.5 * im.width as f64 && p.x < 1.5 * im.width as f64 && p.y.is_finite()
            });
            let pick = picked.iter().find(|(j, _, _)| *j == i);
            let residual = pick.zip(pred).map(|((_, uv, _), p)| uv - p);
            let outlier = outliers.contains(&site.names[i]);
            if let Some(r) = residual
                && site.roles[i] == Role::Control
                && !outlier
            {
                sq.push(r.norm_squared());
            }
            json!({"name": site.names[i],
                   "predicted": pred.map(|p| [p.x, p.y]),
                   "residual": residual.map(|r| [r.x, r.y, r.norm()]),
                   "outlier": outlier})
        })
        .collect();
    let rms = (sq.iter().sum::<f64>() / sq.len().max(1) as f64).sqrt();
    let message = match (&site.cameras[f.image], control.len()) {
        (None, 4) => "4 picks fit any homography: a fifth shows residuals".to_string(),
        (None, _) => format!("{} control picks, ground taken as a plane", control.len()),
        (Some(_), n) if outliers.is_empty() => format!("pose from {n} control picks"),
        (Some(_), n) => format!(
            "pose from {} of {n} control picks ({} {})",
            n - outliers.len(),
            outliers.join(", "),
            if outliers.len() == 1 {
                "disagrees"
            } else {
                "disagree"
            }
        ),
    };
    Response::json(
        200,
        &json!({"fitted": true, "message": message, "rms_px": rms, "points": points}),
    )
}

/// Every point's predicted pixel, and the names of picks the fit found to disagree.
type Predictions = (Vec<Option<Vector2<f64>>>, Vec<String>);

fn pose_predictions(
    site: &Site,
    camera: &Camera,
    control: &[&(usize, Vector2<f64>, f64)],
) -> Result<Predictions, String> {
    if control.len() < 4 {
        return Err(format!(
            "{} control picks: a pose needs 4 (3 fit many)",
            control.len()
        ));
    }
    let obs: Vec<GcpObservation> = control
        .iter()
        .map(|(i, uv, s)| GcpObservation {
            name: site.names[*i].clone(),
            world: site.local[*i],
            world_cov: site.world_cov[*i],
            uv: *uv,
            sigma_px: *s,
        })
        .collect();
    let solution = solve_pose(camera, &obs, &PoseSettings::default())
        .map_err(|e| format!("no pose from these picks: {e}"))?;
    let predicted = site
        .local
        .iter()
        .map(|w| project_pose(camera, &solution.cam_from_world, w).map(|p| p.0))
        .collect();
    let outliers = solution
        .residuals
        .iter()
        .filter(|r| r.outlier)
        .map(|r| r.name.clone())
        .collect();
    Ok((predicted, outliers))
}

fn homography_predictions(
    site: &Site,
    control: &[&(usize, Vector2<f64>, f64)],
) -> Result<Predictions, String> {
    if control.len() < 4 {
        return Err(format!(
            "{} control picks: the ground's homography needs 4",
            control.len()
        ));
    }
    let src: Vec<Vector2<f64>> = control
        .iter()
        .map(|(i, _, _)| site.local[*i].xy())
        .collect();
    let dst: Vec<Vector2<f64>> = control.iter().map(|(_, uv, _)| *uv).collect();
    let h = homography_dlt(&src, &dst).map_err(|e| format!("no homography: {e}"))?;
    let predicted = site
        .local
        .iter()
        .map(|p| {
            let q = h * Vector3::new(p.x, p.y, 1.0);
            (q.z.abs() > 1e-12).then(|| Vector2::new(q.x / q.z, q.y / q.z))
        })
        .collect();
    Ok((predicted, Vec::new()))
}

#[derive(Deserialize)]
struct SaveRequest {
    path: String,
    picks: Vec<PagePick>,
}

fn save(site: &Site, s: &SaveRequest) -> Response {
    let path = Path::new(s.path.trim());
    if s.path.trim().is_empty() {
        return Response::error(409, "name the file to save to");
    }
    if let Err(e) = check_output_file(path, &site.inputs) {
        return Response::error(409, format!("{e:#}"));
    }
    if s.picks.is_empty() {
        return Response::error(409, "no picks to save (every one is rejected?)");
    }
    let mut csv = String::from("name,image,u,v,sigma\n");
    for p in &s.picks {
        let bad = |what: &str| Response::error(400, format!("the pick of '{}': {what}", p.name));
        if !site.names.contains(&p.name) {
            return bad("not a surveyed point");
        }
        if !site.images.iter().any(|im| im.name == p.image) {
            return bad("not in an image of this page");
        }
        if !(p.u.is_finite() && p.v.is_finite() && p.sigma.is_finite() && p.sigma > 0.0) {
            return bad("u, v and a positive sigma are needed");
        }
        if p.name.contains([',', '"', '\n']) || p.image.contains([',', '"', '\n']) {
            return bad("a name with a comma or quote cannot go into the CSV");
        }
        csv.push_str(&format!(
            "{},{},{:.3},{:.3},{:.3}\n",
            p.name, p.image, p.u, p.v, p.sigma
        ));
    }
    match geostride::io::write_atomic(path, csv.as_bytes()) {
        Ok(()) => {
            println!("Saved {} picks to {}", s.picks.len(), path.display());
            Response::json(
                200,
                &json!({"written": path.display().to_string(), "count": s.picks.len()}),
            )
        }
        Err(e) => Response::error(409, format!("writing {}: {e}", path.display())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(host: Option<&str>, origin: Option<&str>) -> Request {
        Request {
            method: "GET".into(),
            path: "/".into(),
            host: host.map(String::from),
            origin: origin.map(String::from),
            fetch_site: None,
            body: Vec::new(),
        }
    }

    #[test]
    fn only_this_servers_host_and_origin_are_served() {
        assert!(foreign(&request(Some("127.0.0.1:8123"), None), 8123).is_none());
        assert!(
            foreign(
                &request(Some("localhost:8123"), Some("http://localhost:8123")),
                8123
            )
            .is_none()
        );
        assert!(foreign(&request(None, None), 8123).is_some());
        assert!(foreign(&request(Some("evil.example:8123"), None), 8123).is_some());
        assert!(foreign(&request(Some("127.0.0.1:9999"), None), 8123).is_some());
        let cross = request(Some("127.0.0.1:8123"), Some("http://evil.example"));
        assert!(foreign(&cross, 8123).unwrap().contains("Origin"));
    }
}
