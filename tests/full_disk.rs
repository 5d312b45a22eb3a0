//! A full disk or a kill never leaves an invalid file under a final name, and the command exits
//! non-zero. The disk is a small tmpfs mounted in a user and mount namespace of the test's own
//! (`unshare -rm`), filled to different points of a run; a killed run's temporaries are removed by
//! the next one.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{assert_success, geostride};

/// Whether this machine lets an unprivileged process mount a tmpfs in its own namespace.
fn can_mount() -> bool {
    Command::new("unshare")
        .args([
            "-rm",
            "sh",
            "-c",
            "mount -t tmpfs -o size=64k none /tmp && true",
        ])
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Runs geostride with `args` where `disk` is a fresh tmpfs of `size_kb`.
fn on_small_disk(disk: &Path, size_kb: usize, args: &[String]) -> std::process::Output {
    let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
    let script = format!(
        "mount -t tmpfs -o size={size_kb}k none '{}' && exec '{}' {}",
        disk.display(),
        env!("CARGO_BIN_EXE_geostride"),
        quoted.join(" ")
    );
    Command::new("unshare")
        .args(["-rm", "sh", "-c", &script])
        .output()
        .unwrap()
}

/// A short simulated hover with a project file.
fn project(dir: &Path) -> PathBuf {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scenes/hover-drift.toml");
    assert_success(
        &geostride()
            .arg("simulate")
            .arg(&scene)
            .arg("--out")
            .arg(dir)
            .args(["--duration", "1", "-q"])
            .output()
            .unwrap(),
    );
    let video = common::simulated_video(dir);
    let p = dir.join("project.toml");
    std::fs::write(
        &p,
        common::hover_project(
            "full disk",
            video,
            "kind = \"plane\"",
            "formats = [\"csv\", \"geojson\", \"gpkg\", \"petrack\", \"mot\"]",
        ),
    )
    .unwrap();
    p
}

/// Every file under `dir`, recursively.
fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return out;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            out.extend(files(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// Whether a file left by a run is whole: JSON parses, a stage cache has its stated length, text
/// ends with a newline, a GeoPackage opens in GDAL, a PNG has its end chunk.
fn whole(p: &Path) -> Result<(), String> {
    let name = p.file_name().unwrap().to_string_lossy().into_owned();
    let bytes = std::fs::read(p).map_err(|e| e.to_string())?;
    let ext = p
        .extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_default();
    match ext.as_str() {
        "json" | "geojson" => serde_json::from_slice::<serde_json::Value>(&bytes)
            .map(|_| ())
            .map_err(|e| format!("{name}: {e}")),
        "bin" => geostride::cache::cache_file_whole(p)
            .then_some(())
            .ok_or(format!("{name}: not a whole stage cache")),
        "gpkg" => {
            let o = Command::new("ogrinfo")
                .args(["-ro", "-so", "-al"])
                .arg(p)
                .output();
            match o {
                Ok(o) if o.status.success() => Ok(()),
                Ok(o) => Err(format!("{name}: {}", String::from_utf8_lossy(&o.stderr))),
                Err(e) => Err(format!("ogrinfo: {e}")),
            }
        }
        "tif" => {
            // Every tile read: a cut-short GeoTIFF fails here.
            let o = Command::new("gdalinfo").arg("-checksum").arg(p).output();
            match o {
                Ok(o)
                    if o.status.success()
                        && !String::from_utf8_lossy(&o.stderr).contains("ERROR") =>
                {
                    Ok(())
                }
                Ok(o) => Err(format!("{name}: {}", String::from_utf8_lossy(&o.stderr))),
                Err(e) => Err(format!("gdalinfo: {e}")),
            }
        }
        "png" => {
            if bytes.ends_with(&[0xAE, 0x42, 0x60, 0x82]) {
                Ok(())
            } else {
                Err(format!("{name}: no PNG end chunk"))
            }
        }
        _ => {
            if bytes.is_empty() || bytes.ends_with(b"\n") {
                Ok(())
            } else {
                Err(format!("{name}: does not end with a newline"))
            }
        }
    }
}

#[test]
fn a_full_disk_leaves_no_invalid_file_and_exits_non_zero() {
    if !can_mount() {
        eprintln!(
            "SKIPPED: this machine does not let a test mount a small file system (unshare -rm); the full-disk cases did not run"
        );
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let project = project(&tmp.path().join("p"));
    // What a whole run writes, for the sizes to try.
    let full = tmp.path().join("full");
    assert_success(
        &geostride()
            .arg("run")
            .arg(&project)
            .arg("--out")
            .arg(&full)
            .arg("-q")
            .output()
            .unwrap(),
    );
    let total: u64 = files(&full)
        .iter()
        .map(|f| f.metadata().unwrap().len())
        .sum();
    let disk = tmp.path().join("disk");
    std::fs::create_dir(&disk).unwrap();
    let out = disk.join("out");
    let mut failed_runs = 0;
    // From a disk too small for the first stage to one that holds nearly everything.
    for fraction in [0.02, 0.1, 0.3, 0.5, 0.7, 0.85, 0.95] {
        let size_kb = ((total as f64 * fraction) / 1024.0).ceil() as usize + 8;
        let args = [
            "run".to_string(),
            project.display().to_string(),
            "--out".into(),
            out.display().to_string(),
            "-q".into(),
        ];
        // The disk lives in the namespace only: to look at what was left, the command lists the
        // files and copies them out.
        let keep = tmp.path().join(format!("left-{size_kb}"));
        std::fs::create_dir(&keep).unwrap();
        let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
        let script = format!(
            "mount -t tmpfs -o size={size_kb}k none '{}' && '{}' {}; rc=$?; cp -a '{}/.' '{}' 2>/dev/null; exit $rc",
            disk.display(),
            env!("CARGO_BIN_EXE_geostride"),
            quoted.join(" "),
            disk.display(),
            keep.display()
        );
        let o = Command::new("unshare")
            .args(["-rm", "sh", "-c", &script])
            .output()
            .unwrap();
        let left = files(&keep);
        for f in &left {
            let name = f.file_name().unwrap().to_string_lossy().into_owned();
            assert!(
                !name.contains(".tmp-"),
                "{size_kb} kB: a temporary file was left: {}",
                f.display()
            );
            if let Err(e) = whole(f) {
                panic!("{size_kb} kB: an invalid file under its final name: {e}");
            }
        }
        if !o.status.success() {
            failed_runs += 1;
            assert_eq!(
                o.status.code(),
                Some(1),
                "{size_kb} kB: a full disk is a failure while running (exit 1): {}",
                String::from_utf8_lossy(&o.stderr)
            );
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(
                err.contains("space") || err.contains("disk") || err.contains("cut short"),
                "{size_kb} kB: {err}"
            );
        }
        eprintln!(
            "{size_kb} kB of {} kB: exit {:?}, {} file(s) left, all whole",
            total / 1024,
            o.status.code(),
            left.len()
        );
    }
    assert!(failed_runs >= 5, "only {failed_runs} runs met a full disk");

    // survey convert onto a full disk: no file, exit non-zero, never "Written".
    for to in ["csv", "geojson", "gpkg"] {
        let target = disk.join(format!("gcps.{to}"));
        let o = on_small_disk(
            &disk,
            4,
            &[
                "survey".into(),
                "convert".into(),
                project.with_file_name("gcps.csv").display().to_string(),
                "--to".into(),
                to.into(),
                "-o".into(),
                target.display().to_string(),
            ],
        );
        // 4 kB may hold a small CSV; if the write succeeded, it is whole (checked in the run above).
        if !o.status.success() {
            assert_eq!(
                o.status.code(),
                Some(1),
                "{to}: {}",
                String::from_utf8_lossy(&o.stderr)
            );
            assert!(
                !String::from_utf8_lossy(&o.stdout).contains("Written"),
                "{to}: says Written on a full disk"
            );
        }
    }
}

#[test]
fn a_killed_runs_temporaries_are_removed_by_the_next() {
    let tmp = tempfile::tempdir().unwrap();
    let project = project(&tmp.path().join("p"));
    let out = tmp.path().join("out");
    let run = || {
        assert_success(
            &geostride()
                .arg("run")
                .arg(&project)
                .arg("--out")
                .arg(&out)
                .arg("-q")
                .output()
                .unwrap(),
        )
    };
    run();
    // What a kill during the export and during a stage's store leaves (no process has this id).
    let stale = [
        out.join(".trajectories.csv.tmp-4194999"),
        out.join(".trajectories.gpkg.tmp-4194999.gpkg"),
        out.join(".trajectories.gpkg.tmp-4194999.gpkg-journal"),
        out.join(".stages/.track.bin.tmp-4194999"),
        out.join(".stages/chunks/.00000.bin.tmp-4194999"),
        out.join("pose/.poses.csv.tmp-4194999"),
        out.join("plots/.speed.png.tmp-4194999"),
    ];
    for s in &stale {
        std::fs::write(s, b"half").unwrap();
    }
    // A file of the user's that merely looks hidden stays.
    std::fs::write(out.join(".notes"), b"mine").unwrap();
    run();
    for s in &stale {
        assert!(!s.exists(), "{} was not removed", s.display());
    }
    assert!(out.join(".notes").exists());

    // A run killed at random moments: whatever it left is whole, and the next run finishes.
    for delay_ms in [150, 400, 900] {
        let o = tmp.path().join(format!("killed-{delay_ms}"));
        let mut child = geostride()
            .arg("run")
            .arg(&project)
            .arg("--out")
            .arg(&o)
            .arg("-q")
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        let _ = child.kill();
        let _ = child.wait();
        for f in files(&o) {
            let name = f.file_name().unwrap().to_string_lossy().into_owned();
            if name.contains(".tmp-") {
                continue; // the next run removes it
            }
            whole(&f).unwrap_or_else(|e| panic!("killed after {delay_ms} ms: {e}"));
        }
        assert_success(
            &geostride()
                .arg("run")
                .arg(&project)
                .arg("--out")
                .arg(&o)
                .arg("-q")
                .output()
                .unwrap(),
        );
        assert!(
            files(&o)
                .iter()
                .all(|f| !f.to_string_lossy().contains(".tmp-")),
            "killed after {delay_ms} ms: a temporary survived the next run"
        );
    }
}
