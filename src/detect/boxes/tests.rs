use super::filter::*;
use super::shadow::*;
use super::*;

fn parse(name: &str, text: &str, format: BoxFormat) -> Result<Vec<RawBox>, String> {
    parse_boxes(Path::new(name), text, format).map_err(|e| e.to_string())
}

fn err(name: &str, text: &str, format: BoxFormat) -> String {
    parse(name, text, format).expect_err("should fail")
}

#[test]
fn mot_det_txt_parses() {
    let text = r"# MOT17-04 det.txt from the detector
1,-1,794.2,47.5,71.2,174.8,0.91,-1,-1,-1
1,-1,1648.1,119.6,66.5,164.2,0.87,-1,-1,-1

2,-1,795.0,48.1,70.9,175.3,-1,-1,-1,-1
3 -1 12.0 40.0 30.5 80.25 0.40
4, -1, 100, 200, 30, 60, 0.5,
";
    let b = parse("det.txt", text, BoxFormat::Mot).unwrap();
    assert_eq!(
        b.iter().map(|b| b.frame).collect::<Vec<_>>(),
        [0, 0, 1, 2, 3]
    );
    assert_eq!(
        b.iter().map(|b| b.line).collect::<Vec<_>>(),
        [2, 3, 5, 6, 7]
    );
    assert_eq!(b[0].bbox, [794.2, 47.5, 71.2, 174.8]);
    assert_eq!(b[0].score, 0.91);
    assert_eq!(b[2].score, 1.0, "conf -1 is unknown");
    assert_eq!(b[3].bbox, [12.0, 40.0, 30.5, 80.25]);
    let header = "frame,id,bb_left,bb_top,bb_width,bb_height,conf\n5,-1,1,2,3,4,0.6\n";
    let b = parse("det.csv", header, BoxFormat::Mot).unwrap();
    assert_eq!((b.len(), b[0].frame, b[0].line), (1, 4, 2));
}

#[test]
fn mot_errors_name_line_and_field() {
    let good = "1,-1,10,10,20,40,0.9,-1,-1,-1\n".repeat(6);
    let cases = [
        (
            "1,-1,10,10,abc,40,0.9,-1,-1,-1",
            "boxes.txt:7: field 'width': expected a number, found 'abc'",
        ),
        (
            "1,-1,10,10,20,-4,0.9,-1,-1,-1",
            "boxes.txt:7: field 'height': expected a positive size",
        ),
        (
            "1,-1,10,10,20,0,0.9",
            "boxes.txt:7: field 'height': expected a positive size",
        ),
        (
            "1,-1,10,10,20,40,1.5",
            "boxes.txt:7: field 'conf': expected a score in [0, 1] or -1",
        ),
        (
            "1,-1,NaN,10,20,40,0.9",
            "boxes.txt:7: field 'left': expected a finite number, found 'NaN'",
        ),
        (
            "0,-1,10,10,20,40,0.9",
            "boxes.txt:7: field 'frame': expected a whole frame number from 1 (MOT frames start at 1)",
        ),
        ("1,-1,10,10,20,40", "boxes.txt:7: expected 7 to 10 fields"),
    ];
    for (bad, want) in cases {
        let e = err("boxes.txt", &format!("{good}{bad}\n{good}"), BoxFormat::Mot);
        assert!(e.starts_with(want), "{bad}: {e}");
    }
    assert!(
        err("boxes.txt", "", BoxFormat::Mot)
            .ends_with("no boxes; expected at least one person box")
    );
    assert!(err("boxes.txt", "# nothing\n\n", BoxFormat::Mot).contains("no boxes"));
}

#[test]
fn json_lines_parse_both_forms() {
    let text = r#"{"frame": 0, "boxes": [{"bbox": [812.4, 233.1, 58.2, 61.0], "score": 0.62, "label": "person"}, {"bbox": [1020.0, 240.5, 55.0, 57.5], "score": 0.48, "label": "person"}]}
{"frame": 1, "boxes": []}

{"frame": 2, "xyxy": [100.0, 200.0, 160.0, 280.0], "score": 0.41, "label": "person"}
{"frame": 3, "bbox": [5, 6, 7, 8]}
"#;
    let b = parse("dino.jsonl", text, BoxFormat::JsonLines).unwrap();
    assert_eq!(
        b.iter().map(|b| (b.frame, b.line)).collect::<Vec<_>>(),
        [(0, 1), (0, 1), (2, 4), (3, 5)]
    );
    assert_eq!(b[1].bbox, [1020.0, 240.5, 55.0, 57.5]);
    assert_eq!(b[2].bbox, [100.0, 200.0, 60.0, 80.0]);
    assert_eq!(b[1].label.as_deref(), Some("person"));
    assert_eq!((b[3].score, b[3].label.clone()), (1.0, None));
}

#[test]
fn json_lines_errors_name_line_and_field() {
    let good = r#"{"frame": 0, "bbox": [1, 2, 3, 4], "score": 0.5}"#;
    let cases = [
        (
            r#"{"frame": 4, "bbox": [1, 2, 3, 4], "score": 0.5"#,
            "b.jsonl:3: invalid JSON at column",
        ),
        (
            r#"{"bbox": [1, 2, 3, 4]}"#,
            "b.jsonl:3: field 'frame': missing",
        ),
        (
            r#"{"frame": -2, "bbox": [1, 2, 3, 4]}"#,
            "b.jsonl:3: field 'frame': expected a 0-based frame index",
        ),
        (
            r#"{"frame": 4, "boxes": [{"bbox": [1, 2, 3, 4]}, {"bbox": [1, 2, 3]}]}"#,
            "b.jsonl:3: field 'boxes[1].bbox': expected 4 numbers",
        ),
        (
            r#"{"frame": 4, "xyxy": [10, 10, 5, 20]}"#,
            "b.jsonl:3: field 'xyxy': expected x1 > x0",
        ),
        (
            r#"{"frame": 4, "bbox": [1, 2, 3, 4], "score": 1.3}"#,
            "b.jsonl:3: field 'score': expected a score in [0, 1]",
        ),
        (
            r#"{"frame": 4, "bbox": [1, 2, "3", 4]}"#,
            "b.jsonl:3: field 'bbox': expected a number, found \"3\"",
        ),
        (r#"{"frame": 4}"#, "b.jsonl:3: field 'bbox': missing"),
    ];
    for (bad, want) in cases {
        let e = err(
            "b.jsonl",
            &format!("{good}\n\n{bad}\n{good}\n"),
            BoxFormat::JsonLines,
        );
        assert!(e.starts_with(want), "{bad}: {e}");
    }
}

#[test]
fn coco_results_list_keeps_people_with_their_lines() {
    let text = r#"[
  {
"image_id": 0,
"category_id": 1,
"bbox": [794.2, 47.5, 71.2, 174.8],
"score": 0.91
  },
  {
"image_id": 0,
"category_id": 3,
"bbox": [10.0, 20.0, 200.0, 100.0],
"score": 0.88
  },
  {
"image_id": 4,
"category_id": 1,
"bbox": [1648.1, 119.6, 66.5, 164.2],
"score": 0.77
  }
]"#;
    let b = parse("results.json", text, BoxFormat::Coco).unwrap();
    assert_eq!(
        b.iter().map(|b| (b.frame, b.line)).collect::<Vec<_>>(),
        [(0, 2), (4, 14)]
    );
    assert_eq!(b[1].bbox, [1648.1, 119.6, 66.5, 164.2]);
    assert_eq!((b[1].score, b[1].label.as_deref()), (0.77, Some("person")));
    let e = err(
        "results.json",
        &text.replace(r#""bbox": [1648.1"#, r#""bbox": [-1, 1648.1"#),
        BoxFormat::Coco,
    );
    assert!(
        e.starts_with("results.json:14: field 'bbox': expected 4 numbers"),
        "{e}"
    );
}

const DATASET: &str = r#"{
  "info": {"description": "bbox from Grounding DINO, prompt 'person', bridge_2024-05-14.mp4"},
  "images": [
{"id": 1, "file_name": "frames/frame_000123.jpg", "width": 3840, "height": 2160},
{"id": 2, "file_name": "frames/frame_000124.jpg", "width": 3840, "height": 2160},
{"id": 3, "file_name": "cam2/img.jpg", "frame_index": 900, "width": 3840, "height": 2160}
  ],
  "annotations": [
{"id": 1, "image_id": 1, "category_id": 2, "bbox": [100.5, 200.0, 60.0, 70.0], "score": 0.8, "area": 4200, "iscrowd": 0},
{"id": 2, "image_id": 2, "category_id": 1, "bbox": [10.0, 10.0, 30.0, 30.0], "score": 0.9, "area": 900, "iscrowd": 0},
{"id": 3, "image_id": 3, "category_id": 2, "bbox": [300.0, 400.0, 55.0, 65.0], "area": 3575, "iscrowd": 0}
  ],
  "categories": [{"id": 1, "name": "bicycle"}, {"id": 2, "name": "person"}]
}"#;

#[test]
fn coco_dataset_takes_frames_from_file_names() {
    // Digits after a character of two or three bytes (a panic, found by make fuzz).
    assert_eq!(frame_from_file_name("frame_é0001.jpg"), Some(1));
    assert_eq!(frame_from_file_name("frame_\u{feff}0012.png"), Some(12));
    assert_eq!(frame_from_file_name("Դ޹01.jpg"), Some(1));
    assert_eq!(frame_from_file_name("été.jpg"), None);
    let b = parse("dino.json", DATASET, BoxFormat::Coco).unwrap();
    assert_eq!(
        b.iter().map(|b| (b.frame, b.line)).collect::<Vec<_>>(),
        [(123, 9), (900, 11)]
    );
    assert_eq!(b[0].bbox, [100.5, 200.0, 60.0, 70.0]);
    assert_eq!((b[1].score, b[1].label.as_deref()), (1.0, Some("person")));
    // The same file on one line, as pycocotools writes it: still COCO, every line 1.
    let one_line: String = DATASET.lines().map(str::trim).collect();
    assert_eq!(
        BoxFormat::guess(Path::new("dino.json"), &one_line),
        BoxFormat::Coco
    );
    let b = parse("dino.json", &one_line, BoxFormat::Coco).unwrap();
    assert_eq!(
        b.iter().map(|b| (b.frame, b.line)).collect::<Vec<_>>(),
        [(123, 1), (900, 1)]
    );
}

#[test]
fn coco_errors_name_the_line() {
    let no_box = DATASET.replace(r#""bbox": [300.0, 400.0, 55.0, 65.0], "#, "");
    let e = err("d.json", &no_box, BoxFormat::Coco);
    assert!(e.starts_with("d.json:11: field 'bbox': missing"), "{e}");
    let unknown = DATASET.replace(r#""image_id": 3"#, r#""image_id": 7"#);
    let e = err("d.json", &unknown, BoxFormat::Coco);
    assert!(
        e.starts_with("d.json:11: field 'image_id': 7 is not among 'images'"),
        "{e}"
    );
    let no_digits = DATASET.replace(r#""frame_index": 900, "#, "");
    let e = err("d.json", &no_digits, BoxFormat::Coco);
    assert!(
        e.starts_with("d.json:6: field 'images.file_name': no digits in 'cam2/img.jpg'"),
        "{e}"
    );
    let broken = DATASET.replace(r#""height": 2160},"#, r#""height": 2160}"#);
    let e = err("d.json", &broken, BoxFormat::Coco);
    assert!(e.starts_with("d.json:5: invalid JSON at column"), "{e}");
    let no_person = DATASET.replace(r#""name": "person""#, r#""name": "car""#);
    let e = err("d.json", &no_person, BoxFormat::Coco);
    assert!(
        e.ends_with("no category named 'person' (found: bicycle, car)"),
        "{e}"
    );
}

#[test]
fn formats_are_named_and_guessed() {
    assert_eq!(BoxFormat::parse("MOT"), Some(BoxFormat::Mot));
    assert_eq!(BoxFormat::parse("jsonl"), Some(BoxFormat::JsonLines));
    assert_eq!(BoxFormat::parse("coco"), Some(BoxFormat::Coco));
    assert_eq!(BoxFormat::parse("yolo"), None);
    let jsonl = "{\"frame\": 0, \"bbox\": [1, 2, 3, 4]}\n{\"frame\": 1, \"bbox\": [1, 2, 3, 4]}\n";
    let g = |name: &str, text: &str| BoxFormat::guess(Path::new(name), text);
    assert_eq!(g("det.txt", "{"), BoxFormat::Mot);
    assert_eq!(g("boxes.ndjson", ""), BoxFormat::JsonLines);
    assert_eq!(g("boxes.json", jsonl), BoxFormat::JsonLines);
    assert_eq!(g("boxes.json", DATASET), BoxFormat::Coco);
    assert_eq!(g("boxes", "[{\"image_id\": 0}]"), BoxFormat::Coco);
    assert_eq!(g("boxes", "1,-1,1,2,3,4,0.5"), BoxFormat::Mot);
}

#[test]
fn read_boxes_from_a_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("det.txt");
    std::fs::write(&path, "\u{feff}1,-1,794.2,47.5,71.2,174.8,0.91,-1,-1,-1\n").unwrap();
    let b = read_boxes(&path, None).unwrap();
    assert_eq!((b.len(), b[0].frame, b[0].line), (1, 0, 1));
    let e = read_boxes(&dir.path().join("missing.txt"), None).unwrap_err();
    assert!(e.to_string().contains("cannot read"), "{e}");
}

fn bx(x: f64, y: f64, w: f64, h: f64, score: f64) -> RawBox {
    RawBox {
        frame: 0,
        bbox: [x, y, w, h],
        score,
        label: None,
        line: 1,
        head: None,
    }
}

/// Runs the filter and checks that the counts add up.
fn run(boxes: &[RawBox], f: &BoxFilter, frame: Option<&FrameView>) -> (Vec<RawBox>, FilterCounts) {
    f.check().unwrap();
    let (kept, n) = filter_frame(boxes, f, frame);
    let removed = n.low_score
        + n.outside_roi
        + n.merged
        + n.suppressed
        + n.bad_aspect
        + n.bad_size
        + n.shadows;
    assert_eq!(n.read + n.split - removed, n.kept, "{n:?}");
    assert_eq!(kept.len(), n.kept);
    (kept, n)
}

/// 100 px/m: a person's box of 50 x 60 px is 0.6 m.
fn person(x: f64, score: f64) -> RawBox {
    bx(x, 100.0, 50.0, 60.0, score)
}

#[test]
fn score_and_roi_filters() {
    let mut f = BoxFilter::new(100.0);
    let (kept, n) = run(&[person(0.0, 0.2), person(100.0, 0.5)], &f, None);
    assert_eq!((n.low_score, kept[0].bbox[0]), (1, 100.0));
    f.roi = Some([0.0, 0.0, 100.0, 1080.0]); // an entry strip along the left edge
    let (kept, n) = run(
        &[person(20.0, 0.9), person(90.0, 0.9), person(300.0, 0.9)],
        &f,
        None,
    );
    assert_eq!(n.outside_roi, 2, "centres at 45, 115 and 325 px");
    assert_eq!(kept[0].bbox[0], 20.0);
}

#[test]
fn near_duplicates_merge_and_overlaps_are_suppressed() {
    let f = BoxFilter::new(100.0);
    let (kept, n) = run(
        &[bx(101.0, 100.0, 50.0, 61.0, 0.6), person(100.0, 0.9)],
        &f,
        None,
    );
    assert_eq!((n.merged, kept.len()), (1, 1));
    assert!((kept[0].bbox[0] - 100.4).abs() < 1e-12 && (kept[0].bbox[3] - 60.4).abs() < 1e-12);
    assert_eq!(kept[0].score, 0.9);
    // IoU 0.54 with the best box: suppressed; IoU 0.11: kept.
    let (kept, n) = run(
        &[person(100.0, 0.9), person(115.0, 0.7), person(140.0, 0.8)],
        &f,
        None,
    );
    assert_eq!((n.merged, n.suppressed), (0, 1));
    assert_eq!(
        kept.iter().map(|b| b.bbox[0]).collect::<Vec<_>>(),
        [100.0, 140.0]
    );
}

#[test]
fn aspect_and_size_filters() {
    let f = BoxFilter::new(100.0);
    let boxes = [
        person(0.0, 0.9),
        bx(300.0, 0.0, 12.0, 60.0, 0.9),   // w/h 0.2
        bx(600.0, 0.0, 15.0, 15.0, 0.9),   // 0.15 m
        bx(900.0, 0.0, 180.0, 180.0, 0.9), // 1.8 m, too wide to be a row of people
    ];
    let (kept, n) = run(&boxes, &f, None);
    assert_eq!((n.bad_aspect, n.bad_size, n.split), (1, 2, 0));
    assert_eq!(kept[0].bbox, person(0.0, 0.9).bbox);
}

#[test]
fn group_boxes_split_along_their_longer_side() {
    let f = BoxFilter::new(100.0);
    let boxes = [
        bx(500.0, 100.0, 140.0, 50.0, 0.7),
        bx(800.0, 100.0, 50.0, 210.0, 0.6),
    ];
    let (kept, n) = run(&boxes, &f, None);
    assert_eq!((n.split, n.kept), (3, 5));
    assert_eq!(kept[0].bbox, [500.0, 100.0, 70.0, 50.0]);
    assert_eq!(kept[1].bbox, [570.0, 100.0, 70.0, 50.0]);
    assert_eq!(kept[4].bbox, [800.0, 240.0, 50.0, 70.0]);
    assert!(kept.iter().all(|b| b.score == 0.7 || b.score == 0.6));
    // A piece covering a person the detector also found alone gives way to it.
    let (kept, n) = run(
        &[
            bx(500.0, 100.0, 140.0, 50.0, 0.7),
            bx(502.0, 100.0, 68.0, 50.0, 0.9),
        ],
        &f,
        None,
    );
    assert_eq!((n.split, n.suppressed, kept.len()), (1, 1, 2));
    assert_eq!(kept[0].bbox[0], 502.0);
}

/// 200 x 100: the left half dark, nearly uniform ground; the right half bright and textured.
fn shadow_scene() -> Vec<u8> {
    let (w, h) = (200, 100);
    let mut bgr = vec![0u8; 3 * w * h];
    let bright = [[60, 180, 200], [220, 200, 60], [240, 240, 240]];
    for y in 0..h {
        for x in 0..w {
            let px = if x < 100 {
                let n = ((7 * x + 13 * y) % 6) as u8;
                [40 + n, 35 + n, 30 + n]
            } else {
                bright[(x / 4 + y / 4) % 3]
            };
            bgr[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&px);
        }
    }
    bgr
}

#[test]
fn boxes_on_shadow_are_rejected() {
    let bgr = shadow_scene();
    let frame = FrameView {
        index: 0,
        width: 200,
        height: 100,
        bgr: &bgr,
    };
    let model = ShadowModel::from_patches(&[(frame, [10, 10, 40, 40])]).unwrap();
    let (dark, lit) = ([20.0, 50.0, 40.0, 40.0], [130.0, 20.0, 40.0, 50.0]);
    assert!(model.shadow_fraction(&frame, &dark) > 0.99);
    assert!(model.shadow_fraction(&frame, &lit) < 0.01);
    assert_eq!(
        model.shadow_fraction(&frame, &[500.0, 0.0, 10.0, 10.0]),
        0.0
    );
    let mut f = BoxFilter::new(100.0);
    f.shadow = Some(model);
    let boxes = [
        bx(20.0, 50.0, 40.0, 40.0, 0.9),
        bx(130.0, 20.0, 40.0, 50.0, 0.8),
    ];
    let (kept, n) = run(&boxes, &f, Some(&frame));
    assert_eq!((n.shadows, kept[0].bbox), (1, lit));
    // Without the frame the shadow test cannot run.
    assert_eq!(run(&boxes, &f, None).1.shadows, 0);
    let e = ShadowModel::from_patches(&[(frame, [195, 95, 20, 20])]).unwrap_err();
    assert!(e.to_string().contains("hold 25 pixels"), "{e}");
}
