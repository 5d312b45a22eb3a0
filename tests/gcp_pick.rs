//! `geostride gcp pick`, the picking page, in a real browser: headless Chromium (Debian's, from
//! scripts/bootstrap.sh) driven by tests/browser/pick_page.py opens the page on a simulated
//! frame whose targets `--find` picked, zooms, drags one pick, rejects one, accepts one, is
//! refused a save over an input, saves and quits; the saved CSV is checked here. The server's
//! own guards (Host, Origin, saves over inputs) are checked with raw requests.

#![cfg(all(feature = "opencv", feature = "gdal"))]

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The server, killed if the test ends before it quits.
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A raw request; the status code and the body.
fn request(port: u16, head: &str, body: &str) -> (u16, String) {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    write!(
        s,
        "{head}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    let status = text[9..12].parse().unwrap();
    let body = text.split_once("\r\n\r\n").unwrap().1.to_string();
    (status, body)
}

fn browser_ready() {
    for tool in ["/usr/bin/chromium", "/usr/bin/chromedriver"] {
        assert!(
            Path::new(tool).exists(),
            "{tool} is missing: scripts/bootstrap.sh installs chromium and chromium-driver"
        );
    }
}

#[test]
fn a_person_moves_rejects_accepts_and_saves_picks_in_a_real_browser() {
    browser_ready();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    common::targets::simulate(dir, &common::target_scene(20.0, &common::IRREGULAR_GCPS));
    let find = common::geostride()
        .current_dir(dir)
        .args(["gcp", "find", "sim/video.mp4", "--gcps", "sim/gcps.csv"])
        .args(["--out", "found.csv"])
        .output()
        .unwrap();
    common::assert_success(&find);
    let found = common::picks(&dir.join("found.csv"));
    assert_eq!(found.len(), 7);

    let mut server = Server(
        common::geostride()
            .current_dir(dir)
            .args([
                "gcp",
                "pick",
                "sim/video.mp4",
                "--gcps",
                "sim/gcps.csv",
                "--find",
            ])
            .args([
                "--camera",
                "sim/camera.json",
                "--out",
                "picked.csv",
                "--port",
                "0",
            ])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut lines = BufReader::new(server.0.stdout.take().unwrap()).lines();
    let first = lines.next().unwrap().unwrap();
    let url = first
        .split_whitespace()
        .find(|w| w.starts_with("http://127.0.0.1:"))
        .unwrap_or_else(|| panic!("no address in '{first}'"))
        .to_string();
    let port: u16 = url["http://127.0.0.1:".len()..url.len() - 1]
        .parse()
        .unwrap();

    // The server's guards.
    let host = format!("Host: 127.0.0.1:{port}");
    let (status, state) = request(port, &format!("GET /api/state HTTP/1.1\r\n{host}"), "");
    assert_eq!(status, 200, "{state}");
    assert_eq!(state.matches("\"status\":\"auto\"").count(), 7, "{state}");
    let (status, why) = request(port, "GET /api/state HTTP/1.1\r\nHost: evil.example", "");
    assert_eq!(
        status, 403,
        "a foreign Host (DNS rebinding) is refused: {why}"
    );
    let (status, why) = request(
        port,
        &format!("POST /api/save HTTP/1.1\r\n{host}\r\nOrigin: http://evil.example"),
        r#"{"path":"x.csv","picks":[]}"#,
    );
    assert_eq!(status, 403, "a foreign Origin is refused: {why}");
    assert!(!dir.join("x.csv").exists());
    let save_over = r#"{"path":"sim/gcps.csv","picks":[{"name":"G1","image":"video.mp4#0","u":1,"v":1,"sigma":1}]}"#;
    let (status, why) = request(
        port,
        &format!("POST /api/save HTTP/1.1\r\n{host}"),
        save_over,
    );
    assert_eq!(status, 409, "{why}");
    assert!(why.contains("overwrite the input"), "{why}");

    // The person, in Chromium.
    let shot = dir.join("page.png");
    let driver = Command::new("/usr/bin/python3")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/browser/pick_page.py"))
        .arg(&url)
        .args(["--move", "G1", "--reject", "G2", "--accept", "G3"])
        .args([
            "--input",
            "sim/gcps.csv",
            "--save",
            "saved.csv",
            "--screenshot",
        ])
        .arg(&shot)
        .output()
        .unwrap();
    assert!(
        driver.status.success(),
        "the browser driver failed:\n{}",
        String::from_utf8_lossy(&driver.stderr)
    );
    let seen: serde_json::Value = serde_json::from_slice(&driver.stdout).unwrap();

    // The page's Quit ends the server.
    let start = Instant::now();
    loop {
        if let Some(status) = server.0.try_wait().unwrap() {
            assert!(status.success());
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "Quit did not end the server"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    assert!(
        rest.iter()
            .any(|l| l.contains("Saved 6 picks to saved.csv")),
        "{rest:?}"
    );

    let scale = |k: &str| seen[k].as_f64().unwrap();
    assert!(scale("scale_after") > 1.5 * scale("scale_before"), "{seen}");
    assert!(
        seen["refusal"]
            .as_str()
            .unwrap()
            .contains("overwrite the input"),
        "{seen}"
    );
    assert_eq!(seen["rejected"], "rejected");
    assert_eq!(seen["accepted"], "accepted");
    // The moved pick is flagged by the live pose fit, the others fit within a pixel.
    let message = seen["fit_message"].as_str().unwrap();
    assert!(message.contains("G1 disagrees"), "{message}");

    let saved = common::picks(&dir.join("saved.csv"));
    assert_eq!(saved.len(), 6, "all but the rejected G2: {saved:?}");
    assert!(!saved.contains_key("G2"));
    let m = &seen["moved"];
    let at = |k: &str| m[k].as_f64().unwrap();
    let (u, v, sigma) = saved["G1"];
    // Dragged 30 px right and 20 px down on screen, at the page's zoom.
    let s = at("scale");
    assert!((at("u0") - found["G1"].0).abs() < 1e-3 && (at("v0") - found["G1"].1).abs() < 1e-3);
    assert!(
        (u - at("u1")).abs() < 1e-3 && (v - at("v1")).abs() < 1e-3,
        "{m} vs {u},{v}"
    );
    assert!((u - at("u0") - 30.0 / s).abs() < 1.0 / s, "{m}");
    assert!((v - at("v0") - 20.0 / s).abs() < 1.0 / s, "{m}");
    assert_eq!(sigma, 0.5, "a hand pick's σ");
    for (name, (fu, fv, fs)) in &found {
        if name == "G1" || name == "G2" {
            continue;
        }
        let (u, v, s) = saved[name];
        assert!((u - fu).abs() < 2e-3 && (v - fv).abs() < 2e-3 && (s - fs).abs() < 2e-3);
    }
    assert!(
        !dir.join("picked.csv").exists(),
        "nothing saved to --out unasked"
    );
    if let Some(to) = std::env::var_os("GEOSTRIDE_PICK_SCREENSHOT") {
        std::fs::copy(&shot, to).unwrap();
    }
}
