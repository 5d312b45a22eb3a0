//! DJI's flight telemetry subtitles (`.SRT` beside each video), pure parsing. A subtitle block
//! is a counter, a time range and a payload; the payload's generations differ:
//!
//! - bracketed fields, `[iso: 100] [latitude: 69.189116] [longitude: 35.259334] [rel_alt: 1.100
//!   abs_alt: -2.927]` after `FrameCnt: 1, DiffTime: 33ms` and a date line (Mini, Air, Mavic 3,
//!   the enterprise M30/M3E/M300 with `[gb_yaw: … gb_pitch: … gb_roll: …]`); with spaces before
//!   the colon and `longtitude`/`altitude` on the Mavic 2 generation;
//! - function-call fields, `GPS(lon, lat, n)`, `HOME(lon, lat)`, `F.PRY (p, r, y)`,
//!   `G.PRY (p, r, y)`, `H 45.00m`, `ISO:100` (Phantom 4, Mavic Pro, M30 lineage).
//!
//! Every field is kept as written; the ones geostride uses (position, heights, gimbal and
//! aircraft attitude, the camera's settings) are read into numbers, and one that does not read
//! is an error naming the file, line and field.

use std::path::Path;

use crate::io::{FileCtx, FileError};

/// A yaw, pitch and roll, degrees (DJI's: yaw clockwise from north, pitch up from the horizon).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Attitude {
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
}

/// One subtitle block.
#[derive(Clone, Debug, PartialEq)]
pub struct SrtRecord {
    /// The block's first line in the file, from 1.
    pub line: usize,
    /// The subtitle counter.
    pub index: u64,
    /// The time range the block covers in the video, seconds.
    pub start_s: f64,
    pub end_s: f64,
    /// `FrameCnt` and `DiffTime` (milliseconds), where written.
    pub frame_count: Option<u64>,
    pub diff_time_ms: Option<f64>,
    /// The date and time as written (the drone's clock; no time zone is given).
    pub datetime: Option<String>,
    pub latitude_deg: Option<f64>,
    pub longitude_deg: Option<f64>,
    /// Height above the take-off point, metres (`rel_alt`; `H` or `BAROMETER` of the older
    /// generations).
    pub rel_alt_m: Option<f64>,
    /// Absolute altitude, metres (`abs_alt`, or `altitude` of the Mavic 2 generation): DJI writes
    /// it above mean sea level on consumer drones; its datum is the user's to state.
    pub abs_alt_m: Option<f64>,
    pub gimbal: Option<Attitude>,
    pub aircraft: Option<Attitude>,
    pub focal_len_mm: Option<f64>,
    pub iso: Option<f64>,
    /// Exposure time, seconds (`shutter: 1/2500.0`).
    pub shutter_s: Option<f64>,
    pub fnum: Option<f64>,
    pub ev: Option<f64>,
    /// Every field as written: (key, value), keys lower-case with single spaces.
    pub fields: Vec<(String, String)>,
}

/// A parsed `.SRT` file.
#[derive(Clone, Debug, PartialEq)]
pub struct SrtFile {
    pub records: Vec<SrtRecord>,
}

impl SrtFile {
    /// The record whose time range holds `t_s` (a video frame's time); else the nearest by its
    /// range's middle; `None` for an empty file.
    pub fn record_at(&self, t_s: f64) -> Option<&SrtRecord> {
        let k = self.records.partition_point(|r| r.start_s <= t_s);
        if k > 0 && t_s < self.records[k - 1].end_s {
            return Some(&self.records[k - 1]);
        }
        let mid = |r: &SrtRecord| ((r.start_s + r.end_s) / 2.0 - t_s).abs();
        [k.checked_sub(1), Some(k)]
            .into_iter()
            .flatten()
            .filter_map(|i| self.records.get(i))
            .min_by(|a, b| mid(a).total_cmp(&mid(b)))
    }

    /// The record of video frame `frame` at `fps`: the one covering the frame's middle. DJI
    /// writes the block times in whole milliseconds, so a frame's start (frame 40 at 15 fps:
    /// 2.6667 s) can fall just before its own block's rounded start (2.667 s) and in the block
    /// of the frame before.
    pub fn record_of_frame(&self, frame: usize, fps: f64) -> Option<&SrtRecord> {
        self.record_at((frame as f64 + 0.5) / fps)
    }
}

/// The columns of [`records_csv`].
pub const CSV_HEADER: &str = "index,start_s,end_s,frame_count,datetime,latitude_deg,longitude_deg,rel_alt_m,abs_alt_m,gimbal_yaw_deg,gimbal_pitch_deg,gimbal_roll_deg,aircraft_yaw_deg,aircraft_pitch_deg,aircraft_roll_deg,focal_len_mm,iso,shutter_s,fnum,ev";

/// The records as CSV, one row a block (empty cells where the drone wrote nothing).
pub fn records_csv(file: &SrtFile) -> String {
    use std::fmt::Write as _;
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v}"));
    let att = |a: Option<Attitude>| {
        a.map_or(",,".to_string(), |a| {
            format!(
                "{},{},{}",
                opt(Some(a.yaw_deg).filter(|v| v.is_finite())),
                opt(Some(a.pitch_deg).filter(|v| v.is_finite())),
                opt(Some(a.roll_deg).filter(|v| v.is_finite()))
            )
        })
    };
    let mut s = format!("{CSV_HEADER}\n");
    for r in &file.records {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.index,
            r.start_s,
            r.end_s,
            r.frame_count.map_or(String::new(), |f| f.to_string()),
            // A date has no comma but the older generations' "HH:MM:SS,mmm": quoted.
            r.datetime
                .as_ref()
                .map_or(String::new(), |d| format!("\"{d}\"")),
            opt(r.latitude_deg),
            opt(r.longitude_deg),
            opt(r.rel_alt_m),
            opt(r.abs_alt_m),
            att(r.gimbal),
            att(r.aircraft),
            opt(r.focal_len_mm),
            opt(r.iso),
            opt(r.shutter_s),
            opt(r.fnum),
            opt(r.ev),
        );
    }
    s
}

/// The most blocks a file may hold: a day of video at 60 frames a second.
const MAX_RECORDS: usize = 24 * 3600 * 60;

/// Parses the text of `path` (CRLF and a byte-order mark allowed).
pub fn parse_srt(path: &Path, text: &str) -> Result<SrtFile, FileError> {
    let ctx = FileCtx { path };
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let lines: Vec<(usize, &str)> = ctx
        .lines(text)
        .map(|l| l.map(|(i, l)| (i, l.trim())))
        .collect::<Result<_, _>>()?;
    // A block starts at a counter followed by a time range (a line starting with a digit): the
    // enterprise drones put a blank line and a lone `0` before bracketed fields inside their
    // blocks, so blank lines do not end one.
    let starts_block = |k: usize| {
        lines[k].1.bytes().all(|b| b.is_ascii_digit())
            && !lines[k].1.is_empty()
            && lines
                .get(k + 1)
                .is_some_and(|l| l.1.bytes().next().is_some_and(|b| b.is_ascii_digit()))
    };
    let mut records: Vec<SrtRecord> = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        if lines[i].1.is_empty() {
            i += 1;
            continue;
        }
        let start = i;
        i += 1;
        while i < lines.len() && !starts_block(i) {
            i += 1;
        }
        let block: Vec<(usize, &str)> = lines[start..i]
            .iter()
            .copied()
            .filter(|l| !l.1.is_empty())
            .collect();
        let record = parse_block(&ctx, &block)?;
        if let Some(last) = records.last()
            && record.start_s < last.start_s
        {
            return Err(ctx.at(
                record.line + 1,
                format!(
                    "the block starts at {:.3} s, before the previous one ({:.3} s): blocks must be in time order",
                    record.start_s, last.start_s
                ),
            ));
        }
        if records.len() == MAX_RECORDS {
            return Err(ctx.at(record.line, "more than a day of blocks at 60 a second"));
        }
        records.push(record);
    }
    if records.is_empty() {
        return Err(ctx.err(
            None,
            None,
            "no subtitle blocks: expected DJI telemetry (a counter, 'HH:MM:SS,mmm --> HH:MM:SS,mmm', then the fields)",
        ));
    }
    Ok(SrtFile { records })
}

/// `HH:MM:SS,mmm` (or `.mmm`) in seconds.
fn timecode(s: &str) -> Option<f64> {
    let (hms, ms) = s.split_once([',', '.'])?;
    let parts: Vec<&str> = hms.split(':').collect();
    let [h, m, sec] = parts.as_slice() else {
        return None;
    };
    let num = |t: &str, max: u64| -> Option<u64> {
        (!t.is_empty() && t.len() <= 3 && t.bytes().all(|b| b.is_ascii_digit()))
            .then(|| t.parse().ok())
            .flatten()
            .filter(|v| *v <= max)
    };
    let (h, m, sec) = (num(h, 999)?, num(m, 59)?, num(sec, 59)?);
    let ms = num(ms, 999)? as f64 / 10f64.powi(ms.len() as i32);
    Some((h * 3600 + m * 60 + sec) as f64 + ms)
}

fn parse_block(ctx: &FileCtx, block: &[(usize, &str)]) -> Result<SrtRecord, FileError> {
    let (line, first) = block[0];
    let index: u64 = first.parse().map_err(|_| {
        ctx.at(
            line,
            format!(
                "expected a subtitle counter (a whole number), got '{}'",
                crate::io::clip(first, 40)
            ),
        )
    })?;
    let Some(&(tline, times)) = block.get(1) else {
        return Err(ctx.at(
            line,
            "the block ends after its counter: expected 'HH:MM:SS,mmm --> HH:MM:SS,mmm'",
        ));
    };
    let range = times
        .split_once("-->")
        .and_then(|(a, b)| Some((timecode(a.trim())?, timecode(b.trim())?)));
    let Some((start_s, end_s)) = range.filter(|(a, b)| b >= a) else {
        return Err(ctx.at(
            tline,
            format!(
                "expected 'HH:MM:SS,mmm --> HH:MM:SS,mmm' with the end not before the start, got '{}'",
                crate::io::clip(times, 60)
            ),
        ));
    };
    let mut r = SrtRecord {
        line,
        index,
        start_s,
        end_s,
        frame_count: None,
        diff_time_ms: None,
        datetime: None,
        latitude_deg: None,
        longitude_deg: None,
        rel_alt_m: None,
        abs_alt_m: None,
        gimbal: None,
        aircraft: None,
        focal_len_mm: None,
        iso: None,
        shutter_s: None,
        fnum: None,
        ev: None,
        fields: Vec::new(),
    };
    for &(l, text) in &block[2..] {
        let text = strip_tags(text);
        for (key, value) in fields_of(&text) {
            read_field(ctx, l, &mut r, &key, &value)?;
            r.fields.push((key, value));
        }
        if r.datetime.is_none() {
            r.datetime = datetime_in(&text);
        }
    }
    if r.latitude_deg.is_some() != r.longitude_deg.is_some() {
        return Err(ctx.at(
            line,
            "the block gives a latitude or a longitude without the other",
        ));
    }
    // DJI writes 0, 0 while it has no fix: no position (the fields keep what was written).
    if r.latitude_deg == Some(0.0) && r.longitude_deg == Some(0.0) {
        r.latitude_deg = None;
        r.longitude_deg = None;
    }
    Ok(r)
}

/// The text without `<…>` tags.
fn strip_tags(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut depth = 0usize;
    for c in s.chars() {
        match c {
            '<' => depth += 1,
            '>' if depth > 0 => depth -= 1,
            _ if depth == 0 => out.push(c),
            _ => {}
        }
    }
    out
}

/// A date and time `YYYY-MM-DD HH:MM:SS[.fff]` (or with dots in the date, or a comma before the
/// fraction), as written.
fn datetime_in(s: &str) -> Option<String> {
    s.char_indices().find_map(|(i, _)| {
        let rest = &s[i..];
        let date = rest.get(..10)?;
        let ok = date.bytes().enumerate().all(|(k, c)| match k {
            4 | 7 => c == b'-' || c == b'.',
            _ => c.is_ascii_digit(),
        });
        let time = rest.get(11..19)?;
        let tok = time.bytes().enumerate().all(|(k, c)| match k {
            2 | 5 => c == b':',
            _ => c.is_ascii_digit(),
        });
        if !(ok && tok && rest.as_bytes()[10] == b' ') {
            return None;
        }
        let frac = rest[19..]
            .strip_prefix(['.', ','])
            .map(|f| f.bytes().take_while(u8::is_ascii_digit).count())
            .filter(|n| *n > 0)
            .map_or(0, |n| n + 1);
        Some(rest[..19 + frac].to_string())
    })
}

/// A key as compared: lower case, single spaces, no space before its colon.
fn normal_key(k: &str) -> String {
    k.split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .to_ascii_lowercase()
}

/// The `(key, value)` fields of one payload line: bracketed groups, function calls
/// (`GPS(…)`, `F.PRY (…)`), `KEY: value` and `KEY value` pairs between commas.
fn fields_of(text: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut rest = text;
    let mut outside = String::new();
    while let Some(open) = rest.find(['[', '(']) {
        let close_ch = if rest.as_bytes()[open] == b'[' {
            ']'
        } else {
            ')'
        };
        let Some(len) = rest[open + 1..].find(close_ch) else {
            break;
        };
        let inner = &rest[open + 1..open + 1 + len];
        if close_ch == ']' {
            outside.push_str(&rest[..open]);
            outside.push(' ');
            out.extend(pairs_in(inner, true));
        } else {
            // A call: its name is the word before the parenthesis.
            let before = rest[..open].trim_end();
            let name_start = before
                .rfind(|c: char| c.is_whitespace() || c == ',' || c == ']')
                .map_or(0, |k| k + 1);
            outside.push_str(&before[..name_start]);
            outside.push(' ');
            out.push((normal_key(&before[name_start..]), inner.trim().to_string()));
        }
        rest = &rest[open + 1 + len + 1..];
    }
    outside.push_str(rest);
    for piece in outside.split(',') {
        out.extend(pairs_in(piece, false));
    }
    out
}

/// `key: value key: value` pairs (a value runs to the next key); a piece without a colon is
/// `KEY value` (`H 45.00m`, `ISO 100`) when it has two words and the second is a number.
/// `grouped`: the text of one bracket, whose first key may name the others.
fn pairs_in(s: &str, grouped: bool) -> Vec<(String, String)> {
    let s = s.replace(" :", ":");
    let words: Vec<&str> = s.split_whitespace().collect();
    if !s.contains(':') {
        return match words.as_slice() {
            // `F/2.8` of the older generation.
            [w] if w.starts_with("F/") => vec![("fnum".into(), w[2..].to_string())],
            [k, v]
                if k.chars().next().is_some_and(char::is_alphabetic)
                    && v.starts_with(|c: char| {
                        c.is_ascii_digit() || matches!(c, '-' | '+' | '.')
                    }) =>
            {
                vec![(normal_key(k), v.trim_end_matches(',').to_string())]
            }
            _ => Vec::new(),
        };
    }
    let mut out: Vec<(String, String)> = Vec::new();
    let mut key_words: Vec<&str> = Vec::new();
    let mut value: Vec<&str> = Vec::new();
    // A bracket's first key without a value names the others (`[Drone: Yaw:17.9, Pitch:-1.4,
    // Roll:1.1]`: `drone yaw`, `drone pitch`, `drone roll`); elsewhere it is an empty field.
    let mut prefix = String::new();
    let flush = |key: &mut Vec<&str>,
                 value: &mut Vec<&str>,
                 out: &mut Vec<(String, String)>,
                 prefix: &mut String| {
        if !key.is_empty() {
            let k = normal_key(&key.join(" "));
            if value.is_empty() && grouped && out.is_empty() && prefix.is_empty() {
                *prefix = k;
            } else if value.is_empty() {
                out.push((k, String::new()));
            } else {
                let k = if prefix.is_empty() {
                    k
                } else {
                    format!("{prefix} {k}")
                };
                out.push((k, value.join(" ").trim_end_matches(',').to_string()));
            }
        }
        key.clear();
        value.clear();
    };
    let mut pending: Vec<&str> = Vec::new();
    for w in words {
        // A time of day (`12:34:24.380`) is a value, not a key.
        let is_time = w.bytes().next().is_some_and(|b| b.is_ascii_digit());
        match w.split_once(':') {
            Some((k, v)) if !is_time && !k.is_empty() => {
                flush(&mut key_words, &mut value, &mut out, &mut prefix);
                // The words before a key that no key claimed belong to it (`shift x: 0.0`).
                key_words.append(&mut pending);
                key_words.push(k);
                if !v.is_empty() {
                    value.push(v);
                }
            }
            _ => {
                if key_words.is_empty() {
                    pending.push(w);
                } else {
                    value.push(w);
                }
            }
        }
    }
    flush(&mut key_words, &mut value, &mut out, &mut prefix);
    if !key_words.is_empty() || !prefix.is_empty() && out.is_empty() {
        // A lone key with no value is kept, empty.
        out.push((normal_key(&prefix), String::new()));
    }
    out
}

/// A number with an optional unit (`45.00m`, `0.0M`, `33ms`, `2.7°`, `3.20m/s`; `F2.8`: the
/// `F` dropped).
fn number(v: &str) -> Option<f64> {
    let v = v.trim();
    let v = v.strip_prefix(['F', 'f']).unwrap_or(v);
    let v = v.trim_end_matches(|c: char| c.is_alphabetic() || matches!(c, '°' | '%' | '/'));
    v.parse::<f64>().ok().filter(|x| x.is_finite())
}

/// Three numbers `a, b, c`.
fn triple(v: &str) -> Option<[f64; 3]> {
    let n: Vec<f64> = v.split(',').map(number).collect::<Option<Vec<f64>>>()?;
    <[f64; 3]>::try_from(n).ok()
}

/// Reads the fields geostride uses into `r`; a value that does not read is an error.
fn read_field(
    ctx: &FileCtx,
    line: usize,
    r: &mut SrtRecord,
    key: &str,
    value: &str,
) -> Result<(), FileError> {
    let bad = |what: &str| {
        ctx.err(
            Some(line),
            Some(key),
            format!("expected {what}, got '{}'", crate::io::clip(value, 40)),
        )
    };
    let num = |_unit: &str| number(value).ok_or_else(|| bad("a number"));
    let angle = |max: f64| {
        number(value)
            .filter(|a| a.abs() <= max)
            .ok_or_else(|| bad(&format!("an angle within ±{max}°")))
    };
    let attitude = |pry: [f64; 3]| Attitude {
        pitch_deg: pry[0],
        roll_deg: pry[1],
        yaw_deg: pry[2],
    };
    let set_angle = |slot: &mut Option<Attitude>, which: usize, a: f64| {
        let mut att = slot.unwrap_or(Attitude {
            yaw_deg: f64::NAN,
            pitch_deg: f64::NAN,
            roll_deg: f64::NAN,
        });
        match which {
            0 => att.yaw_deg = a,
            1 => att.pitch_deg = a,
            _ => att.roll_deg = a,
        }
        *slot = Some(att);
    };
    // An empty value (`EV:` of the Mavic Pro) is no value.
    if value.trim().is_empty() {
        return Ok(());
    }
    match key {
        "framecnt" | "srtcnt" => {
            // The first word: the Matrice 4 generation writes the date after it.
            let first = value.split_whitespace().next().unwrap_or("");
            r.frame_count = Some(first.parse().map_err(|_| bad("a whole number"))?)
        }
        "difftime" => r.diff_time_ms = Some(num("ms")?),
        "latitude" => r.latitude_deg = Some(angle(90.0)?),
        "longitude" | "longtitude" => r.longitude_deg = Some(angle(180.0)?),
        "rel_alt" | "h" | "barometer" => r.rel_alt_m = Some(num("m")?),
        "abs_alt" | "altitude" => r.abs_alt_m = Some(num("m")?),
        "gb_yaw" => set_angle(&mut r.gimbal, 0, angle(360.0)?),
        "gb_pitch" => set_angle(&mut r.gimbal, 1, angle(180.0)?),
        "gb_roll" => set_angle(&mut r.gimbal, 2, angle(180.0)?),
        "drone_yaw" | "drone yaw" => set_angle(&mut r.aircraft, 0, angle(360.0)?),
        "drone_pitch" | "drone pitch" => set_angle(&mut r.aircraft, 1, angle(180.0)?),
        "drone_roll" | "drone roll" => set_angle(&mut r.aircraft, 2, angle(180.0)?),
        "focal_len" => r.focal_len_mm = Some(num("mm")?),
        "iso" => r.iso = Some(num("")?),
        "fnum" | "f/" => r.fnum = Some(num("")?),
        "ev" => r.ev = Some(num("")?),
        "shutter" | "ss" => {
            // A bare number is the denominator (`SS 1000`, `Shutter:60`: 1/1000 s, 1/60 s).
            let s = match value.trim().split_once('/') {
                Some((a, b)) => number(a).zip(number(b)).map(|(a, b)| a / b),
                None => number(value).map(|d| 1.0 / d),
            };
            r.shutter_s = Some(
                s.filter(|s| *s > 0.0 && s.is_finite())
                    .ok_or_else(|| bad("a time such as 1/2500.0"))?,
            );
        }
        "gps" => {
            // Longitude first (the third number a satellite count), except where the third is
            // an altitude in metres (`GPS(36.6146,-6.1120,0.0M)`, the Matrice generation):
            // latitude first there.
            let parts: Vec<&str> = value.split(',').map(str::trim).collect();
            let v: Vec<f64> = parts
                .iter()
                .map(|t| number(t))
                .collect::<Option<_>>()
                .ok_or_else(|| bad("'longitude, latitude[, n]'"))?;
            let lat_first = parts.get(2).is_some_and(|t| t.ends_with(['M', 'm']));
            match v.as_slice() {
                [a, b, ..] => {
                    let (lat, lon) = if lat_first { (*a, *b) } else { (*b, *a) };
                    if !(lat.abs() <= 90.0 && lon.abs() <= 180.0) {
                        return Err(bad("'longitude, latitude[, n]' within range"));
                    }
                    r.longitude_deg = Some(lon);
                    r.latitude_deg = Some(lat);
                    // The third number (satellites, or an altitude that reads 0.0M on the
                    // Matrice generation) stays in the fields only.
                }
                _ => return Err(bad("'longitude, latitude[, n]'")),
            }
        }
        "f.pry" => {
            r.aircraft = Some(attitude(
                triple(value).ok_or_else(|| bad("'pitch, roll, yaw'"))?,
            ))
        }
        "g.pry" => {
            r.gimbal = Some(attitude(
                triple(value).ok_or_else(|| bad("'pitch, roll, yaw'"))?,
            ))
        }
        _ => {}
    }
    Ok(())
}

#[cfg(test)]
mod tests;
