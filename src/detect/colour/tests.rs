use super::*;

#[test]
fn lab_of_known_colours() {
    let w = lab([255, 255, 255]);
    assert!((w - Vector3::new(100.0, 0.0, 0.0)).norm() < 0.01, "{w}");
    let m = lab([255, 0, 255]);
    assert!(
        (m - Vector3::new(60.32, 98.23, -60.82)).norm() < 0.05,
        "{m}"
    );
}

/// A grey-green scene with shaded magenta discs and a magenta line.
fn scene(w: usize, h: usize, hats: &[(f64, f64)], r: f64) -> Vec<u8> {
    let mut bgr = vec![0u8; 3 * w * h];
    for y in 0..h {
        for x in 0..w {
            let i = 3 * (y * w + x);
            let t = ((x * 7 + y * 13) % 23) as u8;
            let (mut b, mut g, mut rr) = (90 + t, 120 + t, 100 + t);
            for &(cx, cy) in hats {
                let d = ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)).sqrt();
                if d <= r {
                    // Shaded: darker towards one side.
                    let s = 0.7 + 0.3 * ((x as f64 - cx) / r);
                    (b, g, rr) = ((220.0 * s) as u8, (30.0 * s) as u8, (210.0 * s) as u8);
                }
            }
            if y == 5 {
                (b, g, rr) = (230, 20, 220);
            }
            bgr[i] = b;
            bgr[i + 1] = g;
            bgr[i + 2] = rr;
        }
    }
    bgr
}

/// Every third pixel of a frame, RGB: the palette's sample.
fn every_third_pixel(frame: &FrameView) -> Vec<[u8; 3]> {
    let w = frame.width;
    (0..w * frame.height)
        .step_by(3)
        .map(|i| frame.pixel(i % w, i / w))
        .collect()
}

/// A detector whose palette is learnt from every third pixel of `frame`.
fn learned(frame: &FrameView, px_per_m: f64) -> ColourDetector {
    let s = ColourSettings {
        px_per_m,
        ..ColourSettings::default()
    };
    let palette = Palette::learn(&every_third_pixel(frame), &s).unwrap();
    ColourDetector::new(&palette, s)
}

#[test]
fn finds_shaded_hats_and_ignores_a_line() {
    let (w, h) = (320, 200);
    let hats = [(60.3, 80.6), (200.0, 120.0), (250.5, 40.2)];
    let bgr = scene(w, h, &hats, 6.0);
    let frame = FrameView {
        index: 0,
        width: w,
        height: h,
        bgr: &bgr,
    };
    let det = learned(&frame, 50.0);
    let found = det.detect(&frame);
    assert_eq!(found.len(), 3, "{found:?}");
    for (cx, cy) in hats {
        let d = found
            .iter()
            .map(|d| (d.uv - Vector2::new(cx, cy)).norm())
            .fold(f64::INFINITY, f64::min);
        assert!(d < 0.5, "hat at ({cx}, {cy}) found {d} px off");
    }
}

#[test]
fn the_coarse_scan_finds_the_same_hat_runs_as_a_full_scan() {
    let (w, h) = (400, 240);
    let hats = [(60.3, 80.6), (200.0, 120.0), (251.5, 40.2), (390.0, 230.0)];
    let bgr = scene(w, h, &hats, 13.0);
    let frame = FrameView {
        index: 0,
        width: w,
        height: h,
        bgr: &bgr,
    };
    let det = learned(&frame, 100.0);
    assert!(det.hat_radius_px() >= 6.0, "the coarse path is exercised");
    let key = |r: &Run| (r.y, r.x0, r.x1);
    let coarse: Vec<_> = det.runs(&frame).iter().map(key).collect();
    let full: Vec<_> = runs_in(&frame, &det.table, 0..h, |_| std::iter::once((0, w)))
        .iter()
        .map(key)
        .collect();
    // The one-pixel line is between the grid's rows: only it may be missed.
    let hat_runs: Vec<_> = full.iter().copied().filter(|r| r.0 != 5).collect();
    assert!(hat_runs.len() > 80, "{}", hat_runs.len());
    assert_eq!(
        coarse
            .iter()
            .copied()
            .filter(|r| r.0 != 5)
            .collect::<Vec<_>>(),
        hat_runs
    );
}

#[test]
fn learning_on_the_way_gives_what_a_palette_learnt_first_gives() {
    let (w, h) = (320, 200);
    let frames: Vec<Vec<u8>> = (0..6)
        .map(|i| {
            let x = 40.0 + 30.0 * i as f64;
            scene(w, h, &[(x, 80.6), (200.0, 120.0 - 5.0 * i as f64)], 6.0)
        })
        .collect();
    let view = |i: usize| FrameView {
        index: i,
        width: w,
        height: h,
        bgr: &frames[i],
    };
    let s = ColourSettings {
        px_per_m: 50.0,
        ..ColourSettings::default()
    };
    let mut learning = LearningColourDetector::new(s.clone(), Some(6), 3, 7, usize::MAX);
    let mut got = Vec::new();
    for i in 0..6 {
        got.extend(learning.push(&view(i)).unwrap());
    }
    got.extend(learning.finish().unwrap());
    assert_eq!(
        got.iter().map(|g| g.0).collect::<Vec<_>>(),
        (0..6).collect::<Vec<_>>()
    );
    // The same frames and pixels, sampled beforehand.
    let mut pixels = Vec::new();
    for &i in &learning.sample_frames {
        let mut k = (i * 7919) % 7;
        while k < w * h {
            pixels.push(view(i).pixel(k % w, k / w));
            k += 7;
        }
    }
    let first = ColourDetector::new(&Palette::learn(&pixels, &s).unwrap(), s.clone());
    for (i, d) in &got {
        assert_eq!(d.len(), 2, "frame {i}: {d:?}");
        assert_eq!(*d, first.detect(&view(*i)), "frame {i}");
    }
    // A budget too small to hold a frame: learnt from the first sampled frame on.
    let mut early = LearningColourDetector::new(s.clone(), Some(6), 3, 7, 1);
    let mut n = 0;
    for i in 0..6 {
        n += early.push(&view(i)).unwrap().len();
    }
    n += early.finish().unwrap().len();
    assert_eq!(n, 6);
    assert!(early.palette().is_some());
}

#[test]
fn a_scene_without_the_colour_is_an_error() {
    let pixels = vec![[100, 120, 90], [30, 30, 30], [200, 200, 200]];
    assert!(matches!(
        Palette::learn(&pixels, &ColourSettings::default()),
        Err(ColourError::NoHatColour { .. })
    ));
}
