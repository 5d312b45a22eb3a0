use super::*;

fn parse(text: &str) -> Result<SrtFile, FileError> {
    parse_srt(Path::new("DJI_0001.SRT"), text)
}

fn close(a: Option<f64>, b: f64) -> bool {
    a.is_some_and(|a| (a - b).abs() < 1e-9)
}

/// Two blocks of the bracketed generation (a Mini/Air/Mavic 3), as the drones lay them out.
const BRACKETED: &str = "1\n00:00:00,000 --> 00:00:00,033\n<font size=\"28\">FrameCnt: 1, DiffTime: 33ms\n2024-05-18 10:21:07.512\n[iso: 110] [shutter: 1/640.0] [fnum: 1.7] [ev: -0.3] [color_md: default] [focal_len: 24.00] [latitude: 47.397842] [longitude: 8.545193] [rel_alt: 31.400 abs_alt: 478.213] [ct: 5480] </font>\n\n2\n00:00:00,033 --> 00:00:00,066\n<font size=\"28\">FrameCnt: 2, DiffTime: 33ms\n2024-05-18 10:21:07.545\n[iso: 110] [shutter: 1/640.0] [fnum: 1.7] [ev: -0.3] [color_md: default] [focal_len: 24.00] [latitude: 47.397845] [longitude: 8.545190] [rel_alt: 31.450 abs_alt: 478.263] [ct: 5480] </font>\n";

#[test]
fn the_bracketed_generation_gives_every_field() {
    let f = parse(BRACKETED).unwrap();
    assert_eq!(f.records.len(), 2);
    let r = &f.records[1];
    assert_eq!((r.line, r.index), (7, 2));
    assert!(close(Some(r.start_s), 0.033) && close(Some(r.end_s), 0.066));
    assert_eq!(r.frame_count, Some(2));
    assert!(close(r.diff_time_ms, 33.0));
    assert_eq!(r.datetime.as_deref(), Some("2024-05-18 10:21:07.545"));
    assert!(close(r.latitude_deg, 47.397845) && close(r.longitude_deg, 8.545190));
    assert!(close(r.rel_alt_m, 31.45) && close(r.abs_alt_m, 478.263));
    assert!(close(r.iso, 110.0) && close(r.shutter_s, 1.0 / 640.0));
    assert!(close(r.fnum, 1.7) && close(r.ev, -0.3) && close(r.focal_len_mm, 24.0));
    assert_eq!(r.gimbal, None);
    let field = |k: &str| {
        r.fields
            .iter()
            .find(|(key, _)| key == k)
            .map(|(_, v)| v.as_str())
    };
    assert_eq!(field("color_md"), Some("default"));
    assert_eq!(field("ct"), Some("5480"));
}

#[test]
fn the_enterprise_generation_gives_the_gimbal_and_zoom() {
    let text = "7\n00:00:00,200 --> 00:00:00,233\n<font size=\"28\">FrameCnt: 7 2024-02-01 09:00:00.200\n[focal_len: 40.00] [dzoom_ratio: 1.00, delta:0], [latitude: 31.229247] [longitude: 121.634603] [rel_alt: 79.969 abs_alt: 96.474] [gb_yaw: -67.6 gb_pitch: -30.0 gb_roll: 0.0] </font>\n";
    let r = &parse(text).unwrap().records[0];
    assert_eq!(r.frame_count, Some(7));
    assert_eq!(r.datetime.as_deref(), Some("2024-02-01 09:00:00.200"));
    assert_eq!(
        r.gimbal,
        Some(Attitude {
            yaw_deg: -67.6,
            pitch_deg: -30.0,
            roll_deg: 0.0
        })
    );
    assert!(close(r.abs_alt_m, 96.474) && close(r.focal_len_mm, 40.0));
    let field = |k: &str| {
        r.fields
            .iter()
            .find(|(key, _)| key == k)
            .map(|(_, v)| v.as_str())
    };
    assert_eq!(field("dzoom_ratio"), Some("1.00"));
    assert_eq!(field("delta"), Some("0"));
}

#[test]
fn the_mavic_2_generation_spaces_before_colons_and_longtitude() {
    let text = "\u{feff}3\r\n00:00:00,066 --> 00:00:00,100\r\n<font size=\"36\">SrtCnt : 3, DiffTime : 33ms\r\n2020-06-12 17:45:01,100,400\r\n[iso : 100] [shutter : 1/500.0] [fnum : 280] [ev : 0] [ct : 5500] [color_md : default] [focal_len : 240] [latitude : 36.115642] [longtitude : -115.172905] [altitude: 688.532997] </font>\r\n";
    let r = &parse(text).unwrap().records[0];
    assert!(close(r.latitude_deg, 36.115642) && close(r.longitude_deg, -115.172905));
    assert!(close(r.abs_alt_m, 688.532997));
    assert!(close(r.diff_time_ms, 33.0));
    assert_eq!(r.datetime.as_deref(), Some("2020-06-12 17:45:01,100"));
    // fnum and focal_len in hundredths and tenths on this generation: kept as written.
    assert!(close(r.fnum, 280.0) && close(r.focal_len_mm, 240.0));
}

#[test]
fn the_function_call_generations_give_position_attitudes_and_height() {
    let phantom = "1\n00:00:00,000 --> 00:00:01,000\nHOME(-122.031100,37.335000) 2017.03.21 15:36:55\nGPS(-122.031220,37.335110,16) BAROMETER:12.2\nISO:100 Shutter:60 EV:0 Fnum:F2.8\n";
    let r = &parse(phantom).unwrap().records[0];
    assert!(close(r.longitude_deg, -122.03122) && close(r.latitude_deg, 37.33511));
    assert_eq!(r.datetime.as_deref(), Some("2017.03.21 15:36:55"));
    assert!(close(r.shutter_s, 1.0 / 60.0) && close(r.fnum, 2.8) && close(r.iso, 100.0));
    assert_eq!(r.abs_alt_m, None);
    let m30 = "1\n00:00:00,000 --> 00:00:00,033\n<font size=\"36\">F/2.8, SS 400, ISO 100, EV 0, DZOOM 1.0, GPS (77.600120, 12.900340, 21), D 80.50m, H 45.00m, H.S 3.20m/s, V.S 0.00m/s, F.PRY (1.2, -0.5, 88.0), G.PRY (-60.0, 0.0, 90.0)</font>\n";
    let r = &parse(m30).unwrap().records[0];
    assert!(close(r.longitude_deg, 77.60012) && close(r.latitude_deg, 12.90034));
    assert!(close(r.rel_alt_m, 45.0) && close(r.fnum, 2.8) && close(r.shutter_s, 1.0 / 400.0));
    assert_eq!(
        r.aircraft,
        Some(Attitude {
            pitch_deg: 1.2,
            roll_deg: -0.5,
            yaw_deg: 88.0
        })
    );
    assert_eq!(
        r.gimbal,
        Some(Attitude {
            pitch_deg: -60.0,
            roll_deg: 0.0,
            yaw_deg: 90.0
        })
    );
}

#[test]
fn no_fix_is_no_position() {
    let text = BRACKETED.replace(
        "[latitude: 47.397842] [longitude: 8.545193]",
        "[latitude: 0.000000] [longitude: 0.000000]",
    );
    let f = parse(&text).unwrap();
    assert_eq!(
        (f.records[0].latitude_deg, f.records[0].longitude_deg),
        (None, None)
    );
    assert!(f.records[1].latitude_deg.is_some());
}

#[test]
fn the_record_of_a_time_is_the_one_covering_it_else_the_nearest() {
    let f = parse(BRACKETED).unwrap();
    assert_eq!(f.record_at(0.0).unwrap().index, 1);
    assert_eq!(f.record_at(0.040).unwrap().index, 2);
    assert_eq!(f.record_at(5.0).unwrap().index, 2);
    assert_eq!(f.record_at(-1.0).unwrap().index, 1);
}

#[test]
fn a_frame_is_matched_with_its_own_block_when_the_times_are_rounded_to_milliseconds() {
    // 15 fps, the block times rounded to ms as DJI and the simulator write them: frame k's
    // start k/15 s is just before block k+1's rounded start for k = 10, 40, ...
    let mut text = String::new();
    for k in 0..60u32 {
        let ms = |f: u32| (f64::from(f) * 1000.0 / 15.0).round() as u32;
        let t = |ms: u32| format!("00:00:{:02},{:03}", ms / 1000, ms % 1000);
        text += &format!(
            "{}\n{} --> {}\n[latitude: 51.{:07}] [longitude: 4.4]\n\n",
            k + 1,
            t(ms(k)),
            t(ms(k + 1)),
            k
        );
    }
    let f = parse(&text).unwrap();
    for frame in 0..60usize {
        assert_eq!(
            f.record_of_frame(frame, 15.0).unwrap().index,
            frame as u64 + 1,
            "frame {frame}"
        );
    }
    // What the check used before: the frame's start lands in the block before.
    assert_eq!(f.record_at(40.0 / 15.0).unwrap().index, 40);
}

#[test]
fn malformed_blocks_are_refused_with_their_line_and_field() {
    let cases: [(String, &str, &str); 7] = [
        (
            BRACKETED.replace("[latitude: 47.397845]", "[latitude: 47,397845]"),
            "DJI_0001.SRT:11",
            "latitude",
        ),
        (
            BRACKETED.replace("[latitude: 47.397845]", "[latitude: 97.3]"),
            "DJI_0001.SRT:11",
            "within ±90",
        ),
        (
            BRACKETED.replace(
                "00:00:00,033 --> 00:00:00,066",
                "00:00:00,033 -> 00:00:00,066",
            ),
            "DJI_0001.SRT:8",
            "HH:MM:SS,mmm",
        ),
        (
            BRACKETED.replacen("1\n", "one\n", 1),
            "DJI_0001.SRT:1",
            "counter",
        ),
        (
            BRACKETED
                .replace(
                    "00:00:00,033 --> 00:00:00,066",
                    "00:00:00,000 --> 00:00:00,010",
                )
                .replacen(
                    "00:00:00,000 --> 00:00:00,033",
                    "00:00:00,500 --> 00:00:00,533",
                    1,
                ),
            "DJI_0001.SRT:8",
            "time order",
        ),
        (
            BRACKETED.replace(" [longitude: 8.545190]", ""),
            "DJI_0001.SRT:7",
            "without the other",
        ),
        ("\n\n".to_string(), "DJI_0001.SRT", "no subtitle blocks"),
    ];
    for (text, at, what) in cases {
        let e = parse(&text).unwrap_err().to_string();
        assert!(e.starts_with(at) && e.contains(what), "{e}");
    }
}
