//! A bounded fuzzing run over every parser (`make fuzz` runs the long one): seeded random,
//! mutated and structured inputs; no parser may panic, take a second on an input, name another
//! file in its errors or print a message over 8 kB, or hold more than 2 GB at once.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

mod fuzzing;

#[global_allocator]
static ALLOC: fuzzing::Counting = fuzzing::Counting;

/// Inputs per parser in `make test`; `GEOSTRIDE_FUZZ_INPUTS` changes it.
const INPUTS: u64 = 3000;

#[test]
fn no_parser_panics_or_runs_away_on_fuzzed_input() {
    let count = std::env::var("GEOSTRIDE_FUZZ_INPUTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(INPUTS);
    let mut failures = Vec::new();
    for target in fuzzing::targets() {
        let n = ((count as f64 * target.share).ceil() as u64).max(1);
        let r = fuzzing::fuzz(&target, 0x6E0_5712, 0, n);
        eprintln!(
            "{:<18} {:>7} inputs in {:>6.1} s: {:>6} ok, {:>6} errors; slowest {:.1} ms ({} bytes); peak heap {:.1} MB",
            r.target,
            r.inputs,
            r.seconds,
            r.ok,
            r.errors,
            r.slowest.1 * 1e3,
            r.slowest.2,
            r.peak_bytes as f64 / 1e6
        );
        if !r.panics.is_empty() {
            failures.push(format!("{}: panics {:?}", r.target, r.panics));
        }
        if !r.bad_messages.is_empty() {
            failures.push(format!("{}: messages {:?}", r.target, r.bad_messages));
        }
        if r.slowest.1 > 1.0 {
            failures.push(format!(
                "{}: input {} took {:.2} s",
                r.target, r.slowest.0, r.slowest.1
            ));
        }
        if r.peak_bytes > 2 << 30 {
            failures.push(format!("{}: {} bytes at once", r.target, r.peak_bytes));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
